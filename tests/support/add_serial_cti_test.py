"""Tests of tests/support/add_serial_cti.py, run as a subprocess on small frames written here.

    /usr/bin/python3 -m pytest -q tests/support/add_serial_cti_test.py

Frames: 16-bit (BZERO 32768), GAIN 2 e-/ADU, BIASLVL 1000 ADU, every pixel at the bias but a
few bright ones, so that each trail can be compared with its closed form by brute force.
"""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from astropy.io import fits

SCRIPT = Path(__file__).with_name("add_serial_cti.py")
GAIN, BIAS = 2.0, 1000.0


def write(path, adu):
    hdu = fits.PrimaryHDU(data=adu.astype(np.uint16))
    hdu.header["GAIN"] = GAIN
    hdu.header["BIASLVL"] = BIAS
    hdu.writeto(path)


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True)


def test_one_bright_pixel_leaves_its_exponential_trail(tmp_path):
    nx, ny, x0, q_adu = 64, 3, 10, 30000
    adu = np.full((ny, nx), BIAS)
    adu[1, x0] += q_adu
    (tmp_path / "in").mkdir()
    write(tmp_path / "in" / "f.fits", adu)
    c, length = 2e-4, 1.5
    r = run(tmp_path / "in", tmp_path / "out", "--per_transfer", c, "--trail_length_px", length)
    assert r.returncode == 0, r.stderr
    with fits.open(tmp_path / "out" / "f.fits") as h:
        got = h[0].data.astype(float)
        assert h[0].header["GAIN"] == GAIN
    # Closed form: the packet at column x0 makes x0 + 1 transfers, f = c (x0 + 1); it keeps
    # (1 - f) Q and puts f Q (1 - r) r^(d - 1) into column x0 + d; rounded to whole ADU.
    q = q_adu * GAIN
    f = c * (x0 + 1)
    rr = math.exp(-1.0 / length)
    want = np.full(nx, BIAS)
    want[x0] = math.floor((1 - f) * q / GAIN + BIAS + 0.5)
    for d in range(1, nx - x0):
        want[x0 + d] = math.floor(f * q * (1 - rr) * rr ** (d - 1) / GAIN + BIAS + 0.5)
    np.testing.assert_array_equal(got[1], want)
    # The other rows, and the columns before the pixel, are untouched.
    np.testing.assert_array_equal(got[0], adu[0])
    np.testing.assert_array_equal(got[2], adu[2])
    # Charge is conserved to the rounding of the ~10 trail pixels holding charge.
    assert abs((got[1] - BIAS).sum() - q_adu) <= 10


def test_fraction_grows_with_the_transfers(tmp_path):
    nx = 200
    adu = np.full((1, nx), BIAS)
    for x in (20, 100, 180):
        adu[0, x] += 20000
    (tmp_path / "in").mkdir()
    write(tmp_path / "in" / "f.fits", adu)
    c = 2e-5
    assert run(tmp_path / "in", tmp_path / "out", "--per_transfer", c).returncode == 0
    got = fits.getdata(tmp_path / "out" / "f.fits").astype(float)[0]
    for x in (20, 100, 180):
        lost = 20000 - (got[x] - BIAS)  # the charge left behind, in ADU
        assert abs(lost - c * (x + 1) * 20000) <= 0.5 + 1e-9


def test_bad_input_is_one_line(tmp_path):
    (tmp_path / "in").mkdir()
    r = run(tmp_path / "in", tmp_path / "out", "--per_transfer", 1e-5)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no FITS files" in r.stderr
    adu = np.full((2, 10), BIAS)
    write(tmp_path / "in" / "f.fits", adu)
    r = run(tmp_path / "in", tmp_path / "out", "--per_transfer", 0.2)
    assert r.returncode == 2 and "--per_transfer" in r.stderr
    assert not (tmp_path / "out").exists()
    (tmp_path / "exists").mkdir()
    r = run(tmp_path / "in", tmp_path / "exists", "--per_transfer", 1e-5)
    assert r.returncode == 2 and "exists" in r.stderr
