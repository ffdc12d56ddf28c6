"""Tests of tests/support/lab_defects.py, run as a subprocess on a small frame written here.

    /usr/bin/python3 -m pytest -q tests/support/lab_defects_test.py

The frame: 48 x 48 uint16 (BZERO 32768), an 8-column prescan (BIASSEC [1:8,1:48]), a Gaussian
spot of 3e5 e- near (24.2, 22.7), Poisson and read noise; GAIN 3.1 e-/ADU, BIASLVL 1000 ADU,
RDNOISE 4.5 e-, SATURATE 65535.
"""

import hashlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

SCRIPT = Path(__file__).with_name("lab_defects.py")
CASES = ["cosmic_adjacent", "cosmic_3px", "hot_column", "second_spot", "clipped_core",
         "quantised_8bit", "clipped_black", "mef_segments"]
GAIN, BIAS, RN = 3.1, 1000.0, 4.5
N, PRESCAN = 48, 8


def write_frame(path, gain=True):
    """The clean test frame: Gaussian spot (sigma 1 px) sampled at pixel centres, in ADU."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:N, 0:N]
    expected_e = 3e5 / (2 * math.pi) * np.exp(-((x - 24.2) ** 2 + (y - 22.7) ** 2) / 2.0)
    expected_e[:, :PRESCAN] = 0.0  # the prescan sees no light
    e = rng.poisson(expected_e) + rng.normal(0.0, RN, (N, N))
    adu = np.clip(np.floor(e / GAIN + BIAS + 0.5), 0, 65535).astype(np.uint16)
    hdu = fits.PrimaryHDU(data=adu)  # uint16 -> BITPIX 16, BZERO 32768
    if gain:
        hdu.header["GAIN"] = GAIN
    hdu.header["RDNOISE"] = RN
    hdu.header["BIASLVL"] = BIAS
    hdu.header["BIASSEC"] = "[1:8,1:48]"
    hdu.header["SATURATE"] = 65535.0
    hdu.header["WAVELEN"] = 800.0
    hdu.header["EXPTIME"] = 4.1
    hdu.header["PIXSIZE"] = 12.0
    hdu.writeto(path)
    return adu.astype(np.int64)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    path = tmp_path_factory.mktemp("clean") / "clean.fits"
    data = write_frame(path)
    assert fits.getheader(path)["BZERO"] == 32768
    return path, data


def digest(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def apply(case, clean, out, *extra):
    """Runs one case; checks IN.fits is untouched and stdout is one JSON line; returns it."""
    path, _ = clean
    before = digest(path)
    r = run(case, path, out, *extra)
    assert r.returncode == 0, r.stderr
    assert digest(path) == before
    lines = r.stdout.splitlines()
    assert len(lines) == 1
    report = json.loads(lines[0])
    assert report["case"] == case
    return report


def read(path):
    with fits.open(path) as hdul:
        return hdul[0].header.copy(), hdul[0].data.astype(np.int64)


def peak_pixel(data):
    y, x = np.unravel_index(np.argmax(data[:, PRESCAN:]), data[:, PRESCAN:].shape)
    return x + PRESCAN, y


def parse_section(text):
    xs, ys = text.strip("[]").split(",")
    x1, x2 = (int(v) for v in xs.split(":"))
    y1, y2 = (int(v) for v in ys.split(":"))
    return slice(y1 - 1, y2), slice(x1 - 1, x2)  # numpy [rows, columns]


def test_list_prints_every_case():
    r = run("--list")
    assert r.returncode == 0
    assert r.stdout.split() == CASES


@pytest.mark.parametrize("case", ["cosmic_adjacent", "cosmic_3px"])
def test_cosmic_ray_pixels(case, clean, tmp_path):
    _, data = clean
    px, py = peak_pixel(data)
    report = apply(case, clean, tmp_path / "out.fits")
    assert report["peak_pixel"] == [px, py]
    header, out = read(tmp_path / "out.fits")
    assert header["BITPIX"] == 16 and header["BZERO"] == 32768
    expected = {"cosmic_adjacent": [(px + 1, 8000.0)],
                "cosmic_3px": [(px + 3, 8000.0), (px + 4, 2400.0)]}[case]
    assert [(p["x"], p["y"], p["e"]) for p in report["pixels"]] == [(x, py, e) for x, e in expected]
    diff = out - data
    for p in report["pixels"]:
        assert p["adu"] == math.floor(p["e"] / GAIN + 0.5)  # 8000 e- -> 2581 ADU
        assert diff[p["y"], p["x"]] == p["adu"]
    assert np.count_nonzero(diff) == len(expected)  # nothing else changed


def test_spot_option_moves_the_defect(clean, tmp_path):
    _, data = clean
    report = apply("cosmic_adjacent", clean, tmp_path / "out.fits", "--spot", "20.2", "30.4")
    assert report["peak_pixel"] == [20, 30] and report["spot_source"] == "--spot"
    diff = read(tmp_path / "out.fits")[1] - data
    assert list(zip(*np.nonzero(diff))) == [(30, 21)]


def test_hot_column(clean, tmp_path):
    _, data = clean
    px, _ = peak_pixel(data)
    report = apply("hot_column", clean, tmp_path / "out.fits", "--seed", "3")
    assert report["column_x"] == px + 4
    diff = read(tmp_path / "out.fits")[1] - data
    column = diff[:, px + 4]
    assert np.all(column > 0)
    assert np.count_nonzero(diff) == N  # only that column, every row
    assert column.sum() == report["added_adu_total"]
    # Mean 400 e- = 129.0 ADU; the mean of 48 Poisson draws has sd 20 e- / sqrt(48) / 3.1 ~ 0.9 ADU.
    assert abs(column.mean() - 400.0 / GAIN) < 5.0
    # Poisson: the variance in e- is the mean (rounding to ADU adds 3.1^2 / 12 e-^2).
    assert 0.6 < np.var(column * GAIN) / 400.0 < 1.6


def test_second_spot(clean, tmp_path):
    _, data = clean
    px, py = peak_pixel(data)
    report = apply("second_spot", clean, tmp_path / "out.fits", "--seed", "3")
    main_e = ((data[py - 3:py + 4, px - 3:px + 4] - BIAS) * GAIN).sum()
    assert report["flux_e"] == pytest.approx(0.6 * main_e)
    assert (report["x"], report["y"]) == (px + 6, py)
    diff = read(tmp_path / "out.fits")[1] - data
    x0, x1, y0, y1 = report["box"]
    inside = np.zeros_like(diff, dtype=bool)
    inside[y0:y1 + 1, x0:x1 + 1] = True
    assert not np.any(diff[~inside])  # nothing changed outside the box
    assert diff.sum() == report["added_adu"]
    # Total within Poisson (sqrt(flux) e-) and rounding (< 0.5 ADU per pixel) of the promise.
    tolerance_e = 5 * math.sqrt(report["flux_e"]) + 81 * 0.5 * GAIN
    assert abs(diff.sum() * GAIN - report["flux_e"]) < tolerance_e
    # Centred on (x+6, y), circular sigma 0.6 px (pixel integration adds 1/12 px^2 of variance).
    yy, xx = np.mgrid[0:N, 0:N]
    w = diff / diff.sum()
    cx, cy = (w * xx).sum(), (w * yy).sum()
    assert abs(cx - (px + 6)) < 0.02 and abs(cy - py) < 0.02
    var_x = (w * (xx - cx) ** 2).sum()
    assert var_x == pytest.approx(0.6 ** 2 + 1 / 12, rel=0.05)
    # Centre pixel: the exact integral of the Gaussian over +-0.5 px in x and y.
    frac = math.erf(0.5 / (0.6 * math.sqrt(2))) ** 2
    assert report["centre_pixel_e"] == pytest.approx(frac * report["flux_e"])


def test_clipped_core(clean, tmp_path):
    _, data = clean
    px, py = peak_pixel(data)
    report = apply("clipped_core", clean, tmp_path / "out.fits")
    header, out = read(tmp_path / "out.fits")
    clip = math.floor(0.7 * data[py, px])
    assert report["clip_adu"] == clip and "SATURATE" not in header
    assert "SATURATE" in report["keywords_removed"]
    hit = data >= clip
    assert hit.sum() == report["n_pixels"] > 1
    assert sorted(map(tuple, report["pixels"])) == sorted((x, y) for y, x in zip(*np.nonzero(hit)))
    assert np.all(out[hit] == clip) and out.max() == clip
    assert np.array_equal(out[~hit], data[~hit])  # the rest is untouched


@pytest.mark.parametrize("case,black", [("quantised_8bit", 10), ("clipped_black", 0)])
def test_8bit(case, black, clean, tmp_path):
    _, data = clean
    px, py = peak_pixel(data)
    report = apply(case, clean, tmp_path / "out.fits")
    header, out = read(tmp_path / "out.fits")
    assert header["BITPIX"] == 8 and "BZERO" not in header and "BSCALE" not in header
    with fits.open(tmp_path / "out.fits") as hdul:
        assert hdul[0].data.dtype == np.uint8
    assert out.min() >= 0 and out.max() <= 255
    g8 = header["GAIN"]
    assert g8 == report["gain8_e_per_adu"]
    assert g8 == pytest.approx((data[py, px] - BIAS) * GAIN / 200.0, rel=1e-3)
    assert header["SATURATE"] == 255 and header["BIASSEC"] == "[1:8,1:48]"
    expected = np.clip(np.floor((data - BIAS) * GAIN / g8 + black + 0.5), 0, 255)
    assert np.array_equal(out, expected)
    assert abs(out[py, px] - (200 + black)) <= 1
    if case == "quantised_8bit":
        assert header["BIASLVL"] == 10 and header["RDNOISE"] == RN
    else:
        assert "BIASLVL" not in header and "RDNOISE" not in header
        assert {"BIASLVL", "RDNOISE"} <= set(report["keywords_removed"])
        assert np.mean(out[:, :PRESCAN] == 0) > 0.9  # the dark pixels sit at exactly 0
        assert report["n_at_0"] == np.count_nonzero(out == 0)


def test_mef_segments(clean, tmp_path):
    _, data = clean
    px, py = peak_pixel(data)
    report = apply("mef_segments", clean, tmp_path / "out.fits", "--seed", "5")
    with fits.open(tmp_path / "out.fits") as hdul:
        assert len(hdul) == 3 and hdul[0].data is None
        exts = [(h.header.copy(), h.data.astype(np.int64)) for h in hdul[1:]]
    split = px - 12  # 12 columns before the peak: AMP1 holds data columns 8..11
    frame_cols = [(PRESCAN, split), (split, N)]
    for (header, ext), (c0, c1), (name, bias, rn) in zip(
            exts, frame_cols, [("AMP1", 1000, 4.5), ("AMP2", 1350, 6.0)]):
        assert header["EXTNAME"] == name and "BIASLVL" not in header
        assert header["GAIN"] == GAIN and header["RDNOISE"] == rn
        for k in ("WAVELEN", "EXPTIME", "PIXSIZE", "SATURATE"):
            assert header[k] == fits.getheader(clean[0])[k]
        dsec, bsec = parse_section(header["DATASEC"]), parse_section(header["BIASSEC"])
        # DATASEC then a 10-column overscan: together they tile the extension exactly.
        assert ext.shape == (N, (c1 - c0) + 10)
        ncol = c1 - c0
        assert (dsec[1].start, dsec[1].stop) == (0, ncol)
        assert (bsec[1].start, bsec[1].stop) == (ncol, ext.shape[1])
        assert dsec[0] == bsec[0] == slice(0, N)
        overscan = ext[bsec]
        assert abs(overscan.mean() - bias) < 0.3
        rounding_e = GAIN / math.sqrt(12)  # sd of rounding to whole ADU [e-]
        assert np.std(overscan * GAIN) == pytest.approx(math.hypot(rn, rounding_e), rel=0.12)
        # Data: the input's signal on the new bias, plus noise bringing the total to rn.
        resid = ext[dsec] - (data[:, c0:c1] - BIAS + bias)
        extra = math.sqrt(rn ** 2 - RN ** 2)
        if extra == 0:
            assert not np.any(resid)
        else:
            assert abs(resid.mean()) < 0.3
            assert np.std(resid * GAIN) == pytest.approx(math.hypot(extra, rounding_e), rel=0.12)
    assert report["spot_extension"] == "AMP2"  # the spot and its stamp lie inside AMP2
    ex, ey = report["peak_ext_xy"]
    assert (ex, ey) == (px - split, py) and ex >= 10
    amp2 = exts[1][1][parse_section(exts[1][0]["DATASEC"])]
    assert np.unravel_index(np.argmax(amp2), amp2.shape) == (ey, ex)


@pytest.mark.parametrize("case", CASES)
def test_same_seed_same_bytes(case, clean, tmp_path):
    apply(case, clean, tmp_path / "a.fits", "--seed", "11")
    apply(case, clean, tmp_path / "b.fits", "--seed", "11")
    assert digest(tmp_path / "a.fits") == digest(tmp_path / "b.fits")


def test_other_seed_other_noise(clean, tmp_path):
    apply("hot_column", clean, tmp_path / "a.fits", "--seed", "1")
    apply("hot_column", clean, tmp_path / "b.fits", "--seed", "2")
    assert digest(tmp_path / "a.fits") != digest(tmp_path / "b.fits")


def assert_fails(r, out_dir):
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and r.stdout == ""
    assert not any(p.name.endswith(".fits") and "tmp" in p.name for p in Path(out_dir).iterdir())


def test_errors(clean, tmp_path):
    path, _ = clean
    before = digest(path)
    out = tmp_path / "out.fits"
    assert_fails(run("no_such_case", path, out), tmp_path)
    assert_fails(run("cosmic_adjacent", tmp_path / "missing.fits", out), tmp_path)
    assert_fails(run("cosmic_adjacent", path, path), tmp_path)  # OUT == IN
    assert_fails(run("cosmic_adjacent", path, Path(path).parent / "." / Path(path).name), tmp_path)
    assert_fails(run("second_spot", path, out, "--spot", "44", "20"), tmp_path)  # off the frame
    assert not out.exists()
    assert digest(path) == before
    no_gain = tmp_path / "no_gain.fits"
    write_frame(no_gain, gain=False)
    r = run("cosmic_adjacent", no_gain, out)
    assert_fails(r, tmp_path)
    assert "GAIN" in r.stderr and not out.exists()
    assert sorted(os.listdir(tmp_path)) == ["no_gain.fits"]
