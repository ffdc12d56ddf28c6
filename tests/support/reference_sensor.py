#!/usr/bin/env python3
"""Reference CCD spot simulator by photon shooting, independent of ccdpsf.

    /usr/bin/python3 tests/support/reference_sensor.py CONFIG.json OUTDIR

Writes OUTDIR/exposure_000.fits, exposure_001.fits, ... (one per entry of "exposures") and
OUTDIR/truth.json. The point is test data made by physics that ccdpsf did not make: this
script shares no code with it (numpy, scipy.special and astropy only) and does not integrate
the PSF over pixels at all. It follows single photons and electrons and counts where they end.

Conventions (those of ccdpsf): frame coordinates are 0-based with pixel centres at integers,
x = column (NAXIS1), y = row, numpy index data[y, x]; pixel (i, j) collects what lands in
[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5). All lengths are in pixels unless a name says um.

CONFIG.json (every key below; an unknown key anywhere is an error)
---------------------------------------------------------------------
seed                      integer >= 0. Exposure k uses numpy.random.default_rng([seed, k]),
                          so adding exposures does not change the earlier ones.
detector                  (all required)
  gain_e_per_adu          > 0 [e-/ADU], written as GAIN (ccdpsf's demo: 3.1)
  read_noise_e            >= 0 [e-] rms Gaussian read noise, written as RDNOISE (4.5)
  bias_adu                0..65535 [ADU], written as BIASLVL (1000)
  pixel_um                > 0 [um], written as PIXSIZE (12)
  saturation_adu          1..65535 [ADU], written as SATURATE (65535). Only a keyword: no
                          full well or blooming is simulated; values are clipped at 65535.
  nx, ny                  integers 1..4096: frame width (columns) and height (rows) [px]
optics                    (all required)
  airy_radius_px          >= 0: radius r0 of the Airy pattern's first dark ring [px]; the
                          intensity is I(r) ~ [2 J1(x) / x]^2 with x = pi r Rz / r0,
                          Rz = 1.2196698912665045 (astropy's AiryDisk2D convention).
                          0 means no diffraction (a point).
  defocus                 {"kind": "gaussian", "sigma_px": s >= 0}: a circular Gaussian; or
                          {"kind": "pillbox", "radius_px": R >= 0}: a uniform disc of radius
                          R (geometric defocus; per-axis second moment R^2 / 4).
  ccd_sigma_x_px,         >= 0: charge diffusion, a Gaussian displacement of each
  ccd_sigma_y_px          photo-electron along x and y [px] (before brighter-fatter).
pixel_response            optional; default {"kind": "box", "width_px": 1}
  kind                    "box" or "intrapixel"
  width_px                (both kinds, optional, default 1) 0 < w <= 1: only electrons landing
                          in the central w x w square of a pixel are collected; the others are
                          lost (not moved to another pixel). Flat light: fraction w^2 kept.
  edge_sensitivity        ("intrapixel" only, required there) 0 <= f <= 1: the probability of
                          collecting an electron landing at offset (u, v) from the pixel
                          centre is s(u) s(v), s(t) = 1 - 2 (1 - f) |t| for |t| <= 1/2
                          (1 at the centre, f at the edges; linear). Flat light: ((1 + f)/2)^2.
brighter_fatter           optional; default strength 0 (off)
  strength                k >= 0 [1/e-], see "Brighter-fatter" below
  batches                 integer 1..10000, default 100: the number of collection batches
exposures                 non-empty list of objects, each with (all required)
  flux_e                  0..2e8: mean number of photo-electrons (photons; QE = 1) [e-]
  x_px, y_px              the spot's true centre in frame coordinates, inside the frame
                          (-0.5 <= x <= nx - 0.5, same for y)
  exptime_s               >= 0 [s], written as EXPTIME (metadata only)
  wavelength_nm           > 0 [nm], written as WAVELEN (metadata only: the Airy radius is
                          airy_radius_px whatever the wavelength)

Physics, per exposure
---------------------
1. N ~ Poisson(flux_e) photons. They are processed in B batches (B = brighter_fatter.batches,
   default 100, raised so that no batch exceeds 250 000 photons) of sizes differing by <= 1.
2. Each photon lands at centre + a + d, where
   a  Airy: a uniform angle and a radius drawn by inverse CDF from the encircled energy
      EE(x) = 1 - J0(x)^2 - J1(x)^2 (Lord Rayleigh's closed form of the integral of I), x as
      above. EE is tabulated on a grid of step 0.005 in x (about 0.0006 px for r0 = 0.47) out
      to 30 dark-ring radii (x_max = 30 pi Rz = 114.95) and inverted by linear interpolation.
      The light beyond the table, 1 - EE(x_max) = J0^2 + J1^2 = 0.553 % of the total, is NOT
      dropped: it is drawn from the ring-averaged envelope of the tail, 1 - EE(x) =
      (1 - EE(x_max)) x_max / x for x > x_max (the leading asymptotic term of J0^2 + J1^2 is
      2 / (pi x), with oscillating relative corrections ~ 1/(8x) < 0.2 % there; the rings,
      0.39 px apart for r0 = 0.47, are averaged away in that 0.55 %). So no light is lost by
      truncation; light that lands outside the frame is lost, and counted (truth.json).
   d  defocus: (s z1, s z2) with standard normals z (Gaussian); R sqrt(u) at a uniform angle
      (pillbox).
   This point is where the photon converts to an electron ("conversion point").
3. Charge diffusion: the electron moves by (sx f z3, sy f z4), z standard normals,
   sx, sy = ccd_sigma_x_px, ccd_sigma_y_px, and f the brighter-fatter factor (1 when off).
4. Pixel response: the landing point's pixel is (floor(x + 1/2), floor(y + 1/2)); outside the
   frame the electron is lost; inside, the pixel_response rule keeps it or loses it (a uniform
   draw against the collection probability for "intrapixel").
5. Per pixel: electrons + Normal(0, read_noise_e), / gain + bias_adu, rounded to the nearest
   integer (halves up), clipped to [0, 65535], written as 16-bit unsigned (BZERO 32768).

Brighter-fatter: collected charge broadens the diffusion of later electrons
----------------------------------------------------------------------------
Electrons are collected batch by batch; Q is the map of electrons already collected in each
pixel [e-] (batches before the current one). An electron converting at point p diffuses with

    f = sqrt(1 + k Q(p)),   sigma_x,eff = sx f,   sigma_y,eff = sy f,

i.e. its diffusion variance grows in proportion to the charge already held around its
conversion point: Var = s^2 (1 + k Q). Q(p) is the bilinear interpolation of the charge map
between pixel centres (0 outside the frame). Picture: the charge in a well weakens the field
that collects new electrons above it, so they drift longer and spread further, away from the
bright pixels into their neighbours. k [1/e-] is the fractional growth of the diffusion
variance per electron already collected there (k = 1e-6: +10 % variance under 1e5 e-).
Measured with this script on the paper's PSF (airy 0.47, Gaussian defocus 0.41, CCD 0.291 /
0.335 px; the peak pixel holds ~0.36 of the flux), paired with k = 0 on the same seed:
k = 6e-6 widens the defocus + diffusion width by 3.4 % in x and 4.1 % in y from 2e4 to 4e5 e-
(peak 7e3 to 1.4e5 e-), k = 7e-6 by 4.0 % / 4.7 %, k = 1e-5 by ~5.6 % / 6.6 %; the growth is
close to linear in the peak signal. The result is the same for 50 to 400 batches.
The broadening is strongest where the charge is (the core), so the profile changes shape
as well as width: it is not exactly a wider Gaussian.
The model only moves electrons: none is created or destroyed by it (the same photons, the same
random draws; only the displacement's length changes), so charge is conserved. With k = 0,
f = sqrt(1 + 0) = 1 exactly and the output is bit for bit the run without brighter_fatter.
Both axes grow by the same factor, so sx / sy is kept. truth.json reports, per exposure, the
mean f over the collected electrons and the second moments (below), from which the growth of
the width with flux can be read off directly.

truth.json
----------
The resolved configuration, the Airy sampling table's parameters, and per exposure: the file,
the true centre, photons drawn, electrons collected / lost outside the frame / lost to the
pixel response, the brightest pixel and its collected electrons (before noise), the number of
pixels clipped at 0 or 65535 and at or above saturation_adu, the brighter-fatter factor's mean
and maximum, and `photon_moments`: the mean offsets and standard deviations (px) of the
collected electrons' exact landing points (before pixelisation), measured from the photons
themselves, with the displacement split into its parts:
  position                landing point - centre (everything). Its width includes the Airy
                          wings, whose second moment diverges (the tail of EE ~ 1/r): it
                          depends on the frame size; not a PSF width.
  defocus_plus_diffusion  d + diffusion displacement: the Gaussian-kernel part, to compare
                          with ccdpsf's total_sigma_x_px / total_sigma_y_px (defocus and CCD
                          widths in quadrature; a pillbox counted as R^2 / 4 per axis). This
                          is the ground truth of "the width" for brighter-fatter tests.
  diffusion               the diffusion displacement alone (sx f z3, sy f z4).
  defocus                 d alone.
  airy                    a alone (frame-dependent, as for position).
Also `expected_plain`: the defocus_plus_diffusion and diffusion widths without brighter-fatter.

Errors (a bad config, a missing key, a value out of range, an unwritable OUTDIR) are one line
on stderr and exit code 2. Every output is written under a temporary name in OUTDIR and
renamed when complete, truth.json last, so no file is ever half-written. The output depends
only on CONFIG.json (same seed, same bytes).
"""

import json
import math
import os
import sys

import numpy as np
from astropy.io import fits
from scipy import special

RZ = 1.2196698912665045  # first zero of J1 / pi: Airy radius in units of lambda F#
TABLE_DARK_RINGS = 30.0  # the EE table reaches this many dark-ring radii
TABLE_STEP_X = 0.005  # table step in x = pi Rz r / r0
MAX_BATCH_PHOTONS = 250_000  # memory bound per batch
MAX_FLUX_E = 2e8
ADU_MAX = 65535


class ConfigError(Exception):
    """A problem with the configuration or the output folder: one line, exit code 2."""


# --------------------------------------------------------------------------------------------
# Configuration


class Section:
    """A JSON object being read: every key must be taken, unknown keys are errors."""

    def __init__(self, obj, where):
        if not isinstance(obj, dict):
            raise ConfigError(f"{where}: expected a JSON object")
        self.obj, self.where, self.taken = obj, where, set()

    def has(self, key):
        return key in self.obj

    def raw(self, key, required=True, default=None):
        self.taken.add(key)
        if key not in self.obj:
            if required:
                raise ConfigError(f"{self.where}.{key}: missing")
            return default
        return self.obj[key]

    def number(self, key, lo=None, hi=None, lo_open=False, required=True, default=None):
        value = self.raw(key, required, default)
        name = f"{self.where}.{key}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{name}: expected a number, got {json.dumps(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{name}: not finite")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            raise ConfigError(f"{name} = {value:g} is out of range (must be {'>' if lo_open else '>='} {lo:g})")
        if hi is not None and value > hi:
            raise ConfigError(f"{name} = {value:g} is out of range (must be <= {hi:g})")
        return value

    def integer(self, key, lo, hi, required=True, default=None):
        value = self.raw(key, required, default)
        name = f"{self.where}.{key}"
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name}: expected an integer, got {json.dumps(value)}")
        if not lo <= value <= hi:
            raise ConfigError(f"{name} = {value} is out of range ({lo}..{hi})")
        return value

    def section(self, key, required=True):
        value = self.raw(key, required, None)
        return None if value is None else Section(value, f"{self.where}.{key}")

    def kind(self, key, choices):
        value = self.raw(key)
        if value not in choices:
            raise ConfigError(f"{self.where}.{key}: {json.dumps(value)} is not one of {', '.join(choices)}")
        return value

    def done(self):
        unknown = sorted(set(self.obj) - self.taken)
        if unknown:
            raise ConfigError(f"{self.where}: unknown key {json.dumps(unknown[0])}")


def read_config(path):
    """CONFIG.json -> a plain dict with every default filled in (see the module docstring)."""
    try:
        with open(path, encoding="utf-8") as f:
            obj = json.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read ({err})") from None
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path}: not valid JSON ({err.msg} at line {err.lineno})") from None
    top = Section(obj, "config")
    cfg = {"seed": top.integer("seed", 0, 2**63 - 1)}

    det = top.section("detector")
    cfg["detector"] = {
        "gain_e_per_adu": det.number("gain_e_per_adu", 0.0, lo_open=True),
        "read_noise_e": det.number("read_noise_e", 0.0),
        "bias_adu": det.number("bias_adu", 0.0, ADU_MAX),
        "pixel_um": det.number("pixel_um", 0.0, lo_open=True),
        "saturation_adu": det.number("saturation_adu", 1.0, ADU_MAX),
        "nx": det.integer("nx", 1, 4096),
        "ny": det.integer("ny", 1, 4096),
    }
    det.done()

    opt = top.section("optics")
    optics = {"airy_radius_px": opt.number("airy_radius_px", 0.0, 1000.0)}
    dfc = opt.section("defocus")
    kind = dfc.kind("kind", ["gaussian", "pillbox"])
    if kind == "gaussian":
        optics["defocus"] = {"kind": kind, "sigma_px": dfc.number("sigma_px", 0.0, 1000.0)}
    else:
        optics["defocus"] = {"kind": kind, "radius_px": dfc.number("radius_px", 0.0, 1000.0)}
    dfc.done()
    optics["ccd_sigma_x_px"] = opt.number("ccd_sigma_x_px", 0.0, 1000.0)
    optics["ccd_sigma_y_px"] = opt.number("ccd_sigma_y_px", 0.0, 1000.0)
    opt.done()
    cfg["optics"] = optics

    resp = top.section("pixel_response", required=False)
    if resp is None:
        cfg["pixel_response"] = {"kind": "box", "width_px": 1.0}
    else:
        kind = resp.kind("kind", ["box", "intrapixel"])
        pr = {"kind": kind,
              "width_px": resp.number("width_px", 0.0, 1.0, lo_open=True, required=False, default=1.0)}
        if kind == "intrapixel":
            pr["edge_sensitivity"] = resp.number("edge_sensitivity", 0.0, 1.0)
        resp.done()
        cfg["pixel_response"] = pr

    bf = top.section("brighter_fatter", required=False)
    if bf is None:
        cfg["brighter_fatter"] = {"strength": 0.0, "batches": 100}
    else:
        cfg["brighter_fatter"] = {"strength": bf.number("strength", 0.0, 1.0),
                                  "batches": bf.integer("batches", 1, 10000, required=False, default=100)}
        bf.done()

    exposures = top.raw("exposures")
    if not isinstance(exposures, list) or not exposures:
        raise ConfigError("config.exposures: expected a non-empty list")
    if len(exposures) > 1000:
        raise ConfigError("config.exposures: more than 1000 exposures")
    nx, ny = cfg["detector"]["nx"], cfg["detector"]["ny"]
    cfg["exposures"] = []
    for k, e in enumerate(exposures):
        s = Section(e, f"config.exposures[{k}]")
        cfg["exposures"].append({
            "flux_e": s.number("flux_e", 0.0, MAX_FLUX_E),
            "x_px": s.number("x_px", -0.5, nx - 0.5),
            "y_px": s.number("y_px", -0.5, ny - 0.5),
            "exptime_s": s.number("exptime_s", 0.0),
            "wavelength_nm": s.number("wavelength_nm", 0.0, lo_open=True),
        })
        s.done()
    top.done()
    return cfg


# --------------------------------------------------------------------------------------------
# Sampling


class AiryRadii:
    """Inverse-CDF sampler of the Airy pattern's radius [px] (see the docstring, step 2a)."""

    def __init__(self, r0):
        self.r0 = r0
        self.x_max = TABLE_DARK_RINGS * math.pi * RZ
        x = np.arange(0.0, self.x_max + 0.5 * TABLE_STEP_X, TABLE_STEP_X)
        x[-1] = self.x_max
        ee = 1.0 - special.j0(x) ** 2 - special.j1(x) ** 2
        ee[0] = 0.0
        # EE is non-decreasing; keep strictly increasing nodes for the inversion (at a dark
        # ring dEE/dx ~ (x - x0)^2, so neighbouring values may agree to rounding).
        keep = np.concatenate(([True], np.diff(np.maximum.accumulate(ee)) > 0))
        self.ee, self.x = ee[keep], x[keep]
        self.ee_max = float(self.ee[-1])
        self.beyond = 1.0 - self.ee_max  # fraction of light beyond the table
        self.px_per_x = r0 / (math.pi * RZ)

    def draw(self, u):
        """Radii [px] for uniform draws u in [0, 1)."""
        if self.r0 == 0.0:
            return np.zeros_like(u)
        x = np.interp(u, self.ee, self.x)
        tail = u > self.ee_max
        if np.any(tail):
            x[tail] = self.x_max * self.beyond / (1.0 - u[tail])
        return x * self.px_per_x

    def describe(self):
        return {"method": "inverse CDF of EE(x) = 1 - J0(x)^2 - J1(x)^2, x = pi Rz r / r0",
                "Rz": RZ, "table_step_x": TABLE_STEP_X, "table_nodes": int(self.x.size),
                "table_radius_dark_rings": TABLE_DARK_RINGS,
                "table_radius_px": TABLE_DARK_RINGS * self.r0,
                "fraction_beyond_table": self.beyond,
                "beyond_table": "drawn from the envelope 1 - EE = (1 - EE(x_max)) x_max / x "
                                "(nothing dropped)"}


def bilinear(charge, x, y):
    """The charge map [e-] interpolated bilinearly at (x, y) between pixel centres; 0 outside."""
    ny, nx = charge.shape
    pad = np.zeros((ny + 2, nx + 2))
    pad[1:-1, 1:-1] = charge
    q = np.zeros_like(x)
    inside = (x >= -1.0) & (x < nx) & (y >= -1.0) & (y < ny)
    xs, ys = x[inside], y[inside]
    i0, j0 = np.floor(xs), np.floor(ys)
    tx, ty = xs - i0, ys - j0
    i = i0.astype(np.int64) + 1  # index into pad
    j = j0.astype(np.int64) + 1
    q[inside] = ((1 - ty) * ((1 - tx) * pad[j, i] + tx * pad[j, i + 1])
                 + ty * ((1 - tx) * pad[j + 1, i] + tx * pad[j + 1, i + 1]))
    return q


class Moments:
    """Running first and second moments of 2-D displacements [px]."""

    def __init__(self):
        self.n = 0
        self.s = np.zeros(4)  # sum x, sum y, sum x^2, sum y^2

    def add(self, dx, dy):
        self.n += dx.size
        self.s += [dx.sum(), dy.sum(), (dx * dx).sum(), (dy * dy).sum()]

    def result(self):
        if self.n == 0:
            return {"mean_x_px": None, "mean_y_px": None, "sigma_x_px": None, "sigma_y_px": None}
        mx, my = self.s[0] / self.n, self.s[1] / self.n
        vx, vy = self.s[2] / self.n - mx * mx, self.s[3] / self.n - my * my
        return {"mean_x_px": mx, "mean_y_px": my,
                "sigma_x_px": math.sqrt(max(vx, 0.0)), "sigma_y_px": math.sqrt(max(vy, 0.0))}


def simulate_exposure(cfg, index, airy):
    """One exposure: (electron map [e-, int64], ADU image [uint16], truth dict)."""
    det, opt = cfg["detector"], cfg["optics"]
    resp, bf = cfg["pixel_response"], cfg["brighter_fatter"]
    exp = cfg["exposures"][index]
    nx, ny = det["nx"], det["ny"]
    rng = np.random.default_rng([cfg["seed"], index])
    x0, y0 = exp["x_px"], exp["y_px"]
    sx, sy = opt["ccd_sigma_x_px"], opt["ccd_sigma_y_px"]
    k = bf["strength"]
    half_w = 0.5 * resp["width_px"]
    defocus = opt["defocus"]

    n_photons = int(rng.poisson(exp["flux_e"]))
    n_batches = max(bf["batches"], -(-n_photons // MAX_BATCH_PHOTONS))
    sizes = [n_photons // n_batches + (1 if b < n_photons % n_batches else 0) for b in range(n_batches)]

    charge = np.zeros((ny, nx))  # collected electrons so far (float: exact below 2^53)
    parts = {name: Moments() for name in
             ("position", "defocus_plus_diffusion", "diffusion", "defocus", "airy")}
    lost_frame = lost_response = 0
    f_sum, f_max = 0.0, 1.0
    for n in sizes:
        if n == 0:
            continue
        # The draws, always in this order, whatever the strengths.
        u_airy, phi_airy = rng.random(n), rng.random(n)
        d_draw = rng.standard_normal((2, n)) if defocus["kind"] == "gaussian" else rng.random((2, n))
        z = rng.standard_normal((2, n))
        u_resp = rng.random(n) if resp["kind"] == "intrapixel" else None

        r = airy.draw(u_airy)
        ax, ay = r * np.cos(2 * math.pi * phi_airy), r * np.sin(2 * math.pi * phi_airy)
        if defocus["kind"] == "gaussian":
            dx, dy = defocus["sigma_px"] * d_draw[0], defocus["sigma_px"] * d_draw[1]
        else:
            rd = defocus["radius_px"] * np.sqrt(d_draw[0])
            dx, dy = rd * np.cos(2 * math.pi * d_draw[1]), rd * np.sin(2 * math.pi * d_draw[1])
        cx, cy = x0 + ax + dx, y0 + ay + dy  # conversion points

        f = np.sqrt(1.0 + k * bilinear(charge, cx, cy))  # exactly 1 when k = 0
        gx, gy = sx * f * z[0], sy * f * z[1]
        px, py = cx + gx, cy + gy

        ix, iy = np.floor(px + 0.5), np.floor(py + 0.5)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        ux, uy = px - ix, py - iy  # offsets from the pixel centre, in [-1/2, 1/2)
        kept = inside & (np.abs(ux) <= half_w) & (np.abs(uy) <= half_w)
        if resp["kind"] == "intrapixel":
            fe = resp["edge_sensitivity"]
            prob = (1.0 - 2.0 * (1.0 - fe) * np.abs(ux)) * (1.0 - 2.0 * (1.0 - fe) * np.abs(uy))
            kept &= u_resp < prob
        lost_frame += int(np.count_nonzero(~inside))
        lost_response += int(np.count_nonzero(inside & ~kept))

        flat = iy[kept].astype(np.int64) * nx + ix[kept].astype(np.int64)
        charge += np.bincount(flat, minlength=nx * ny).reshape(ny, nx)

        fk = f[kept]
        f_sum += float(fk.sum())
        if fk.size:
            f_max = max(f_max, float(fk.max()))
        parts["position"].add(px[kept] - x0, py[kept] - y0)
        parts["defocus_plus_diffusion"].add(dx[kept] + gx[kept], dy[kept] + gy[kept])
        parts["diffusion"].add(gx[kept], gy[kept])
        parts["defocus"].add(dx[kept], dy[kept])
        parts["airy"].add(ax[kept], ay[kept])

    electrons = np.rint(charge).astype(np.int64)
    collected = int(electrons.sum())
    signal_e = electrons + rng.normal(0.0, det["read_noise_e"], size=(ny, nx))
    adu_float = np.floor(signal_e / det["gain_e_per_adu"] + det["bias_adu"] + 0.5)
    adu = np.clip(adu_float, 0, ADU_MAX).astype(np.uint16)

    peak_y, peak_x = np.unravel_index(int(np.argmax(electrons)), electrons.shape)
    truth = {
        "index": index,
        "true_centre": {"x_px": x0, "y_px": y0},
        "flux_e": exp["flux_e"], "exptime_s": exp["exptime_s"],
        "wavelength_nm": exp["wavelength_nm"],
        "photons_drawn": n_photons,
        "electrons_collected": collected,
        "lost_outside_frame": lost_frame,
        "lost_pixel_response": lost_response,
        "batches": sum(1 for n in sizes if n),
        "peak_pixel": {"x": int(peak_x), "y": int(peak_y), "electrons": int(electrons[peak_y, peak_x])},
        "pixels_clipped": int(np.count_nonzero((adu_float < 0) | (adu_float > ADU_MAX))),
        "pixels_at_or_above_saturation": int(np.count_nonzero(adu >= det["saturation_adu"])),
        "brighter_fatter_factor": {"mean": f_sum / collected if collected else 1.0, "max": f_max},
        "photon_moments": {name: m.result() for name, m in parts.items()},
    }
    return electrons, adu, truth


def expected_plain(cfg):
    """Widths [px] without brighter-fatter: diffusion, and defocus + diffusion in quadrature."""
    opt = cfg["optics"]
    d = opt["defocus"]
    d2 = d["sigma_px"] ** 2 if d["kind"] == "gaussian" else d["radius_px"] ** 2 / 4.0
    sx, sy = opt["ccd_sigma_x_px"], opt["ccd_sigma_y_px"]
    return {"diffusion": {"sigma_x_px": sx, "sigma_y_px": sy},
            "defocus_plus_diffusion": {"sigma_x_px": math.sqrt(d2 + sx * sx),
                                       "sigma_y_px": math.sqrt(d2 + sy * sy)}}


# --------------------------------------------------------------------------------------------
# Output


def fits_hdu(cfg, index, adu):
    det, exp = cfg["detector"], cfg["exposures"][index]
    hdu = fits.PrimaryHDU(data=adu)  # uint16 -> BITPIX 16, BZERO 32768
    h = hdu.header
    h["GAIN"] = (det["gain_e_per_adu"], "[e-/ADU]")
    h["RDNOISE"] = (det["read_noise_e"], "[e-] read noise")
    h["BIASLVL"] = (det["bias_adu"], "[ADU] bias level")
    h["SATURATE"] = (det["saturation_adu"], "[ADU] saturation level")
    h["WAVELEN"] = (exp["wavelength_nm"], "[nm]")
    h["EXPTIME"] = (exp["exptime_s"], "[s]")
    h["PIXSIZE"] = (det["pixel_um"], "[um]")
    h["CREATOR"] = ("reference_sensor.py", "photon-shooting reference simulator")
    h["SIMSEED"] = (cfg["seed"], "seed; exposure k uses default_rng([SIMSEED, k])")
    h["SIMINDEX"] = (index, "exposure index k")
    return hdu


def temp_name(outdir, name):
    return os.path.join(outdir, f".{name}.tmp.{os.getpid()}")


def run(config_path, outdir):
    cfg = read_config(config_path)
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"{outdir}: cannot create the output folder ({err.strerror})") from None
    if not os.access(outdir, os.W_OK):
        raise ConfigError(f"{outdir}: output folder not writable")

    airy = AiryRadii(cfg["optics"]["airy_radius_px"])
    temps = []  # (temporary path, final path)
    try:
        records = []
        for k in range(len(cfg["exposures"])):
            _, adu, truth = simulate_exposure(cfg, k, airy)
            name = f"exposure_{k:03d}.fits"
            truth["file"] = name
            tmp = temp_name(outdir, name)
            temps.append((tmp, os.path.join(outdir, name)))
            fits_hdu(cfg, k, adu).writeto(tmp, overwrite=True, checksum=False, output_verify="exception")
            records.append(truth)
        truth_all = {
            "generator": "tests/support/reference_sensor.py (photon shooting)",
            "config": cfg,
            "airy_sampling": airy.describe(),
            "expected_plain": expected_plain(cfg),
            "exposures": records,
        }
        tmp = temp_name(outdir, "truth.json")
        temps.append((tmp, os.path.join(outdir, "truth.json")))
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(truth_all, f, indent=1, sort_keys=False)
            f.write("\n")
        for tmp, final in temps:
            os.replace(tmp, final)
    except OSError as err:
        raise ConfigError(f"{outdir}: cannot write ({err.strerror or err})") from None
    finally:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.remove(tmp)
    return truth_all


def main(argv):
    if len(argv) != 3 or argv[1] in ("-h", "--help"):
        if len(argv) == 2 and argv[1] in ("-h", "--help"):
            print(__doc__)
            return 0
        print("usage: reference_sensor.py CONFIG.json OUTDIR", file=sys.stderr)
        return 2
    try:
        truth = run(argv[1], argv[2])
    except ConfigError as err:
        print(f"reference_sensor: {err}", file=sys.stderr)
        return 2
    summary = {"outdir": argv[2], "exposures": len(truth["exposures"]),
               "electrons_collected": [e["electrons_collected"] for e in truth["exposures"]]}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
