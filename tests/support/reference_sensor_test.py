"""Tests of tests/support/reference_sensor.py: its photon shooting against physics computed
here by another route, and its file handling. Runs the script as a subprocess.

    /usr/bin/python3 -m pytest -q tests/support/reference_sensor_test.py

Independent references used here (none of them is in the script):
- the pixel-integrated image of Airy (*) defocus (*) Gaussian (*) pixel box, computed exactly in
  Fourier space: the circular pupil's OTF (2/pi)(acos v - v sqrt(1 - v^2)), v = rho r0 / Rz,
  times the defocus transform (Gaussian, or 2 J1(2 pi R rho) / (2 pi R rho) for a disc), the
  diffusion Gaussian, sinc(fx) sinc(fy) for the unit pixel, and the centre's phase, summed on a
  frequency grid of step 1/L with the aliases folded onto [0, 1) (exact for the image
  periodised with period L = 256 px) and inverse-transformed;
- the Airy encircled energy from a numerical quadrature of [2 J1(x)/x]^2 x (scipy.integrate);
- moments of a uniform disc (R^2 / 2 radially) and of a flat illumination (w^2 kept).
"""

import hashlib
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits
from scipy import integrate, special

SCRIPT = Path(__file__).with_name("reference_sensor.py")
RZ = 1.2196698912665045


def base_config(**over):
    cfg = {
        "seed": 11,
        "detector": {"gain_e_per_adu": 1.0, "read_noise_e": 0.0, "bias_adu": 1000,
                     "pixel_um": 12, "saturation_adu": 65535, "nx": 40, "ny": 40},
        "optics": {"airy_radius_px": 0.47, "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                   "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335},
        "exposures": [{"flux_e": 1e5, "x_px": 20.0, "y_px": 20.0, "exptime_s": 1.0,
                       "wavelength_nm": 800}],
    }
    cfg.update(over)
    return cfg


def run_script(cfg, outdir, tmp_path, name="config.json"):
    path = tmp_path / name
    path.write_text(json.dumps(cfg) if not isinstance(cfg, str) else cfg)
    return subprocess.run([sys.executable, str(SCRIPT), str(path), str(outdir)],
                          capture_output=True, text=True, timeout=120)


def simulate(cfg, tmp_path, name="out"):
    """Runs the script; returns (truth, [electron images]) with electrons = (ADU - bias) gain."""
    outdir = tmp_path / name
    res = run_script(cfg, outdir, tmp_path, name=f"{name}.json")
    assert res.returncode == 0, res.stderr
    truth = json.loads((outdir / "truth.json").read_text())
    images = []
    for e in truth.get("exposures", []):
        with fits.open(outdir / e["file"]) as hdul:
            h = hdul[0].header
            images.append((hdul[0].data.astype(np.float64) - h["BIASLVL"]) * h["GAIN"])
    return truth, images


def exact_image(nx, ny, flux, x0, y0, r0, defocus, sx, sy, L=256, M=3):
    """Expected electrons per pixel (see the module docstring): Fourier route, no sampling."""
    f = np.arange(-M * L, M * L) / L
    fx, fy = f[None, :], f[:, None]
    rho = np.hypot(fx, fy)
    v = np.minimum(rho * r0 / RZ, 1.0)
    transfer = (2.0 / math.pi) * (np.arccos(v) - v * np.sqrt(1.0 - v * v))
    if defocus["kind"] == "gaussian":
        transfer *= np.exp(-2.0 * math.pi ** 2 * defocus["sigma_px"] ** 2 * rho ** 2)
    else:
        t = 2.0 * math.pi * defocus["radius_px"] * rho
        with np.errstate(invalid="ignore", divide="ignore"):
            transfer *= np.where(t > 0, 2.0 * special.j1(t) / t, 1.0)
    gx = np.exp(-2.0 * math.pi ** 2 * sx ** 2 * f ** 2) * np.sinc(f) * np.exp(-2j * math.pi * f * x0)
    gy = np.exp(-2.0 * math.pi ** 2 * sy ** 2 * f ** 2) * np.sinc(f) * np.exp(-2j * math.pi * f * y0)
    spectrum = transfer * gy[:, None] * gx[None, :]
    folded = spectrum.reshape(2 * M, L, 2 * M, L).sum(axis=(0, 2))
    image = np.fft.ifft2(folded).real * flux
    return image[:ny, :nx]


def poisson_chi2(data, model, min_model=0.5):
    """chi2 of counts against their expectation, with E[chi2] and its sd for Poisson counts."""
    use = model > min_model
    m, d = model[use], data[use]
    chi2 = float(np.sum((d - m) ** 2 / m))
    n = int(use.sum())
    sd = math.sqrt(float(np.sum(2.0 + 1.0 / m)))  # Var[(d - m)^2 / m] = 2 + 1/m
    return chi2, n, sd


def load_module():
    spec = importlib.util.spec_from_file_location("reference_sensor", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# ---------------------------------------------------------------------------------------------
# Physics


def test_exact_model_normalisation():
    """The Fourier reference itself: it holds the flux, and the centroid is where it was put."""
    img = exact_image(40, 40, 1.0, 20.3, 19.6, 0.47, {"kind": "gaussian", "sigma_px": 0.41}, 0.29, 0.33)
    y, x = np.mgrid[0:40, 0:40]
    assert abs(img.sum() - 0.995) < 0.005  # the Airy wings beyond the frame hold ~0.5 %
    core = (abs(x - 20) <= 6) & (abs(y - 20) <= 6)
    cx = (img * x)[core].sum() / img[core].sum()
    cy = (img * y)[core].sum() / img[core].sum()
    assert abs(cx - 20.3) < 0.01 and abs(cy - 19.6) < 0.01


def test_airy_radii_follow_numerical_encircled_energy():
    """The sampler's radii against EE from quadrature of the intensity (not Rayleigh's formula)."""
    mod = load_module()
    r0 = 0.47
    airy = mod.AiryRadii(r0)
    u = np.random.default_rng(5).random(1_000_000)
    r = airy.draw(u)
    edges_px = np.array([0.1, 0.2, 0.3, 0.47, 0.6, 0.8, 0.9, 1.2, 2.0, 5.0, 14.0])
    x_edges = math.pi * RZ * edges_px / r0
    intensity = lambda x: (2 * special.j1(x) / x) ** 2 * x if x > 0 else 0.0
    total = 2.0  # integral of [2 J1(x)/x]^2 x dx from 0 to inf
    ee = np.array([integrate.quad(intensity, 0, xe, limit=400)[0] for xe in x_edges]) / total
    got = np.array([np.mean(r <= e) for e in edges_px])
    sd = np.sqrt(ee * (1 - ee) / u.size)
    assert np.all(np.abs(got - ee) < 5 * sd + 1e-6), list(zip(edges_px, got, ee))


@pytest.mark.parametrize("defocus", [{"kind": "gaussian", "sigma_px": 0.41},
                                     {"kind": "pillbox", "radius_px": 1.0}])
def test_image_matches_exact_pixel_integral(tmp_path, defocus):
    """Photon shooting against the exact pixel-integrated Airy (*) defocus (*) Gaussian model.

    Six exposures of 1.6e5 photons at different sub-pixel centres (9.6e5 photons in all), gain 1
    and no read noise, so the images are the electron counts themselves (the peak stays below
    the 16-bit top). Pixels whose expectation exceeds 0.5 e- (all of the 40 x 40 frame). The
    photon count is Poisson(flux), so the pixel counts are independent Poisson(flux p):
    E[chi2] = n and Var[chi2] = sum(2 + 1/m). Pass: |chi2 - n| < 5 sd. The same data against the
    model with every width (defocus and diffusion) 3 % larger must fail that bound: the test
    has the power to see a 3 % error in the width."""
    cfg = base_config()
    cfg["optics"]["defocus"] = defocus
    centres = [(20.0, 20.0), (20.3, 19.8), (19.55, 20.15), (20.5, 20.5), (19.9, 19.62), (20.21, 20.44)]
    cfg["exposures"] = [{"flux_e": 1.6e5, "x_px": x, "y_px": y, "exptime_s": 1, "wavelength_nm": 800}
                        for x, y in centres]
    wider = {k: (v * 1.03 if k != "kind" else v) for k, v in defocus.items()}
    truth, images = simulate(cfg, tmp_path)
    chi2 = n = var = chi2_wrong = 0.0
    for e, data in zip(truth["exposures"], images):
        c = e["true_centre"]
        assert data.max() < 65535 - 1000
        assert data.sum() == e["electrons_collected"]
        model = exact_image(40, 40, 1.6e5, c["x_px"], c["y_px"], 0.47, defocus, 0.291, 0.335)
        c2, k, sd = poisson_chi2(data, model)
        chi2, n, var = chi2 + c2, n + k, var + sd * sd
        wrong = exact_image(40, 40, 1.6e5, c["x_px"], c["y_px"], 0.47, wider, 0.291 * 1.03, 0.335 * 1.03)
        chi2_wrong += poisson_chi2(data, wrong)[0]
    sd = math.sqrt(var)
    assert abs(chi2 - n) < 5 * sd, f"chi2 {chi2:.1f} for {n} pixels (sd {sd:.1f})"
    assert chi2_wrong - n > 5 * sd, f"3 % wider model: chi2 {chi2_wrong:.1f} for {n} pixels"


def test_pillbox_second_moment(tmp_path):
    """A disc of radius R has radial second moment R^2 / 2; diffusion adds sx^2 + sy^2.

    Without diffraction (airy 0): from the photon positions (truth.json) within 0.004 px^2 (the
    estimator's sd is 9e-4 px^2 for 3e5 photons: Var r^2 = R^4/12 + 4 (R^2/4)(sx^2 + sy^2)
    + 2 (sx^4 + sy^4) = 0.26 px^4), and from the pixel image (gain 4, so nothing is clipped)
    with Sheppard's correction for the unit pixel (+1/12 per axis) within 0.01 px^2. With the Airy pattern (0.47)
    the parts add: position moment = airy + defocus + diffusion moments within 0.02 px^2 (the
    cross terms vanish on average), and the defocus part alone is R^2 / 2 within 0.004 px^2."""
    R, sx, sy = 1.0, 0.25, 0.3
    expected = R * R / 2 + sx * sx + sy * sy
    cfg = base_config()
    cfg["detector"]["gain_e_per_adu"] = 4.0
    cfg["optics"] = {"airy_radius_px": 0.0, "defocus": {"kind": "pillbox", "radius_px": R},
                     "ccd_sigma_x_px": sx, "ccd_sigma_y_px": sy}
    cfg["exposures"][0]["flux_e"] = 3e5
    cfg["exposures"][0]["x_px"], cfg["exposures"][0]["y_px"] = 20.2, 19.7
    truth, (img,) = simulate(cfg, tmp_path, "noairy")
    pos = truth["exposures"][0]["photon_moments"]["position"]
    m2 = pos["sigma_x_px"] ** 2 + pos["sigma_y_px"] ** 2
    assert abs(m2 - expected) < 0.004, (m2, expected)
    assert truth["exposures"][0]["lost_outside_frame"] == 0
    y, x = np.mgrid[0:40, 0:40]
    tot = img.sum()
    cx, cy = (img * x).sum() / tot, (img * y).sum() / tot
    m2_img = (img * ((x - cx) ** 2 + (y - cy) ** 2)).sum() / tot - 2.0 / 12.0
    assert abs(m2_img - expected) < 0.01, (m2_img, expected)

    cfg["optics"]["airy_radius_px"] = 0.47
    truth, _ = simulate(cfg, tmp_path, "airy")
    pm = truth["exposures"][0]["photon_moments"]
    r2 = {k: v["sigma_x_px"] ** 2 + v["sigma_y_px"] ** 2 for k, v in pm.items()}
    assert abs(r2["defocus"] - R * R / 2) < 0.004
    assert abs(r2["defocus_plus_diffusion"] - expected) < 0.004
    assert abs(r2["position"] - (r2["airy"] + r2["defocus"] + r2["diffusion"])) < 0.02


@pytest.mark.parametrize("response,kept", [({"kind": "box", "width_px": 0.6}, 0.36),
                                           ({"kind": "box", "width_px": 1.0}, 1.0),
                                           ({"kind": "intrapixel", "edge_sensitivity": 0.5}, 0.5625)])
def test_pixel_response_flat_light(tmp_path, response, kept):
    """Flat light (a 6 px Gaussian, no diffraction or diffusion): a box response of width w keeps
    w^2 of the electrons landing in the frame, the linear intrapixel response ((1 + f)/2)^2.
    Within 5 binomial sd; the image holds exactly the collected electrons (gain 1, no noise)."""
    cfg = base_config()
    cfg["detector"]["nx"] = cfg["detector"]["ny"] = 48
    cfg["optics"] = {"airy_radius_px": 0.0, "defocus": {"kind": "gaussian", "sigma_px": 6.0},
                     "ccd_sigma_x_px": 0.0, "ccd_sigma_y_px": 0.0}
    cfg["pixel_response"] = response
    cfg["exposures"][0].update(flux_e=2e5, x_px=23.5, y_px=23.5)
    truth, (img,) = simulate(cfg, tmp_path)
    e = truth["exposures"][0]
    landed = e["electrons_collected"] + e["lost_pixel_response"]
    assert landed + e["lost_outside_frame"] == e["photons_drawn"]
    frac = e["electrons_collected"] / landed
    sd = math.sqrt(kept * (1 - kept) / landed)
    assert abs(frac - kept) <= 5 * sd + 1e-12, (frac, kept)
    assert img.sum() == e["electrons_collected"]


def bf_config(strength, batches=100):
    """The paper's PSF on a 48 x 48 frame, five fluxes 2e4 .. 4e5 e- (peak 7.5e3 .. 1.4e5 e-)."""
    cfg = base_config(seed=2024)
    cfg["detector"].update(gain_e_per_adu=3.1, read_noise_e=4.5, nx=48, ny=48)
    cfg["brighter_fatter"] = {"strength": strength, "batches": batches}
    cfg["exposures"] = [{"flux_e": f, "x_px": 24.0 + 0.03 * i, "y_px": 23.98, "exptime_s": 1,
                         "wavelength_nm": 800} for i, f in enumerate([2e4, 5e4, 1e5, 2e5, 4e5])]
    return cfg


def test_brighter_fatter_widths_grow_and_charge_is_conserved(tmp_path):
    """k = 1e-5 / e-, against the same seed with k = 0 (the same photons and draws, so the ratio
    of the widths is free of sampling noise): the defocus + diffusion width and the diffusion
    width, relative to the plain run, grow strictly with flux, the former by more than 3 % at
    4e5 e- (the simulation gives ~6 % in x, ~7 % in y); the plain widths themselves grow from
    the faintest to the brightest exposure by more than 3 %. Charge: every photon is accounted
    for (collected + lost outside the frame + lost to the pixel response = drawn), and the same
    number of electrons is collected as without brighter-fatter, to within 5 (the frame's edge)."""
    truth, _ = simulate(bf_config(1e-5), tmp_path, "bf")
    plain, _ = simulate(bf_config(0.0), tmp_path, "plain")
    widths, ratios = [], []
    keys = [("defocus_plus_diffusion", "sigma_x_px"), ("defocus_plus_diffusion", "sigma_y_px"),
            ("diffusion", "sigma_x_px"), ("diffusion", "sigma_y_px")]
    for e, p in zip(truth["exposures"], plain["exposures"]):
        assert e["photons_drawn"] == p["photons_drawn"]
        assert e["electrons_collected"] + e["lost_outside_frame"] + e["lost_pixel_response"] == e["photons_drawn"]
        assert abs(e["electrons_collected"] - p["electrons_collected"]) <= 5
        w = [e["photon_moments"][a][b] for a, b in keys]
        widths.append(w)
        ratios.append([x / p["photon_moments"][a][b] for x, (a, b) in zip(w, keys)])
        assert e["brighter_fatter_factor"]["mean"] > 1.0
        assert p["brighter_fatter_factor"]["mean"] == 1.0 == p["brighter_fatter_factor"]["max"]
    widths, ratios = np.array(widths), np.array(ratios)
    assert np.all(np.diff(ratios, axis=0) > 0), ratios
    assert np.all(ratios[-1, :2] > 1.03), ratios
    assert np.all(widths[-1, :2] / widths[0, :2] > 1.03), widths
    # Without brighter-fatter the widths are the configured ones at every flux (sd <= 0.5 %).
    for p in plain["exposures"]:
        w = p["photon_moments"]["defocus_plus_diffusion"]
        assert abs(w["sigma_x_px"] / math.hypot(0.41, 0.291) - 1) < 0.02
        assert abs(w["sigma_y_px"] / math.hypot(0.41, 0.335) - 1) < 0.02


def test_brighter_fatter_zero_is_the_plain_run_bit_for_bit(tmp_path):
    cfg = bf_config(0.0)
    plain = dict(cfg)
    del plain["brighter_fatter"]  # no "brighter_fatter" key at all
    simulate(cfg, tmp_path, "zero")
    simulate(plain, tmp_path, "absent")
    simulate(bf_config(1e-5), tmp_path, "on")
    for k in range(5):
        name = f"exposure_{k:03d}.fits"
        zero = (tmp_path / "zero" / name).read_bytes()
        assert zero == (tmp_path / "absent" / name).read_bytes()
        assert zero != (tmp_path / "on" / name).read_bytes()


# ---------------------------------------------------------------------------------------------
# Boundary shift (brighter-fatter as pixel boundaries moved by collected charge)


def closed_form_a(i, j, bx, by, p, d, R):
    """a_ij from the kernel written out side by side: the outward displacements of the right,
    left, top and bottom sides of pixel (i, j) by a unit charge at (0, 0)."""
    def s(mx, my, mn, b):
        r2 = mx * mx + my * my
        return 0.0 if r2 > R * R else -b * mn / (r2 + d * d) ** ((p + 1) / 2)
    return (s(i + 0.5, j, i + 0.5, bx) - s(i - 0.5, j, i - 0.5, bx)
            + s(i, j + 0.5, j + 0.5, by) - s(i, j - 0.5, j - 0.5, by))


def flat_config(levels, bs=None, n=32, **flats):
    cfg = {"seed": 3,
           "detector": {"gain_e_per_adu": 1.0, "read_noise_e": 0.0, "bias_adu": 1000,
                        "pixel_um": 12, "saturation_adu": 65535, "nx": n, "ny": n},
           "flats": dict({"levels_e": levels}, **flats)}
    if bs is not None:
        cfg["boundary_shift"] = bs
    return cfg


def test_a_table_closed_form_and_sum_rule(tmp_path):
    """truth.json's a_ij against the kernel evaluated side by side (every lag, to 1e-12
    relative), and against hand-derived values for d = 0: a_00 = -2^(p+1) (B_x + B_y) (the four
    sides of the charged pixel at |m| = 1/2 each move in by B 2^p), a_10 = B_x (2^p - 1.5^-p)
    - B_y / 1.25^((p+1)/2). The sum over all lags is 0 to rounding (< 1e-12 |a_00|); the table
    is mirror symmetric; a_00 < 0 < a_10, a_01, a_11."""
    bs = {"strength_x": 2e-7, "strength_y": 1e-7, "power": 2.5, "softening_px": 0.3, "range_px": 5}
    truth, _ = simulate(flat_config([100.0], bs, n=8), tmp_path, "soft")
    t = truth["boundary_shift"]
    R = 5
    table = np.array(t["a_table"])
    assert table.shape == (2 * R + 1, 2 * R + 1)
    for j in range(-R, R + 1):
        for i in range(-R, R + 1):
            want = closed_form_a(i, j, 2e-7, 1e-7, 2.5, 0.3, R)
            assert abs(table[j + R, i + R] - want) <= 1e-12 * abs(want) + 1e-24, (i, j)
            if i >= 0 and j >= 0:
                assert t["a"][f"a_{i}{j}"] == table[j + R, i + R]
    assert abs(table.sum()) < 1e-12 * abs(table[R, R]) and abs(t["a_sum_all_lags"]) < 1e-12 * abs(table[R, R])
    assert np.array_equal(table, table[::-1, :]) and np.array_equal(table, table[:, ::-1])
    assert t["a"]["a_00"] < 0 < min(t["a"]["a_10"], t["a"]["a_01"], t["a"]["a_11"])

    bs = {"strength_x": 1.5e-7, "strength_y": 2.5e-7, "power": 3, "softening_px": 0, "range_px": 4}
    truth, _ = simulate(flat_config([100.0], bs, n=8), tmp_path, "hard")
    a = truth["boundary_shift"]["a"]
    assert a["a_00"] == pytest.approx(-16 * (1.5e-7 + 2.5e-7), rel=1e-12)
    assert a["a_10"] == pytest.approx(1.5e-7 * (8 - 1.5 ** -3) - 2.5e-7 / 1.25 ** 2, rel=1e-12)
    assert a["a_01"] == pytest.approx(2.5e-7 * (8 - 1.5 ** -3) - 1.5e-7 / 1.25 ** 2, rel=1e-12)
    assert abs(sum(np.array(truth["boundary_shift"]["a_table"]).ravel())) < 1e-12 * 6.4e-6


def test_shift_field_convolution_against_direct_sums():
    """The FFT convolutions against direct sums over the charges (boundary displacements), and
    the two routes to the pixel areas (a_ij table vs the four sides' displacements) agree."""
    mod = load_module()
    bs = dict(mod.BOUNDARY_SHIFT_DEFAULTS, strength_x=3e-7, range_px=4)
    rng = np.random.default_rng(1)
    q = rng.poisson(1000.0, (9, 12)).astype(np.float64)
    field = mod.ShiftField(bs, q.shape)
    sv, sh = field.fields(q)
    assert sv.shape == (9, 13) and sh.shape == (10, 12)

    def shift(mx, my, mn, b):
        r2 = mx * mx + my * my
        return 0.0 if r2 > 16 else -b * mn / (r2 + 0.25) ** 2

    for r, k in [(0, 0), (4, 6), (8, 12), (3, 1)]:  # the vertical boundary left of column k
        want = sum(q[cy, cx] * shift(k - 0.5 - cx, r - cy, k - 0.5 - cx, 3e-7)
                   for cy in range(9) for cx in range(12))
        assert sv[r, k] == pytest.approx(want, rel=1e-9, abs=1e-15)
    for k, c in [(0, 0), (5, 7), (9, 11)]:  # the horizontal boundary below row k
        want = sum(q[cy, cx] * shift(c - cx, k - 0.5 - cy, k - 0.5 - cy, bs["strength_y"])
                   for cy in range(9) for cx in range(12))
        assert sh[k, c] == pytest.approx(want, rel=1e-9, abs=1e-15)
    areas = field.areas(q)
    assert np.allclose(areas, mod.areas_from_shifts(sv, sh), rtol=0, atol=1e-12 * np.abs(areas).max())


def bs_spot_config(bs, fluxes=(2e4, 1e5, 5e5)):
    """The paper's spot, gain 1 and no read noise; a boundary_shift block unless bs is None."""
    cfg = base_config(seed=7)
    cfg["exposures"] = [{"flux_e": f, "x_px": 20.1, "y_px": 19.95, "exptime_s": 1,
                         "wavelength_nm": 800} for f in fluxes]
    if bs is not None:
        cfg["boundary_shift"] = bs
    return cfg


def test_boundary_shift_zero_is_the_plain_run_bit_for_bit(tmp_path):
    """Both strengths 0: spot exposures and flats are byte for byte those without the block
    (nothing random is drawn for the shift); the default strengths change them."""
    zero = {"strength_x": 0, "strength_y": 0}
    for name, bs in [("zero", zero), ("plain", None), ("on", {})]:
        cfg = bs_spot_config(bs, (2e5,))
        cfg["flats"] = {"levels_e": [3e3, 4e4], "prnu": 0.01, "gradient": [0.05, 0.0]}
        simulate(cfg, tmp_path, name)
    for name in ["exposure_000.fits", "flat_000_0.fits", "flat_001_1.fits"]:
        plain = (tmp_path / "plain" / name).read_bytes()
        assert (tmp_path / "zero" / name).read_bytes() == plain
        assert (tmp_path / "on" / name).read_bytes() != plain


def test_boundary_shift_spots(tmp_path):
    """The default boundary shift on the paper's spot at 2e4, 1e5 and 5e5 e- (peaks ~7e3 ..
    1.8e5 e-), against the same seed without it (the same photons and landing points, so the
    differences are the reassignments alone, free of sampling noise):
    - charge is conserved: every electron is reassigned, none created or lost (the images
      sum to the same total, photons = collected + lost);
    - the defocus + diffusion + shift width grows strictly with flux in x and y, by more than
      2.5 % (x) and 3 % (y) at 5e5 e- (the simulation gives 5.1 and 5.9 %), more in y
      (B_y > B_x); at 2e4 e- by less than 0.6 % (it gives 0.2 %);
    - the peak pixel loses charge, growing with flux; the four edge neighbours together gain
      more electrons than the four diagonal ones, and both gain."""
    mod = load_module()
    airy = mod.AiryRadii(0.47)
    (tmp_path / "bs.json").write_text(json.dumps(bs_spot_config({})))
    (tmp_path / "plain.json").write_text(json.dumps(bs_spot_config(None)))
    cfg_bs, cfg_plain = mod.read_config(tmp_path / "bs.json"), mod.read_config(tmp_path / "plain.json")
    ratios, peak_loss = [], []
    for k in range(3):
        e_bs, _, t_bs = mod.simulate_exposure(cfg_bs, k, airy)
        e_pl, _, t_pl = mod.simulate_exposure(cfg_plain, k, airy)
        assert t_bs["photons_drawn"] == t_pl["photons_drawn"]
        assert e_bs.sum() == e_pl.sum() == t_bs["electrons_collected"]
        assert (t_bs["electrons_collected"] + t_bs["lost_outside_frame"]
                + t_bs["lost_pixel_response"] == t_bs["photons_drawn"])
        w = t_bs["photon_moments"]["defocus_plus_diffusion_plus_shift"]
        w0 = t_pl["photon_moments"]["defocus_plus_diffusion"]
        ratios.append([w["sigma_x_px"] / w0["sigma_x_px"], w["sigma_y_px"] / w0["sigma_y_px"]])
        d = (e_bs - e_pl).astype(np.float64)
        y0, x0 = np.unravel_index(np.argmax(e_pl), e_pl.shape)
        peak_loss.append(-d[y0, x0] / e_pl[y0, x0])
        edges = d[y0, x0 + 1] + d[y0, x0 - 1] + d[y0 + 1, x0] + d[y0 - 1, x0]
        diagonals = d[y0 + 1, x0 + 1] + d[y0 + 1, x0 - 1] + d[y0 - 1, x0 + 1] + d[y0 - 1, x0 - 1]
        if k == 2:
            assert edges > diagonals > 0, (edges, diagonals)
    ratios = np.array(ratios)
    assert np.all(np.diff(ratios, axis=0) > 0), ratios
    assert ratios[-1, 0] > 1.025 and ratios[-1, 1] > 1.03 and ratios[-1, 1] > ratios[-1, 0], ratios
    assert np.all(ratios[0] < 1.006), ratios
    assert 0 < peak_loss[0] < peak_loss[1] < peak_loss[2], peak_loss


def pair_covariances(a, b, lags):
    """Covariances [e-^2] of a flat pair from its difference, and their sds: C_ij = mean of
    d(x) d(x + (i, j)) / 2, averaged with the mirror lag (i, -j) for i, j > 0; sd C_00 sqrt(2/N),
    C_00 / sqrt(N) for the others (N products; halved by the mirror average)."""
    d = a - b
    d = d - d.mean()
    ny, nx = d.shape
    c00 = float(np.mean(d * d)) / 2
    out = {}
    for i, j in lags:
        prods = [d[:ny - j, :nx - i] * d[j:, i:]]
        if i > 0 and j > 0:
            prods.append(d[j:, :nx - i] * d[:ny - j, i:])
        n = sum(p.size for p in prods)
        c = float(sum(p.sum() for p in prods)) / n / 2
        out[(i, j)] = (c, c00 * math.sqrt((2.0 if (i, j) == (0, 0) else 1.0) / n))
    return out


def linear_theory(table, mu, batches, n=64):
    """Expected covariances [e-^2] of a flat collected in `batches` equal batches under
    area = 1 + a (*) charge (the docstring's recursion, derived independently here): in Fourier
    space each batch maps C^ -> (1 + D a^)^2 C^ + D, D = mu / batches, from C^ = 0."""
    R = (table.shape[0] - 1) // 2
    grid = np.zeros((n, n))
    for j in range(-R, R + 1):
        for i in range(-R, R + 1):
            grid[j % n, i % n] = table[j + R, i + R]
    ahat = np.fft.fft2(grid).real  # the table is symmetric: a real transform
    dd = mu / batches
    c = np.zeros_like(ahat)
    for _ in range(batches):
        c = (1 + dd * ahat) ** 2 * c + dd
    return np.fft.ifft2(c).real


def test_flat_covariances_follow_the_a_ij(tmp_path):
    """Two flat pairs of 512 x 512 pixels at 3e4 e- (gain 1, no read noise) with four times
    the default strengths (a_10 = 6.7e-7, a_00 mu = -0.15, so that 5e5 products per lag give
    C_10 to ~7 % within seconds), 16 batches. The measured C_10, C_01, C_11 and the variance
    agree with the linear theory of the batched collection (linear_theory, computed here from
    truth.json's a_ij table) within 4 of their sds (sampling sds of the estimator, computed
    from the data: a failure at 4 sd happens by chance 6e-5 of the time). To first order the
    theory is C_ij = a_ij mu^2 (1 - 1/B) and C_00 = mu + a_00 mu^2 (1 - 1/B). The test has
    power: C_10 and C_01 are > 8 sd from 0 and the variance deficit > 20 sd; C_11 > 1.5 sd.
    Charge: the frames' mean is the level within 5 Poisson sds (the area is conserved)."""
    bs = {k: 4 * v if k.startswith("strength") else v
          for k, v in load_module().BOUNDARY_SHIFT_DEFAULTS.items()}
    bs["batches"] = 16
    level = 3e4
    truth, _ = simulate(flat_config([level], bs, n=512, pairs_per_level=2), tmp_path, "flats")
    frames = []
    for rec in truth["flats"]:
        with fits.open(tmp_path / "flats" / rec["file"]) as hdul:
            frames.append(hdul[0].data.astype(np.float64) - hdul[0].header["BIASLVL"])
        assert abs(frames[-1].mean() - level) < 5 * math.sqrt(level / frames[-1].size)
    lags = [(0, 0), (1, 0), (0, 1), (1, 1)]
    pairs = [pair_covariances(frames[0], frames[1], lags), pair_covariances(frames[2], frames[3], lags)]
    mu = float(np.mean([f.mean() for f in frames]))
    table = np.array(truth["boundary_shift"]["a_table"])
    theory = linear_theory(table, mu, 16)
    a = truth["boundary_shift"]["a"]
    report = []
    for i, j in lags:
        c = 0.5 * (pairs[0][(i, j)][0] + pairs[1][(i, j)][0])
        sd = 0.5 * math.hypot(pairs[0][(i, j)][1], pairs[1][(i, j)][1])
        want = theory[j, i]
        first = a[f"a_{i}{j}"] * mu ** 2 * (1 - 1 / 16) + (mu if (i, j) == (0, 0) else 0.0)
        report.append(f"C_{i}{j} {c:.1f} theory {want:.1f} first order {first:.1f} sd {sd:.1f}")
        assert abs(c - want) < 4 * sd, report
        signal = abs(c - mu) if (i, j) == (0, 0) else abs(c)
        assert signal > {(0, 0): 20, (1, 0): 8, (0, 1): 8, (1, 1): 1.5}[(i, j)] * sd, report


def test_flats_files_and_fixed_pattern(tmp_path):
    """Flat files: one pair per level, EXPTIME = level / flux_e_per_s, the spot frames'
    keywords and 16-bit format; the same config gives the same bytes, and adding flats leaves
    the spot exposures as they were. The response pattern (prnu 0.03 and a gradient) is fixed:
    it is the same in both frames of a pair, so the pair's difference has the Poisson variance
    2 mu (within 5 sd), while one frame's variance exceeds mu by (0.03 mu)^2."""
    cfg = base_config()
    cfg["flats"] = {"levels_e": [2e3, 2e4], "prnu": 0.03, "gradient": [0.1, -0.05],
                    "flux_e_per_s": 4e3}
    cfg["detector"].update(nx=64, ny=48)
    truth, _ = simulate(cfg, tmp_path, "a")
    assert run_script(cfg, tmp_path / "b", tmp_path).returncode == 0
    assert digest(tmp_path / "a") == digest(tmp_path / "b")
    assert sorted(digest(tmp_path / "a")) == ["exposure_000.fits", "flat_000_0.fits", "flat_000_1.fits",
                                              "flat_001_0.fits", "flat_001_1.fits", "truth.json"]
    spots_only = base_config()
    spots_only["detector"].update(nx=64, ny=48)
    assert run_script(spots_only, tmp_path / "c", tmp_path).returncode == 0
    assert digest(tmp_path / "c")["exposure_000.fits"] == digest(tmp_path / "a")["exposure_000.fits"]
    for level, expected_time in [(0, 0.5), (1, 5.0)]:
        with fits.open(tmp_path / "a" / f"flat_{level:03d}_0.fits") as h0, \
                fits.open(tmp_path / "a" / f"flat_{level:03d}_1.fits") as h1:
            h = h0[0].header
            assert h["BITPIX"] == 16 and h["BZERO"] == 32768 and h0[0].data.shape == (48, 64)
            assert h["EXPTIME"] == pytest.approx(expected_time) and h["IMAGETYP"] == "FLAT"
            for key in ["GAIN", "RDNOISE", "BIASLVL", "SATURATE", "PIXSIZE", "WAVELEN"]:
                assert key in h
            a = h0[0].data.astype(np.float64) - 1000
            b = h1[0].data.astype(np.float64) - 1000
        mu = 0.5 * (a.mean() + b.mean())
        n = a.size
        assert abs(np.var(a - b) / 2 - mu) < 5 * mu * math.sqrt(2 / n)
        if level == 1:
            assert np.var(a) > mu + 0.5 * (0.03 * mu) ** 2


# ---------------------------------------------------------------------------------------------
# Files and errors


def digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_deterministic_and_readable(tmp_path):
    cfg = base_config()
    cfg["detector"].update(gain_e_per_adu=3.1, read_noise_e=4.5)
    cfg["exposures"].append(dict(cfg["exposures"][0], x_px=19.6, flux_e=3e4))
    assert run_script(cfg, tmp_path / "a", tmp_path).returncode == 0
    assert run_script(cfg, tmp_path / "b", tmp_path).returncode == 0
    a, b = digest(tmp_path / "a"), digest(tmp_path / "b")
    assert a == b and sorted(a) == ["exposure_000.fits", "exposure_001.fits", "truth.json"]
    cfg["seed"] = 12
    assert run_script(cfg, tmp_path / "c", tmp_path).returncode == 0
    assert digest(tmp_path / "c")["exposure_000.fits"] != a["exposure_000.fits"]
    # Exposure k does not depend on the exposures after it.
    cfg["seed"] = 11
    cfg["exposures"] = cfg["exposures"][:1]
    assert run_script(cfg, tmp_path / "d", tmp_path).returncode == 0
    assert digest(tmp_path / "d")["exposure_000.fits"] == a["exposure_000.fits"]
    with fits.open(tmp_path / "a" / "exposure_000.fits") as hdul:
        h = hdul[0].header
        assert h["BITPIX"] == 16 and h["BZERO"] == 32768 and hdul[0].data.dtype == np.uint16
        for key, value in [("GAIN", 3.1), ("RDNOISE", 4.5), ("BIASLVL", 1000), ("SATURATE", 65535),
                           ("WAVELEN", 800), ("EXPTIME", 1.0), ("PIXSIZE", 12)]:
            assert h[key] == value
        assert hdul[0].data.shape == (40, 40)
        bright = np.unravel_index(np.argmax(hdul[0].data), (40, 40))
        assert bright == (20, 20)


def mutate(path, value):
    """base_config() with the key at `path` (a list of keys) set to value, or deleted if None."""
    cfg = base_config()
    obj = cfg
    for key in path[:-1]:
        obj = obj[key]
    if value is None:
        del obj[path[-1]]
    else:
        obj[path[-1]] = value
    return cfg


BAD = [
    ("missing key", mutate(["detector", "gain_e_per_adu"], None), "gain_e_per_adu: missing"),
    ("unknown key", mutate(["optics", "airy_radius"], 0.5), 'unknown key "airy_radius"'),
    ("negative", mutate(["optics", "ccd_sigma_x_px"], -0.1), "ccd_sigma_x_px"),
    ("zero gain", mutate(["detector", "gain_e_per_adu"], 0), "gain_e_per_adu"),
    ("bad kind", mutate(["optics", "defocus"], {"kind": "donut", "sigma_px": 1}), "defocus.kind"),
    ("pillbox key", mutate(["optics", "defocus"], {"kind": "pillbox", "sigma_px": 1}), "radius_px"),
    ("spot outside", mutate(["exposures", 0, "x_px"], 45.0), "x_px"),
    ("no exposures", mutate(["exposures"], []), "exposures"),
    ("string number", mutate(["seed"], "11"), "seed"),
    ("boolean", mutate(["detector", "nx"], True), "nx"),
    ("width 0", mutate(["pixel_response"], {"kind": "box", "width_px": 0}), "width_px"),
    ("intrapixel", mutate(["pixel_response"], {"kind": "intrapixel"}), "edge_sensitivity: missing"),
    ("bf unknown", mutate(["brighter_fatter"], {"strength": 1e-6, "k": 1}), 'unknown key "k"'),
    ("not json", "{not json", "not valid JSON"),
    ("top unknown", mutate(["model"], {}), 'unknown key "model"'),
    ("bs and bf", mutate(["boundary_shift"], {}) | {"brighter_fatter": {"strength": 1e-6}}, "exclusive"),
    ("bs unknown", mutate(["boundary_shift"], {"strength": 1e-7}), 'unknown key "strength"'),
    ("bs range", mutate(["boundary_shift"], {"range_px": 0}), "range_px"),
    ("flat level", mutate(["flats"], {"levels_e": [1e3, -5]}), "levels_e[1]"),
    ("flat no levels", mutate(["flats"], {"prnu": 0.01}), "levels_e: missing"),
    ("flat gradient", mutate(["flats"], {"levels_e": [1e3], "gradient": [0.1]}), "gradient"),
    ("bs too strong", mutate(["boundary_shift"], {"strength_x": 1e-3}), "moved by"),
]


@pytest.mark.parametrize("label,cfg,needle", BAD, ids=[b[0] for b in BAD])
def test_errors_are_one_line(tmp_path, label, cfg, needle):
    out = tmp_path / "out"
    res = run_script(cfg, out, tmp_path)
    assert res.returncode == 2
    assert res.stdout == ""
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and needle in lines[0], res.stderr
    assert not out.exists() or not any(out.iterdir())


def test_missing_config_and_usage(tmp_path):
    res = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "nope.json"), str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1 and "no such file" in res.stderr
    res = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1


def test_failed_write_leaves_no_temporary_files(tmp_path):
    """A file that cannot be put in place: one line, exit 2, no temporary file left behind."""
    out = tmp_path / "out"
    (out / "truth.json").mkdir(parents=True)  # a folder where truth.json must go
    res = run_script(base_config(), out, tmp_path)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
