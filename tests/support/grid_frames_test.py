"""Tests of tests/support/grid_frames.py, run as a subprocess on small sets.

    /usr/bin/python3 -m pytest -q tests/support/grid_frames_test.py

The frames are checked against the exact expected image of each spot, computed here by
another route than photon shooting: reference_sensor_test.exact_image, the pixel-integrated
Airy (*) Gaussian defocus (*) Gaussian diffusion (*) pixel box evaluated in Fourier space (its
own tests check it against photon shooting and quadrature). In a window around each spot the
summed electrons, the centroid and the per-axis second moments of the data, (ADU - BIASLVL) x
GAIN, are compared with those of the expected image, with standard deviations from the
expected image itself (delta method; per pixel Var = E + read_noise^2 + gain^2 / 12 for
Poisson counts, read noise and rounding to whole ADU).
"""

import csv
import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits
from scipy import stats

sys.path.insert(0, str(Path(__file__).parent))
from reference_sensor_test import exact_image  # noqa: E402  (the Fourier-space reference)

SCRIPT = Path(__file__).with_name("grid_frames.py")
GAIN, RN, BIAS, PIXEL_UM = 3.1, 4.5, 1000.0, 12.0
SMALL = ["--size", "512", "--grid", "3", "--exposures", "2", "--seed", "5"]
HALF = 7  # 15 x 15 px windows around single spots
Z_MAX = 4.0  # each comparison: |data - expected| < 4 sd (Gaussian two-sided p = 6e-5)


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def make(outdir, *args):
    r = run(outdir, *args)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    return json.loads((Path(outdir) / "truth.json").read_text())


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def digests(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(Path(folder).iterdir())}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The 512 x 512, 3 x 3 grid, 2-exposure set with extras: (folder, truth.json, e- frames)."""
    out = tmp_path_factory.mktemp("small") / "set"
    truth = make(out, *SMALL)
    frames = []
    for e in truth["exposures"]:
        with fits.open(out / e["file"]) as hdul:
            frames.append((hdul[0].data.astype(np.float64) - BIAS) * GAIN)
    return out, truth, frames


# --------------------------------------------------------------------------------------------
# Window statistics of the data against the expected image


def window_moments(img, var, xs, ys, px, py):
    """Sum, centroid and second moments about (px, py) of img, with delta-method sds for
    independent pixels of variance var."""
    s0 = img.sum()
    cx, cy = (img * xs).sum() / s0, (img * ys).sum() / s0
    mx, my = (img * (xs - px) ** 2).sum() / s0, (img * (ys - py) ** 2).sum() / s0
    value = {"sum": s0, "cx": cx, "cy": cy, "mx": mx, "my": my}
    sd = {"sum": math.sqrt(var.sum()),
          "cx": math.sqrt((var * (xs - cx) ** 2).sum()) / s0,
          "cy": math.sqrt((var * (ys - cy) ** 2).sum()) / s0,
          "mx": math.sqrt((var * ((xs - px) ** 2 - mx) ** 2).sum()) / s0,
          "my": math.sqrt((var * ((ys - py) ** 2 - my) ** 2).sum()) / s0}
    return value, sd


def compare_window(frame, exposure, spots, centre, half_x, half_y, width_scale=1.0):
    """Data against the exact expected image of `spots` (truth rows) in exposure `exposure`, in
    the window of (2 half + 1) px around the pixel nearest `centre` (exposure-0 coordinates),
    clipped to the frame. Returns (data moments, expected moments, sds); second moments are
    about the drifted centre."""
    dx, dy = exposure["drift_x_px"], exposure["drift_y_px"]
    px, py = centre[0] + dx, centre[1] + dy
    ix, iy = math.floor(px + 0.5), math.floor(py + 0.5)
    size = frame.shape[0]
    x0, x1 = max(ix - half_x, 0), min(ix + half_x + 1, size)
    y0, y1 = max(iy - half_y, 0), min(iy + half_y + 1, size)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    # The reference image is periodic with period L = 128 px, starting at the window's corner:
    # light left of or below the window wraps to the far side, outside the window. The copies
    # of the spot 128 px away put their Airy wings, ~2 r0 / (pi^3 Rz r^3) of the flux per px^2
    # (~2.5e-8 at 128 px), into the window: < 3 e- in 225 px at 4e5 e-, vs an sd of ~640 e-.
    model = np.zeros(xs.shape)
    for s in spots:
        model += exact_image(x1 - x0, y1 - y0, s["flux_e"], s["x_px"] + dx - x0, s["y_px"] + dy - y0,
                             s["airy_radius_px"], {"kind": "gaussian", "sigma_px": exposure["defocus_px"]},
                             s["ccd_sigma_x_px"] * width_scale, s["ccd_sigma_y_px"] * width_scale,
                             L=128)
    var = model + RN ** 2 + GAIN ** 2 / 12.0
    expected, sd = window_moments(model, var, xs, ys, px, py)
    data, _ = window_moments(frame[y0:y1, x0:x1], var, xs, ys, px, py)
    return data, expected, sd


def groups(truth):
    """(spots, centre, half_x, half_y) per isolated group: each grid and edge spot alone in a
    15 x 15 window; the crowded pair together in 21 x 15 about its midpoint."""
    rows = truth["spots"]
    out = [([s], (s["x_px"], s["y_px"]), HALF, HALF) for s in rows if s["kind"] in ("grid", "edge")]
    pair = [s for s in rows if s["kind"] == "crowded"]
    if pair:
        mid = (0.5 * (pair[0]["x_px"] + pair[1]["x_px"]), 0.5 * (pair[0]["y_px"] + pair[1]["y_px"]))
        out.append((pair, mid, 10, HALF))
    return out


@pytest.fixture(scope="module")
def compared(small):
    """compare_window for every (exposure, group) of the small set, with the truth's widths
    (scale 1) and, for the grid spots, with every CCD width 5 % larger: a list of dicts."""
    _, truth, frames = small
    out = []
    for frame, e in zip(frames, truth["exposures"]):
        for spots, centre, hx, hy in groups(truth):
            for scale in (1.0, 1.05) if spots[0]["kind"] == "grid" else (1.0,):
                data, expected, sd = compare_window(frame, e, spots, centre, hx, hy, scale)
                out.append({"exposure": e["index"], "spots": spots, "scale": scale,
                            "data": data, "expected": expected, "sd": sd})
    return out


# --------------------------------------------------------------------------------------------
# The frames against the truth


def test_spots_match_exact_expectation(compared):
    """Every spot group in every exposure: summed electrons (bias-subtracted ADU x gain; the
    15 x 15 box holds ~99.06 % of the flux, the Airy wings the rest, which the expected image
    accounts for exactly), the centroid (this checks x_px, y_px and the drift: the sd is
    ~0.002 px, the drift 0.03 / 0.02 px per exposure) and the second moments about the true
    centre (sd ~0.006 px^2) agree with the expected image within 4 sd each. 12 x 2 x 5 = 120
    comparisons at 4 sd: a false alarm has probability < 1 %, and the seed is fixed."""
    checked = [c for c in compared if c["scale"] == 1.0]
    assert len(checked) == 2 * (9 + 1 + 1)  # 9 grid spots, the pair, the edge spot; 2 exposures
    for c in checked:
        for q in c["data"]:
            z = (c["data"][q] - c["expected"][q]) / c["sd"][q]
            assert abs(z) < Z_MAX, (f"exposure {c['exposure']} spot {c['spots'][0]['spot']} {q}: "
                                    f"data {c['data'][q]:.5g}, expected {c['expected'][q]:.5g}, z {z:+.2f}")


def test_flux_in_box_is_flux_e(small):
    """The brief's plain check, without the model: each grid spot's electrons in a 15 x 15 box
    equal flux_e x the fraction of the PSF in that box within 4 sd of Poisson + read noise +
    rounding. The fraction comes from the encircled energy of the Airy pattern alone,
    EE(x) = 1 - J0^2 - J1^2 (Rayleigh), averaged over the ray directions to the square's
    boundary: beyond ~7 px the Airy wings (~1 %) are all there is, and the Gaussian blur
    (sigma ~0.5 px) moves < 1e-4 of the flux across the boundary (second order in sigma)."""
    from scipy import special
    _, truth, frames = small
    rz = 1.2196698912665045
    theta = (np.arange(20000) + 0.5) * (2 * math.pi / 20000)
    for frame, e in zip(frames, truth["exposures"]):
        for s in truth["spots"]:
            if s["kind"] != "grid":
                continue
            x, y = s["x_px"] + e["drift_x_px"], s["y_px"] + e["drift_y_px"]
            ix, iy = math.floor(x + 0.5), math.floor(y + 0.5)
            # Distances from the centre to the box edges along each ray [px].
            left, right = x - (ix - HALF - 0.5), (ix + HALF + 0.5) - x
            below, above = y - (iy - HALF - 0.5), (iy + HALF + 0.5) - y
            c, sn = np.cos(theta), np.sin(theta)
            with np.errstate(divide="ignore"):
                rx = np.where(c > 0, right / c, np.where(c < 0, -left / c, np.inf))
                ry = np.where(sn > 0, above / sn, np.where(sn < 0, -below / sn, np.inf))
            arg = math.pi * rz * np.minimum(rx, ry) / s["airy_radius_px"]
            fraction = float(np.mean(1.0 - special.j0(arg) ** 2 - special.j1(arg) ** 2))
            expected = s["flux_e"] * fraction
            got = frame[iy - HALF:iy + HALF + 1, ix - HALF:ix + HALF + 1].sum()
            sd = math.sqrt(expected + (2 * HALF + 1) ** 2 * (RN ** 2 + GAIN ** 2 / 12.0))
            assert 0.985 < fraction < 0.995
            assert abs(got - expected) < Z_MAX * sd, (s["spot"], got, expected, sd)


def test_widths_have_the_power_to_fail(compared):
    """The second moments summed over the grid spots, both axes and both exposures (36 values)
    agree with the truth's widths within 4 sd of the sum, and the same data against the model
    with every CCD width 5 % larger misses by more than 4 sd: the data carry the truth's
    widths, not just widths near them."""
    def summed_z(scale):
        diff = var = 0.0
        for c in compared:
            if c["scale"] == scale and c["spots"][0]["kind"] == "grid":
                for q in ("mx", "my"):
                    diff += c["data"][q] - c["expected"][q]
                    var += c["sd"][q] ** 2
        return diff / math.sqrt(var)

    assert abs(summed_z(1.0)) < Z_MAX
    assert abs(summed_z(1.05)) > Z_MAX


def test_second_moments_grow_with_truth_sigma(compared):
    """Model-free: across the 9 grid spots, the measured second moment about the true centre
    (mean of the 2 exposures) ranks like the truth's CCD sigma, per axis: Spearman rho > 0.9.
    The spots' sigma^2 differ by 0.005 .. 0.08 px^2, the moments' noise is ~0.004 px^2, and the
    truth has near-ties (the law is even in u or v), which can cost a few rank swaps: each swap
    of neighbours lowers rho by 12 / (9 x 80) = 0.017."""
    grid = [c for c in compared if c["scale"] == 1.0 and c["spots"][0]["kind"] == "grid"]
    spot_ids = sorted({c["spots"][0]["spot"] for c in grid})
    assert len(spot_ids) == 9
    measured = {q: [np.mean([c["data"][q] for c in grid if c["spots"][0]["spot"] == n]) for n in spot_ids]
                for q in ("mx", "my")}
    truth = {q: [next(c["spots"][0][key] for c in grid if c["spots"][0]["spot"] == n) for n in spot_ids]
             for q, key in (("mx", "ccd_sigma_x_px"), ("my", "ccd_sigma_y_px"))}
    for q in ("mx", "my"):
        assert stats.spearmanr(measured[q], truth[q])[0] > 0.9, q


def test_background_is_bias_and_read_noise(small):
    """Pixels farther than 25 px from every spot (the light stops at the 41 x 41 box, 20 px):
    mean 0 e- within 4 sd / sqrt(n), and the variance rn^2 + gain^2 / 12 (Gaussian read noise
    plus uniform rounding to whole ADU) within 4 sd of a sample variance, sqrt(2 / n) relative
    (Gaussian-dominated: the rounding's kurtosis changes that by < 5 %, allowed here)."""
    _, truth, frames = small
    for frame, e in zip(frames, truth["exposures"]):
        ys, xs = np.mgrid[0:frame.shape[0], 0:frame.shape[1]]
        far = np.ones(frame.shape, bool)
        for s in truth["spots"]:
            far &= np.maximum(abs(xs - s["x_px"] - e["drift_x_px"]), abs(ys - s["y_px"] - e["drift_y_px"])) > 25
        values = frame[far]
        n = values.size
        expected_var = RN ** 2 + GAIN ** 2 / 12.0
        assert abs(values.mean()) < Z_MAX * math.sqrt(expected_var / n)
        assert abs(values.var() / expected_var - 1.0) < 1.05 * Z_MAX * math.sqrt(2.0 / n)


# --------------------------------------------------------------------------------------------
# Files, headers and truth


def test_headers_and_pixels(small):
    out, truth, _ = small
    for e in truth["exposures"]:
        with fits.open(out / e["file"], do_not_scale_image_data=True) as hdul:
            h = hdul[0].header
            raw = hdul[0].data
            assert (h["BITPIX"], h["BZERO"], h["BSCALE"]) == (16, 32768, 1)
            assert (h["NAXIS1"], h["NAXIS2"]) == (512, 512)
            assert (h["GAIN"], h["RDNOISE"], h["BIASLVL"], h["PIXSIZE"], h["SATURATE"], h["WAVELEN"]) == \
                (GAIN, RN, BIAS, PIXEL_UM, 65535.0, 800.0)
            assert h["EXPTIME"] == e["exptime_s"] > 0
            assert "FOCUSPOS" not in h  # single-focus default
            adu = raw.astype(np.int64) + 32768
            assert 0 < adu.min() and adu.max() < 65535  # nothing clipped, nothing saturated


def test_truth_layout_and_columns(small):
    """truth.csv equals truth.json's spots; the layout and derived columns follow the spec."""
    out, truth, _ = small
    rows = read_csv(out / "truth.csv")
    assert list(rows[0].keys()) == truth["columns"]
    assert truth["columns"] == ["spot", "kind", "x_px", "y_px", "ccd_sigma_x_px", "ccd_sigma_y_px",
                                "airy_radius_px", "flux_e", "defocus_px", "total_sigma_x_px",
                                "total_sigma_y_px", "total_fwhm_um", "fwhm_um", "ellipticity",
                                "alpha_x", "alpha_y", "wavelength_nm"]
    assert len(rows) == len(truth["spots"]) == 9 + 3
    for r, j in zip(rows, truth["spots"]):
        assert int(r["spot"]) == j["spot"] and r["kind"] == j["kind"]
        for c in truth["columns"][2:]:
            assert float(r[c]) == j[c], c  # repr round-trips exactly

    spots = truth["spots"]
    assert [s["spot"] for s in spots] == list(range(12))
    assert [s["kind"] for s in spots] == ["grid"] * 9 + ["crowded", "crowded", "edge"]
    cell = 512 / 3
    for n, s in enumerate(spots[:9]):  # row-major from the bottom-left
        row, col = divmod(n, 3)
        assert abs(s["x_px"] - (-0.5 + (col + 0.5) * cell)) <= 0.5
        assert abs(s["y_px"] - (-0.5 + (row + 0.5) * cell)) <= 0.5
    a, b, edge = spots[9], spots[10], spots[11]
    assert b["x_px"] - a["x_px"] == pytest.approx(5.0, abs=1e-12) and a["y_px"] == b["y_px"]
    assert edge["x_px"] - (-0.5) == 3.0  # its 21 x 21 stamp would need columns -7 .. 13
    for extra in (a, b, edge):  # on a cell boundary in y: >= cell / 2 - 1 px from grid spots
        assert min(abs(extra["y_px"] - g["y_px"]) for g in spots[:9]) >= cell / 2 - 1

    fwhm = 2 * math.sqrt(2 * math.log(2))
    for s in spots:
        u, v = 2 * (s["x_px"] + 0.5) / 512 - 1, 2 * (s["y_px"] + 0.5) / 512 - 1
        sx, sy = s["ccd_sigma_x_px"], s["ccd_sigma_y_px"]
        assert sx == pytest.approx(0.29 + 0.05 * u + 0.03 * v * v, rel=1e-12)
        assert sy == pytest.approx(0.33 + 0.04 * v - 0.02 * u * u, rel=1e-12)
        assert 0.2 <= sx <= 0.45 and 0.2 <= sy <= 0.45
        assert s["airy_radius_px"] == 0.47 and s["flux_e"] == 4e5 and s["defocus_px"] == 0.41
        tx, ty = math.hypot(sx, 0.41), math.hypot(sy, 0.41)
        assert s["total_sigma_x_px"] == pytest.approx(tx, rel=1e-12)
        assert s["total_sigma_y_px"] == pytest.approx(ty, rel=1e-12)
        assert s["total_fwhm_um"] == pytest.approx(fwhm * math.sqrt(tx * ty) * PIXEL_UM, rel=1e-12)
        assert s["fwhm_um"] == pytest.approx(fwhm * math.sqrt(sx * sy) * PIXEL_UM, rel=1e-12)
        assert s["ellipticity"] == pytest.approx(abs(sx * sx - sy * sy) / (sx * sx + sy * sy), rel=1e-12)
        assert s["alpha_x"] == pytest.approx(-0.25 + 0.10 * u, rel=1e-12)
        assert s["alpha_y"] == pytest.approx(-0.20 + 0.08 * v, rel=1e-12)
        assert s["wavelength_nm"] == 800.0

    assert truth["seed"] == 5
    d = truth["detector"]
    assert (d["gain_e_per_adu"], d["read_noise_e"], d["bias_adu"], d["pixel_um"], d["saturation_adu"]) == \
        (GAIN, RN, BIAS, PIXEL_UM, 65535.0)
    for k, e in enumerate(truth["exposures"]):
        assert e["file"] == f"frame_{k:03d}.fits" and e["focus_um"] is None and e["defocus_px"] == 0.41
        assert (e["drift_x_px"], e["drift_y_px"]) == pytest.approx((0.03 * k, 0.02 * k))
        for rec in e["spots"]:  # photon bookkeeping: every photon drawn is accounted for
            assert rec["photons_drawn"] == rec["electrons_collected"] + rec["lost_beyond_box"] + rec["lost_beyond_frame"]
    assert sorted(p.name for p in out.iterdir()) == ["frame_000.fits", "frame_001.fits", "truth.csv", "truth.json"]


def test_focus_series(tmp_path):
    """--focus_um and --defocus_px: FOCUSPOS per frame, each frame's defocus, and no
    single-focus columns in truth.csv; the frame with the larger defocus has the wider spots."""
    out = tmp_path / "focus"
    # 2e5 e-: at 4e5 e- a 0.2 px defocus would saturate the peak (the script refuses that).
    truth = make(out, "--size", "128", "--grid", "2", "--no_extras", "--seed", "3", "--flux_e", "2e5",
                 "--focus_um", "-50,0,50", "--defocus_px", "0.6,0.2,0.6")
    assert [e["focus_um"] for e in truth["exposures"]] == [-50.0, 0.0, 50.0]
    assert [e["defocus_px"] for e in truth["exposures"]] == [0.6, 0.2, 0.6]
    assert truth["columns"] == ["spot", "kind", "x_px", "y_px", "ccd_sigma_x_px", "ccd_sigma_y_px",
                                "airy_radius_px", "flux_e", "fwhm_um", "ellipticity",
                                "alpha_x", "alpha_y", "wavelength_nm"]
    assert [s["kind"] for s in truth["spots"]] == ["grid"] * 4
    frames = []
    for e in truth["exposures"]:
        with fits.open(out / e["file"]) as hdul:
            assert hdul[0].header["FOCUSPOS"] == e["focus_um"]
            frames.append((hdul[0].data.astype(np.float64) - BIAS) * GAIN)
    for spots, centre, hx, hy in groups(truth):
        for frame, e in zip(frames, truth["exposures"]):
            data, expected, sd = compare_window(frame, e, spots, centre, hx, hy)
            for q in data:
                assert abs(data[q] - expected[q]) < Z_MAX * sd[q], (e["index"], q)
        # 0.6^2 - 0.2^2 = 0.32 px^2 wider at +-50 um: ~50 sd of a second moment.
        m = [compare_window(f, e, spots, centre, hx, hy)[0]["mx"] for f, e in zip(frames, truth["exposures"])]
        assert m[0] > m[1] + 0.2 and m[2] > m[1] + 0.2


def test_deterministic_per_seed(tmp_path):
    args = ["--size", "128", "--grid", "2", "--exposures", "2", "--no_extras"]
    make(tmp_path / "a", *args, "--seed", "9")
    make(tmp_path / "b", *args, "--seed", "9")
    make(tmp_path / "c", *args, "--seed", "10")
    a, b, c = digests(tmp_path / "a"), digests(tmp_path / "b"), digests(tmp_path / "c")
    assert a == b
    assert all(a[name] != c[name] for name in a)


def test_refuses_a_non_empty_outdir(tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    r = run(out, "--size", "128", "--grid", "2")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "not empty" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("args, needle", [
    (["--size", "abc"], "invalid int value"),
    (["--size", "32"], "--size 32 is out of range"),
    (["--grid", "0"], "--grid 0 is out of range"),
    (["--size", "128", "--grid", "4"], "too fine"),
    (["--grid", "1"], "no cell corner"),
    (["--size", "256", "--grid", "5"], "too close to grid spots"),
    (["--flux_e", "-1"], "--flux_e -1 is out of range"),
    (["--focus_um", "1,x,3"], "'x' is not a number"),
    (["--focus_um", "1,2", "--exposures", "3"], "exposure counts disagree"),
    (["--defocus_px", "0.4,-0.1"], "--defocus_px -0.1 is out of range"),
    (["--seed", "-4"], "--seed -4 is out of range"),
    (["--size", "128", "--grid", "2", "--flux_e", "1e6"], "saturates"),
    (["--bogus"], "unrecognized arguments"),
    (["--wavelength_nm", "0"], "--wavelength_nm 0 is out of range"),
    (["--wavelength_nm", "-650"], "--wavelength_nm -650 is out of range"),
    (["--wavelength_nm", "549"], "--wavelength_nm 549 is out of range"),
    (["--wavelength_nm", "901"], "--wavelength_nm 901 is out of range"),
    (["--wavelength_nm", "nan"], "--wavelength_nm nan is out of range"),
    (["--wavelength_nm", "red"], "invalid float value"),
])
def test_errors_are_one_line(tmp_path, args, needle):
    out = tmp_path / "never"
    r = run(out, *args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not out.exists()  # a refused set leaves nothing behind


def test_missing_outdir_is_one_line():
    r = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


# --------------------------------------------------------------------------------------------
# Wavelength: one run per wavelength, the same seed, the same layout


def law(x, y, size, wavelength_nm):
    """The docstring's laws, written out here: (sigma_x, sigma_y, alpha_x, alpha_y, airy) [px]
    at frame position (x, y) and wavelength [nm]."""
    u, v = 2 * (x + 0.5) / size - 1, 2 * (y + 0.5) / size - 1
    ax, ay = -0.25 + 0.10 * u, -0.20 + 0.08 * v
    r = wavelength_nm / 800.0
    return ((0.29 + 0.05 * u + 0.03 * v * v) * r ** ax, (0.33 + 0.04 * v - 0.02 * u * u) * r ** ay,
            ax, ay, 0.47 * r)


@pytest.fixture(scope="module")
def by_wavelength(tmp_path_factory):
    """The small set (as the `small` fixture, seed 5) at 650 and 850 nm: {W: (folder, truth,
    e- frames)}."""
    out = {}
    for w in (650, 850):
        folder = tmp_path_factory.mktemp(f"w{w}") / "set"
        truth = make(folder, *SMALL, "--wavelength_nm", w)
        frames = []
        for e in truth["exposures"]:
            with fits.open(folder / e["file"]) as hdul:
                assert hdul[0].header["WAVELEN"] == float(w)
                frames.append((hdul[0].data.astype(np.float64) - BIAS) * GAIN)
        out[w] = (folder, truth, frames)
    return out


def test_wavelength_truth_follows_the_laws(small, by_wavelength):
    """At 650 nm: every spot's widths, exponents and Airy radius equal the documented laws
    (to rounding: the script and this test may order the operations differently); truth.csv
    carries them as truth.json does; the positions are exactly those of the 800 nm set with the
    same seed (the layout does not depend on the wavelength), as are the other columns that do
    not depend on it."""
    folder, truth, _ = by_wavelength[650]
    _, truth800, _ = small
    assert truth["options"]["wavelength_nm"] == 650.0 and truth["optics"]["wavelength_nm"] == 650.0
    assert truth["optics"]["airy_radius_px"] == pytest.approx(0.47 * 650 / 800, rel=1e-12)
    assert truth["columns"] == truth800["columns"]
    rows = read_csv(folder / "truth.csv")
    assert len(rows) == len(truth["spots"]) == len(truth800["spots"]) == 12
    for r, s, s800 in zip(rows, truth["spots"], truth800["spots"]):
        for c in truth["columns"][2:]:
            assert float(r[c]) == s[c], c
        assert (s["kind"], s["x_px"], s["y_px"]) == (s800["kind"], s800["x_px"], s800["y_px"])
        sx, sy, ax, ay, airy = law(s["x_px"], s["y_px"], 512, 650.0)
        assert s["ccd_sigma_x_px"] == pytest.approx(sx, rel=1e-12)
        assert s["ccd_sigma_y_px"] == pytest.approx(sy, rel=1e-12)
        assert (s["alpha_x"], s["alpha_y"]) == pytest.approx((ax, ay), rel=1e-12)
        assert s["airy_radius_px"] == pytest.approx(airy, rel=1e-12)
        assert s["wavelength_nm"] == 650.0
        assert (s["alpha_x"], s["alpha_y"]) == (s800["alpha_x"], s800["alpha_y"])
        # Bluer light diffuses more (alpha < 0): every width is larger than at 800 nm.
        assert s["ccd_sigma_x_px"] > s800["ccd_sigma_x_px"] and s["ccd_sigma_y_px"] > s800["ccd_sigma_y_px"]
        tx, ty = math.hypot(sx, 0.41), math.hypot(sy, 0.41)
        assert s["total_sigma_x_px"] == pytest.approx(tx, rel=1e-12)
        assert s["total_sigma_y_px"] == pytest.approx(ty, rel=1e-12)
    assert [e["drift_x_px"] for e in truth["exposures"]] == [e["drift_x_px"] for e in truth800["exposures"]]


def test_width_laws_stay_in_bounds_at_every_allowed_wavelength(tmp_path):
    """The documented laws keep every width in 0.2 .. 0.45 px over the whole sensor (a 401 x 401
    grid of (u, v) in [-1, 1]) at 550 and 900 nm; the width is monotonic in W for each (u, v)
    (a power law), so the two ends bound every wavelength between. The script accepts both
    ends and writes those widths."""
    uv = np.linspace(-1.0, 1.0, 401)
    u, v = np.meshgrid(uv, uv)
    for w in (550.0, 900.0):
        r = w / 800.0
        sx = (0.29 + 0.05 * u + 0.03 * v * v) * r ** (-0.25 + 0.10 * u)
        sy = (0.33 + 0.04 * v - 0.02 * u * u) * r ** (-0.20 + 0.08 * v)
        assert 0.2 <= sx.min() and sx.max() <= 0.45 and 0.2 <= sy.min() and sy.max() <= 0.45, w
        truth = make(tmp_path / f"w{w:g}", "--size", "128", "--grid", "2", "--no_extras",
                     "--exposures", "1", "--wavelength_nm", w)
        for s in truth["spots"]:
            want = law(s["x_px"], s["y_px"], 128, w)
            assert (s["ccd_sigma_x_px"], s["ccd_sigma_y_px"]) == pytest.approx(want[:2], rel=1e-12)


def test_noise_streams_differ_between_wavelengths_and_800_is_the_default(tmp_path, small, by_wavelength):
    """--wavelength_nm 800 gives the default set's bytes. Other wavelengths draw their own noise:
    the Poisson photon counts of the spots differ (with the same stream they would be equal:
    reference_sensor draws the count from flux_e first, before any position), and the read noise in pixels far from all
    spots (25+ px) is uncorrelated between 650 and 850 nm (|r| < 4 / sqrt(n); with one shared
    stream r would be ~1)."""
    args = ["--size", "128", "--grid", "2", "--exposures", "1", "--no_extras", "--seed", "9"]
    make(tmp_path / "default", *args)
    make(tmp_path / "w800", *args, "--wavelength_nm", "800.0")
    assert digests(tmp_path / "default") == digests(tmp_path / "w800")

    counts = {w: [rec["photons_drawn"] for e in t["exposures"] for rec in e["spots"]]
              for w, (_, t, _) in list(by_wavelength.items()) + [(800, small)]}
    assert counts[650] != counts[850] and counts[650] != counts[800] and counts[850] != counts[800]

    _, truth, frames650 = by_wavelength[650]
    frames850 = by_wavelength[850][2]
    for k, e in enumerate(truth["exposures"]):
        ys, xs = np.mgrid[0:512, 0:512]
        far = np.ones((512, 512), bool)
        for s in truth["spots"]:
            far &= np.maximum(abs(xs - s["x_px"] - e["drift_x_px"]), abs(ys - s["y_px"] - e["drift_y_px"])) > 25
        r = np.corrcoef(frames650[k][far], frames850[k][far])[0, 1]
        assert abs(r) < Z_MAX / math.sqrt(far.sum()), (k, r)


def test_second_moments_follow_the_wavelength(by_wavelength, small):
    """The measured per-axis second moments of the 9 grid spots (15 x 15 windows about the true
    centre), averaged over spots, axes and exposures, change from 650 to 850 nm as the truth
    says: the expected change D comes from the exact images of each set's truth (Airy radius
    and widths at that wavelength). Its sign is not obvious: the windowed Airy moment grows
    ~linearly with r0 (its 1/r^3 wings weigh in up to the window's edge), the diffusion part
    shrinks (alpha < 0), so the sign is taken from D and required to be clear (|D| > 4 sd).
    With seed 5, D = -0.071 px^2 (850 nm the wider: the Airy term wins in this window). The
    data's change agrees with D within 4 sd (sd ~0.0013 px^2: ~0.006 px^2 per moment over 36
    moments per wavelength), and misses by > 4 sd the change predicted with the 800 nm widths
    at both wavelengths (only the Airy radius following W; -0.083 px^2, ~9 sd away): the data
    carry the widths' power law, not just the diffraction."""
    _, truth800, _ = small
    widths800 = {s["spot"]: (s["ccd_sigma_x_px"], s["ccd_sigma_y_px"]) for s in truth800["spots"]}

    def mean_moments(w, fixed_widths):
        _, truth, frames = by_wavelength[w]
        data = expected = var = 0.0
        n = 0
        for frame, e in zip(frames, truth["exposures"]):
            for spots, centre, hx, hy in groups(truth):
                if spots[0]["kind"] != "grid":
                    continue
                spot = dict(spots[0])
                if fixed_widths:
                    spot["ccd_sigma_x_px"], spot["ccd_sigma_y_px"] = widths800[spot["spot"]]
                d, x, sd = compare_window(frame, e, [spot], centre, hx, hy)
                for q in ("mx", "my"):
                    data += d[q]
                    expected += x[q]
                    var += sd[q] ** 2
                    n += 1
        assert n == 36
        return data / n, expected / n, var / n ** 2

    d650, x650, v650 = mean_moments(650, False)
    d850, x850, v850 = mean_moments(850, False)
    sd = math.sqrt(v650 + v850)
    change_data, change_expected = d650 - d850, x650 - x850
    assert abs(change_expected) > Z_MAX * sd  # the sign is clear
    assert math.copysign(1.0, change_data) == math.copysign(1.0, change_expected)
    assert abs(change_data - change_expected) < Z_MAX * sd, (change_data, change_expected, sd)

    _, a650, _ = mean_moments(650, True)
    _, a850, _ = mean_moments(850, True)
    assert abs(change_data - (a650 - a850)) > Z_MAX * sd, (change_data, a650 - a850, sd)
