#!/usr/bin/env python3
"""Reference CCD spot simulator by photon shooting, independent of ccdpsf.

    /usr/bin/python3 tests/support/reference_sensor.py CONFIG.json OUTDIR

Writes OUTDIR/exposure_000.fits, exposure_001.fits, ... (one per entry of "exposures"),
OUTDIR/flat_LLL_F.fits (frame F of flat level LLL, when the config has "flats") and
OUTDIR/truth.json. The point is test data made by physics that ccdpsf did not make: this
script shares no code with it (numpy, scipy and astropy only) and does not integrate
the PSF over pixels at all. It follows single photons and electrons and counts where they end.
One sensor makes both spots and flats: the "boundary_shift" block below (brighter-fatter as
pixel boundaries moved by collected charge) acts on both, with known coefficients a_ij.

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
boundary_shift            optional (absent: off); exclusive with brighter_fatter.strength > 0.
                          See "Boundary shift" below; every key optional, defaults CCD273-like:
  strength_x              B_x >= 0 [px^(p+1) / e-], default 1.4e-7: vertical boundaries
                          (between columns; serial direction)
  strength_y              B_y >= 0 [px^(p+1) / e-], default 1.8e-7: horizontal boundaries
                          (between rows; parallel direction)
  power                   p in [1, 8], default 3
  softening_px            d in [0, 4] [px], default 0.5
  range_px                R, integer 1..32 [px], default 8: shifts beyond |m| > R neglected
  batches                 integer 1..10000, default 100: collection batches (spots and flats)
exposures                 list of spot exposures; required unless "flats" is given (then
                          optional, and "optics" with it). Non-empty, each with (all required)
  flux_e                  0..2e8: mean number of photo-electrons (photons; QE = 1) [e-]
  x_px, y_px              the spot's true centre in frame coordinates, inside the frame
                          (-0.5 <= x <= nx - 0.5, same for y)
  exptime_s               >= 0 [s], written as EXPTIME (metadata only)
  wavelength_nm           > 0 [nm], written as WAVELEN (metadata only: the Airy radius is
                          airy_radius_px whatever the wavelength)
flats                     optional: flat-field pairs (see "Flats" below)
  levels_e                list of 1..1000 mean levels [0, 1e7] [e- per pixel]; 0 makes a
                          bias pair (EXPTIME 0)
  pairs_per_level         integer 1..100, default 1: frames 2k and 2k + 1 of a level pair
  flux_e_per_s            > 0 [e- / s per pixel], default 1e4: EXPTIME = level / this
  gradient                [gx, gy], each in [-0.5, 0.5], default [0, 0]: the illumination
                          changes by the fraction gx across the frame's width (gy: height)
  prnu                    0..0.2, default 0: rms pixel response non-uniformity (fixed per
                          pixel, the same in every frame)
  wavelength_nm           > 0, default 800: WAVELEN (metadata only)
  batches                 integer 0..10000, default 0 (= boundary_shift.batches)

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

Boundary shift: pixel boundaries moved by the charge already collected
-----------------------------------------------------------------------
Brighter-fatter as a CCD makes it (Antilogus et al. 2014; Astier et al. 2019): the charge held
in a pixel repels the electrons still drifting towards the pixels, so it moves the pixel
boundaries towards itself: the charged pixel shrinks, its neighbours grow, and later charge
lands in the neighbours. The model: every pixel boundary segment (the side of one pixel
between two neighbours) is displaced rigidly along its unit normal n (+x for the vertical
boundaries between columns, +y for the horizontal ones between rows). For one electron held at
the centre of a pixel, a segment whose midpoint is m [px] from that centre moves by

    s = -B (m.n) / (|m|^2 + d^2)^((p + 1) / 2)   [px],   0 beyond |m| > R,

i.e. towards the charge, by B / |m|^p times the cosine of the angle between m and n far away
(p = 3: a charge and its image in the gate electrodes form a dipole, whose lateral field falls
faster than 1/r^2); d softens the near field (the stored charge is spread over the potential
well, not a point: without d the nearest boundaries, at |m| = 1/2, would dominate everything).
B is B_x for vertical and B_y for horizontal boundaries: the column boundaries are made by
channel stops, the row boundaries by the clock-gate potentials, so they are not equally stiff
(with B_x != B_y the displacement is not the gradient of a potential). The shifts of all
electrons add linearly.

Coefficients. a_ij [1/e-] (Astier et al. 2019): the fractional area change of pixel (i, j) per
electron in pixel (0, 0) = the sum over its four sides of their outward displacement (the
pixel's area to first order; corner patches are of second order). They follow exactly from
the kernel above (a_table; written to truth.json for |i|, |j| <= R), obey a_{-i,j} = a_{i,-j}
= a_ij, and obey the sum rule: every moved segment is gained by one pixel and lost by its
neighbour, and the cut |m| <= R moves only segments with both neighbours inside the table,
so the sum over all lags is 0 (to rounding). With the defaults: a_00 = -1.28e-6,
a_10 = 1.66e-7, a_01 = 2.55e-7, a_11 = 3.19e-8, a_20 = 1.64e-8, a_02 = 2.56e-8 per e-.

Why these defaults (a CCD273, 12 um pixels, as in Euclid VIS): a_00 ~ -1.3e-6 makes the
photon transfer curve of flats at 1.5e5 e- lie 17 % below Poisson ((1 - exp(2 a_00 mu)) /
(-2 a_00 mu) = 0.83; aimed at 10-20 %); the nearest neighbours take two thirds of the
charged pixel's loss, with a_10 and a_01 in 1e-7 .. 4e-7; a_01 / a_10 ~ 1.5 by choice (the
parallel direction's barriers are clocked potentials, softer than the channel stops);
a_11 / a_10 ~ 0.2, and the far lags fall as ~r^-(p+1).

Spot-width growth, on the paper's spot (airy 0.47, Gaussian defocus 0.41, CCD 0.291 / 0.335
px) with the defaults and 100 batches, paired with the same seed without the shift: the
defocus + diffusion + shift width (photon_moments below) grows from peak 7e3 to 1.6e5 e- by
4.5 % in x and 4.9 % in y for a spot centred on a pixel (the peak pixel holding 0.37 of the
flux); attributed to the CCD diffusion alone, 0.291 -> 0.330 px and 0.335 -> 0.378 px. Spots
off the pixel centre share their charge among more pixels and grow by 3.5-4 % in x and
4.3-5.6 % in y (testdata/reference_sensor/intensity_series.json; a series drifting along
x). The growth is close to linear in the peak signal.

Spots. Electrons are collected in the batches of step 1 (boundary_shift.batches). Before each
batch, the boundaries are displaced by the charge collected in the batches before it (exact
sequential accumulation: the first electrons see undistorted pixels, the last almost the full
distortion; the mean displacement seen lags the continuous limit by half a batch, a relative
1 / (2 batches) of the effect). Each electron's landing point (after diffusion) is then given
to the pixel whose displaced boundaries contain it: from its nominal pixel (step 4), it goes
right when it lies at or beyond that pixel's displaced right boundary in the nominal row,
left when below the displaced left boundary, and likewise up or down against the nominal
column's horizontal boundaries. Corner rule: a point beyond both a vertical and a horizontal
boundary goes to the diagonal pixel. The regions so defined tile the plane exactly (every
point goes to one pixel) and differ from the rectangles [left, right] x [bottom, top] of
each pixel's displaced sides only in corner patches of area |s_x s_y| (second order: < 2e-3
px^2 at peak 1.6e5 e-). Shifts are computed for the frame and a ring of one pixel around it
(an electron landing just outside may be collected by an edge pixel, and the reverse); a
shift above 0.5 px is an error (the nominal pixel's boundaries would no longer decide).
Nothing random is drawn for it: with both strengths 0 the output is bit for bit the run
without the block. The pixel response (step 4) is applied at the collected pixel's offset,
clipped to its edge. Charge is conserved: electrons are only reassigned.

Flats
-----
A "flats" block writes, for each level L (index l) and frame f = 0 .. 2 pairs - 1,
flat_LLL_F.fits (e.g. flat_003_1.fits), of the same size, keywords (GAIN, RDNOISE, BIASLVL,
SATURATE, PIXSIZE, WAVELEN, EXPTIME = L / flux_e_per_s; IMAGETYP = 'FLAT', FLATLVL = L) and
digitisation (step 5) as the spot frames. Frame f uses default_rng([seed, 61863, l, f]), so
the two frames of a pair are independent draws of the same illumination. The illumination of
pixel (x, y) is L (1 + gx (x - xc) / nx + gy (y - yc) / ny) (1 + prnu z_xy) (xc, yc the frame's
centre; z standard normals fixed by the seed, the same in every frame; clipped at 0), so that
an analysis must difference the pairs. Without a boundary shift each pixel holds
Poisson(illumination). With one, the frame is a window of a larger lit sensor: a margin of R
pixels on each side is simulated (and cut away), so that every frame pixel feels the charge
around it. Charge is collected in B batches (flats.batches, else boundary_shift.batches):
per batch each pixel receives Poisson(illumination / B x (1 + its area change)), the area
change being that of the charge collected in the earlier batches (sum_kl a_kl Q_{x-k,y-l},
by FFT; the same numbers as the sum of its sides' displacements). To first order the flat's
covariances are then C_ij = a_ij mu^2 (1 - 1/B) [e-^2] for (i, j) != (0, 0) and the variance
mu + a_00 mu^2 (1 - 1/B): the batches lag the charge by one (truth.json gives the factor).
Exactly, in the linear regime, the batch recursion gives in Fourier space
C^(k) = D ((1 + D a^(k))^(2B) - 1) / ((1 + D a^(k))^2 - 1), D = mu / B, which tends to
Astier et al.'s (exp(2 a^(k) mu) - 1) / (2 a^(k)) as B grows.

Examples
--------
An intensity series (12 exposures, peaks ~7e3 .. 1.6e5 e-) with the default boundary shift:

    {"seed": 1,
     "detector": {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000,
                  "pixel_um": 12, "saturation_adu": 65535, "nx": 48, "ny": 48},
     "optics": {"airy_radius_px": 0.47, "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335},
     "boundary_shift": {},
     "exposures": [{"flux_e": 2.2e4, "x_px": 24.1, "y_px": 23.9, "exptime_s": 0.11,
                    "wavelength_nm": 800}, ...]}

Flat pairs at 12 levels from 1e3 to 1.5e5 e- on 256 x 256 pixels, same sensor:

    {"seed": 1,
     "detector": {...as above, "nx": 256, "ny": 256},
     "boundary_shift": {},
     "flats": {"levels_e": [1e3, 2e3, 4e3, 8e3, 1.5e4, 2.5e4, 4e4, 6e4, 8e4, 1e5, 1.25e5,
                            1.5e5], "prnu": 0.01, "gradient": [0.02, -0.01]}}

testdata/reference_sensor/ holds both (intensity_series.json, flats.json):

    /usr/bin/python3 tests/support/reference_sensor.py \
        testdata/reference_sensor/flats.json /tmp/flats

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
With a boundary shift, photon_moments also has
  shift                   the reassignment steps (collected pixel - nominal pixel, 0 or +-1)
  defocus_plus_diffusion_plus_shift
                          defocus_plus_diffusion + shift: the Gaussian-kernel width as the
                          pixels see it (= defocus_plus_diffusion without the shift);
and each exposure's `boundary_shift` gives the electrons reassigned and the largest boundary
displacement [px]. The top-level `boundary_shift` block holds the parameters, the a_ij
("a": {"a_00":, "a_10":, ...} for 0 <= i, j <= R; "a_table" for -R..R; "a_sum_all_lags") and
the batches' first-order factors 1 - 1/B of spots and flats. Flats: `flats`, one record per
frame (file, level, exposure time, batches, mean electrons, mean illumination, clipped
pixels, largest boundary displacement in the frame), and `flat_margin_px`. The spot part
(airy_sampling, expected_plain, exposures) is there only when the config has exposures.

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
MAX_FLAT_LEVEL_E = 1e7
# Random streams of the flats: frame f of level l uses default_rng([seed, FLAT_STREAM, l, f]),
# the fixed response map default_rng([seed, FLAT_STREAM + 1]); spot exposure k uses [seed, k]
# with k < 1000, so no stream is shared.
FLAT_STREAM = 0xF1A7
# Boundary-shift defaults (CCD273-like, 12 um pixels; the docstring says why).
BOUNDARY_SHIFT_DEFAULTS = {"strength_x": 1.4e-7, "strength_y": 1.8e-7, "power": 3.0,
                           "softening_px": 0.5, "range_px": 8, "batches": 100}
MAX_BOUNDARY_SHIFT_PX = 0.5  # beyond it the nominal pixel's boundaries no longer decide


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

    # Spot exposures need the optics; a configuration of flats alone has neither.
    spots = top.has("exposures") or not top.has("flats")
    if spots:
        cfg["optics"] = read_optics(top.section("optics"))
    cfg["pixel_response"] = read_pixel_response(top.section("pixel_response", required=False))

    bf = top.section("brighter_fatter", required=False)
    if bf is None:
        cfg["brighter_fatter"] = {"strength": 0.0, "batches": 100}
    else:
        cfg["brighter_fatter"] = {"strength": bf.number("strength", 0.0, 1.0),
                                  "batches": bf.integer("batches", 1, 10000, required=False, default=100)}
        bf.done()

    bs = top.section("boundary_shift", required=False)
    if bs is not None:
        cfg["boundary_shift"] = read_boundary_shift(bs)
        if cfg["brighter_fatter"]["strength"] > 0:
            raise ConfigError("config.boundary_shift: exclusive with brighter_fatter.strength > 0 "
                              "(two brighter-fatter mechanisms at once)")

    nx, ny = cfg["detector"]["nx"], cfg["detector"]["ny"]
    if spots:
        cfg["exposures"] = read_exposures(top.raw("exposures"), nx, ny)
    fl = top.section("flats", required=False)
    if fl is not None:
        cfg["flats"] = read_flats(fl)
    top.done()
    return cfg


def read_optics(opt):
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
    return optics


def read_pixel_response(resp):
    if resp is None:
        return {"kind": "box", "width_px": 1.0}
    kind = resp.kind("kind", ["box", "intrapixel"])
    pr = {"kind": kind,
          "width_px": resp.number("width_px", 0.0, 1.0, lo_open=True, required=False, default=1.0)}
    if kind == "intrapixel":
        pr["edge_sensitivity"] = resp.number("edge_sensitivity", 0.0, 1.0)
    resp.done()
    return pr


def read_boundary_shift(bs):
    d = BOUNDARY_SHIFT_DEFAULTS
    out = {"strength_x": bs.number("strength_x", 0.0, 1e-3, required=False, default=d["strength_x"]),
           "strength_y": bs.number("strength_y", 0.0, 1e-3, required=False, default=d["strength_y"]),
           "power": bs.number("power", 1.0, 8.0, required=False, default=d["power"]),
           "softening_px": bs.number("softening_px", 0.0, 4.0, required=False, default=d["softening_px"]),
           "range_px": bs.integer("range_px", 1, 32, required=False, default=d["range_px"]),
           "batches": bs.integer("batches", 1, 10000, required=False, default=d["batches"])}
    bs.done()
    return out


def read_exposures(exposures, nx, ny):
    if not isinstance(exposures, list) or not exposures:
        raise ConfigError("config.exposures: expected a non-empty list")
    if len(exposures) > 1000:
        raise ConfigError("config.exposures: more than 1000 exposures")
    out = []
    for k, e in enumerate(exposures):
        s = Section(e, f"config.exposures[{k}]")
        out.append({
            "flux_e": s.number("flux_e", 0.0, MAX_FLUX_E),
            "x_px": s.number("x_px", -0.5, nx - 0.5),
            "y_px": s.number("y_px", -0.5, ny - 0.5),
            "exptime_s": s.number("exptime_s", 0.0),
            "wavelength_nm": s.number("wavelength_nm", 0.0, lo_open=True),
        })
        s.done()
    return out


def number_list(value, name, length_lo, length_hi, lo, hi, lo_open=False):
    """A JSON list of numbers, each in [lo, hi] ((lo, hi] with lo_open)."""
    if not isinstance(value, list) or not length_lo <= len(value) <= length_hi:
        raise ConfigError(f"{name}: expected a list of {length_lo}..{length_hi} numbers")
    out = []
    for k, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{name}[{k}]: expected a finite number, got {json.dumps(v)}")
        if v < lo or (lo_open and v == lo) or v > hi:
            raise ConfigError(f"{name}[{k}] = {v:g} is out of range ({lo:g}..{hi:g})")
        out.append(float(v))
    return out


def read_flats(fl):
    out = {"levels_e": number_list(fl.raw("levels_e"), "config.flats.levels_e", 1, 1000,
                                   0.0, MAX_FLAT_LEVEL_E),
           "pairs_per_level": fl.integer("pairs_per_level", 1, 100, required=False, default=1),
           "flux_e_per_s": fl.number("flux_e_per_s", 0.0, lo_open=True, required=False, default=1e4),
           "gradient": number_list(fl.raw("gradient", required=False, default=[0.0, 0.0]),
                                   "config.flats.gradient", 2, 2, -0.5, 0.5),
           "prnu": fl.number("prnu", 0.0, 0.2, required=False, default=0.0),
           # 0: boundary_shift.batches
           "batches": fl.integer("batches", 0, 10000, required=False, default=0),
           "wavelength_nm": fl.number("wavelength_nm", 0.0, lo_open=True, required=False, default=800.0)}
    fl.done()
    return out


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


# --------------------------------------------------------------------------------------------
# Boundary shift (see the docstring, "Boundary shift")


def boundary_shift_kernels(bs):
    """The displacements [px] of the boundaries around a unit charge: (kv, kh), each indexed
    [v + R, u + R] for the offset (u, v) [px] of the boundary's pixel from the charge's pixel.
    kv: the vertical boundary on the LEFT of pixel (u, v), midpoint m = (u - 1/2, v), moved
    along +x; kh: the horizontal boundary BELOW pixel (u, v), midpoint m = (u, v - 1/2), moved
    along +y. s = -B (m.n) / (|m|^2 + d^2)^((p + 1) / 2) for |m| <= R, else 0."""
    R, p, d = bs["range_px"], bs["power"], bs["softening_px"]
    off = np.arange(-R, R + 1, dtype=np.float64)
    v, u = np.meshgrid(off, off, indexing="ij")

    def shift(mx, my, mn, strength):
        r2 = mx * mx + my * my
        return np.where(r2 <= R * R, -strength * mn / (r2 + d * d) ** ((p + 1.0) / 2.0), 0.0)

    kv = shift(u - 0.5, v, u - 0.5, bs["strength_x"])
    kh = shift(u, v - 0.5, v - 0.5, bs["strength_y"])
    return kv, kh


def areas_from_shifts(sv, sh):
    """Fractional area change of each pixel: the outward displacements of its four sides.
    sv[r, k]: the vertical boundary left of column k in row r (k = 0..nx, column nx being the
    right edge); sh[k, c]: the horizontal boundary below row k in column c (k = 0..ny)."""
    return (sv[:, 1:] - sv[:, :-1]) + (sh[1:, :] - sh[:-1, :])


def a_table(bs):
    """a_ij [1/e-]: the fractional area change of pixel (i, j) per electron in pixel (0, 0),
    indexed [j + R, i + R]; exactly the charge's kernel applied to a unit charge."""
    kv, kh = boundary_shift_kernels(bs)
    # The boundaries right of column R and above row R do not move (|m| > R): a zero column
    # and a zero row close the table.
    sv = np.concatenate([kv, np.zeros((kv.shape[0], 1))], axis=1)
    sh = np.concatenate([kh, np.zeros((1, kh.shape[1]))], axis=0)
    return areas_from_shifts(sv, sh)


class ShiftField:
    """What a charge map [e-] of a fixed shape (ny, nx) does to the pixels: the boundary
    displacements [px] (fields) and the pixels' fractional area changes (areas). Both are
    linear in the charge, convolutions with the kernels (areas: with the a_ij table, the same
    numbers as areas_from_shifts of the fields), done by FFT with the kernels' transforms
    computed once; zero-padded, so no charge lies outside the map."""

    def __init__(self, bs, shape):
        from scipy import fft
        self.fft = fft
        self.R = bs["range_px"]
        self.ny, self.nx = shape
        full = (self.ny + 2 * self.R, self.nx + 2 * self.R)  # linear convolution's size
        self.fshape = tuple(fft.next_fast_len(n, real=True) for n in full)
        kv, kh = boundary_shift_kernels(bs)
        self.kv_f = fft.rfft2(kv, self.fshape)
        self.kh_f = fft.rfft2(kh, self.fshape)
        self.a_f = fft.rfft2(a_table(bs), self.fshape)

    def _apply(self, q, kernel_f, rows, cols):
        R = self.R
        return self.fft.irfft2(q * kernel_f, self.fshape)[R:R + rows, R:R + cols]

    def fields(self, charge):
        """(sv, sh) as in areas_from_shifts: sv (ny, nx + 1), sh (ny + 1, nx)."""
        q = self.fft.rfft2(charge, self.fshape)
        return (self._apply(q, self.kv_f, self.ny, self.nx + 1),
                self._apply(q, self.kh_f, self.ny + 1, self.nx))

    def areas(self, charge):
        """The fractional area change of every pixel (ny, nx)."""
        return self._apply(self.fft.rfft2(charge, self.fshape), self.a_f, self.ny, self.nx)


def assign_displaced(px, py, sv, sh, nx, ny):
    """Pixel indices (ix, iy) of landing points under displaced boundaries, and the steps
    (ix - ix0, iy - iy0) from their nominal pixels; sv, sh are the fields of the frame padded
    by one pixel on every side (a point landing just outside the frame may be collected by an
    edge pixel whose boundary moved out, and the reverse). A point goes right when it lies at
    or beyond its nominal pixel's displaced right boundary in the nominal row, left when below
    the displaced left boundary; up and down likewise with the nominal column's horizontal
    boundaries. Both at once: the diagonal pixel."""
    ix0, iy0 = np.floor(px + 0.5), np.floor(py + 0.5)
    ux, uy = px - ix0, py - iy0
    step_x, step_y = np.zeros(px.size), np.zeros(px.size)
    ring = (ix0 >= -1) & (ix0 <= nx) & (iy0 >= -1) & (iy0 <= ny)
    a = ix0[ring].astype(np.int64) + 1  # padded column
    b = iy0[ring].astype(np.int64) + 1  # padded row
    step_x[ring] = ((ux[ring] >= 0.5 + sv[b, a + 1]).astype(np.float64)
                    - (ux[ring] < -0.5 + sv[b, a]).astype(np.float64))
    step_y[ring] = ((uy[ring] >= 0.5 + sh[b + 1, a]).astype(np.float64)
                    - (uy[ring] < -0.5 + sh[b, a]).astype(np.float64))
    return ix0 + step_x, iy0 + step_y, step_x, step_y


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
    bs = cfg.get("boundary_shift")
    exp = cfg["exposures"][index]
    nx, ny = det["nx"], det["ny"]
    rng = np.random.default_rng([cfg["seed"], index])
    x0, y0 = exp["x_px"], exp["y_px"]
    sx, sy = opt["ccd_sigma_x_px"], opt["ccd_sigma_y_px"]
    k = bf["strength"]
    half_w = 0.5 * resp["width_px"]
    defocus = opt["defocus"]

    n_photons = int(rng.poisson(exp["flux_e"]))
    n_batches = max((bs or bf)["batches"], -(-n_photons // MAX_BATCH_PHOTONS))
    sizes = [n_photons // n_batches + (1 if b < n_photons % n_batches else 0) for b in range(n_batches)]

    charge = np.zeros((ny, nx))  # collected electrons so far (float: exact below 2^53)
    parts = {name: Moments() for name in
             ("position", "defocus_plus_diffusion", "diffusion", "defocus", "airy")}
    if bs is not None:
        parts["defocus_plus_diffusion_plus_shift"] = Moments()
        parts["shift"] = Moments()
        field = ShiftField(bs, (ny + 2, nx + 2))  # the frame and a ring of one pixel
        moved, max_shift = 0, 0.0
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

        if bs is None:
            ix, iy = np.floor(px + 0.5), np.floor(py + 0.5)
        else:
            # The boundaries as displaced by the charge of the earlier batches.
            sv, sh = field.fields(np.pad(charge, 1))
            max_shift = max(max_shift, float(np.abs(sv).max()), float(np.abs(sh).max()))
            if max_shift > MAX_BOUNDARY_SHIFT_PX:
                raise ConfigError(f"exposure {index}: a pixel boundary moved by {max_shift:.2f} px "
                                  f"(> {MAX_BOUNDARY_SHIFT_PX}): boundary_shift strengths too large "
                                  "for this flux")
            ix, iy, step_x, step_y = assign_displaced(px, py, sv, sh, nx, ny)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        ux, uy = px - ix, py - iy  # offsets from the pixel centre, in [-1/2, 1/2)
        if bs is not None:
            # A point collected across a displaced boundary lies just beyond its pixel's
            # nominal edge: the response there is the edge's.
            ux, uy = np.clip(ux, -0.5, 0.5), np.clip(uy, -0.5, 0.5)
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
        if bs is not None:
            sx_k, sy_k = step_x[kept], step_y[kept]
            moved += int(np.count_nonzero((sx_k != 0) | (sy_k != 0)))
            parts["shift"].add(sx_k, sy_k)
            parts["defocus_plus_diffusion_plus_shift"].add(dx[kept] + gx[kept] + sx_k,
                                                           dy[kept] + gy[kept] + sy_k)

    electrons = np.rint(charge).astype(np.int64)
    collected = int(electrons.sum())
    adu, adu_float = digitise(electrons, det, rng)

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
    if bs is not None:
        truth["boundary_shift"] = {"electrons_moved": moved, "max_shift_px": max_shift}
    return electrons, adu, truth


def digitise(electrons, det, rng):
    """Electrons per pixel -> (ADU image [uint16], unclipped ADU [float]): read noise, gain,
    bias, rounding to the nearest integer (halves up), clipping to [0, 65535]."""
    signal_e = electrons + rng.normal(0.0, det["read_noise_e"], size=electrons.shape)
    adu_float = np.floor(signal_e / det["gain_e_per_adu"] + det["bias_adu"] + 0.5)
    return np.clip(adu_float, 0, ADU_MAX).astype(np.uint16), adu_float


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
# Flats (see the docstring, "Flats")


def flat_illumination(cfg, pad):
    """The fixed relative illumination of the flats' pixels, frame and margin (pad pixels on
    each side): the linear gradient times the pixel response non-uniformity, >= 0."""
    det, fl = cfg["detector"], cfg["flats"]
    nx, ny = det["nx"], det["ny"]
    y, x = np.mgrid[-pad:ny + pad, -pad:nx + pad].astype(np.float64)
    gx, gy = fl["gradient"]
    light = 1.0 + gx * (x - 0.5 * (nx - 1)) / nx + gy * (y - 0.5 * (ny - 1)) / ny
    if fl["prnu"] > 0:
        # The frame's values first, so that they do not depend on the margin.
        rng = np.random.default_rng([cfg["seed"], FLAT_STREAM + 1])
        z_frame = rng.standard_normal((ny, nx))
        z = rng.standard_normal(light.shape)
        z[pad:pad + ny, pad:pad + nx] = z_frame
        light = light * np.maximum(1.0 + fl["prnu"] * z, 0.0)
    return light


def shifts_active(cfg):
    """True when the boundary shift moves anything: a boundary_shift block with a strength
    > 0. With both strengths 0 the flats are drawn as without the block (bit for bit)."""
    bs = cfg.get("boundary_shift")
    return bs is not None and (bs["strength_x"] > 0 or bs["strength_y"] > 0)


def simulate_flat(cfg, level, frame, light, field):
    """One flat frame: (electron map [e-, int64], ADU image [uint16], truth dict). With a
    boundary shift, `field` is the ShiftField of the frame and its margin (light's shape)."""
    det, fl, bs = cfg["detector"], cfg["flats"], cfg.get("boundary_shift")
    nx, ny = det["nx"], det["ny"]
    rng = np.random.default_rng([cfg["seed"], FLAT_STREAM, level, frame])
    level_e = fl["levels_e"][level]
    pad = (light.shape[0] - ny) // 2
    if field is None:
        charge = rng.poisson(level_e * light).astype(np.float64)
        max_shift, n_batches = 0.0, 1
    else:
        n_batches = fl["batches"] or bs["batches"]
        per_batch = (level_e / n_batches) * light
        charge = np.zeros(light.shape)
        max_shift = 0.0
        for _ in range(n_batches):
            area = 1.0 + field.areas(charge)  # moved by the charge of the earlier batches
            charge += rng.poisson(per_batch * np.maximum(area, 0.0))
        # The largest displacement of a frame pixel's side, by the collected charge.
        sv, sh = field.fields(charge)
        sv, sh = sv[pad:pad + ny, pad:pad + nx + 1], sh[pad:pad + ny + 1, pad:pad + nx]
        max_shift = max(float(np.abs(sv).max()), float(np.abs(sh).max()))
        if max_shift > MAX_BOUNDARY_SHIFT_PX:
            raise ConfigError(f"flat level {level}: a pixel boundary moved by {max_shift:.2f} px "
                              f"(> {MAX_BOUNDARY_SHIFT_PX}): boundary_shift strengths too large")
    electrons = charge[pad:pad + ny, pad:pad + nx].astype(np.int64)
    adu, adu_float = digitise(electrons, det, rng)
    truth = {"level_index": level, "frame": frame, "level_e": level_e,
             "exptime_s": level_e / fl["flux_e_per_s"],
             "batches": n_batches,
             "mean_electrons": float(electrons.mean()),
             "mean_illumination": float(light[pad:pad + ny, pad:pad + nx].mean()),
             "pixels_clipped": int(np.count_nonzero((adu_float < 0) | (adu_float > ADU_MAX))),
             "pixels_at_or_above_saturation": int(np.count_nonzero(adu >= det["saturation_adu"])),
             "max_boundary_shift_px": max_shift}
    return electrons, adu, truth


def boundary_shift_truth(cfg):
    """truth.json's boundary_shift block: the kernel, the a_ij table and its checks."""
    bs = cfg["boundary_shift"]
    R = bs["range_px"]
    a = a_table(bs)
    named = {f"a_{i}{j}" if i < 10 and j < 10 else f"a_{i}_{j}": float(a[j + R, i + R])
             for j in range(R + 1) for i in range(R + 1)}
    n = bs["batches"]
    n_flat = cfg["flats"]["batches"] or n if "flats" in cfg else n
    return {"parameters": bs,
            "shift_px": "s = -B (m.n) / (|m|^2 + d^2)^((p + 1) / 2) per electron, |m| <= R",
            "a": named,
            "a_lags": "a_ij for 0 <= i, j <= range_px; a_{-i,j} = a_{i,-j} = a_ij "
                      "(i along x, j along y)",
            "a_sum_all_lags": float(a.sum()),
            "a_table": a.tolist(),
            "a_table_index": "a_table[j + range_px][i + range_px] = a_ij, -R <= i, j <= R",
            "batches_first_order_factor": 1.0 - 1.0 / n,
            "flat_batches_first_order_factor": 1.0 - 1.0 / n_flat}


# --------------------------------------------------------------------------------------------
# Output


def fits_hdu(cfg, adu, wavelength_nm, exptime_s):
    """The frame with the keywords every frame has (spot exposures and flats alike)."""
    det = cfg["detector"]
    hdu = fits.PrimaryHDU(data=adu)  # uint16 -> BITPIX 16, BZERO 32768
    h = hdu.header
    h["GAIN"] = (det["gain_e_per_adu"], "[e-/ADU]")
    h["RDNOISE"] = (det["read_noise_e"], "[e-] read noise")
    h["BIASLVL"] = (det["bias_adu"], "[ADU] bias level")
    h["SATURATE"] = (det["saturation_adu"], "[ADU] saturation level")
    h["WAVELEN"] = (wavelength_nm, "[nm]")
    h["EXPTIME"] = (exptime_s, "[s]")
    h["PIXSIZE"] = (det["pixel_um"], "[um]")
    h["CREATOR"] = ("reference_sensor.py", "photon-shooting reference simulator")
    return hdu


def exposure_hdu(cfg, index, adu):
    exp = cfg["exposures"][index]
    hdu = fits_hdu(cfg, adu, exp["wavelength_nm"], exp["exptime_s"])
    hdu.header["SIMSEED"] = (cfg["seed"], "seed; exposure k uses default_rng([SIMSEED, k])")
    hdu.header["SIMINDEX"] = (index, "exposure index k")
    return hdu


def flat_hdu(cfg, level, frame, adu):
    fl = cfg["flats"]
    level_e = fl["levels_e"][level]
    hdu = fits_hdu(cfg, adu, fl["wavelength_nm"], level_e / fl["flux_e_per_s"])
    h = hdu.header
    h["IMAGETYP"] = ("FLAT", "flat field")
    h["FLATLVL"] = (level_e, "[e-] mean level per pixel (illumination 1)")
    h["SIMSEED"] = (cfg["seed"], "seed; default_rng([SIMSEED, 61863, L, F])")
    h["SIMLEVEL"] = (level, "flat level index L")
    h["SIMFRAME"] = (frame, "frame F of the level; pairs (0, 1), (2, 3) ...")
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

    temps = []  # (temporary path, final path)

    def write_fits(hdu, name):
        tmp = temp_name(outdir, name)
        temps.append((tmp, os.path.join(outdir, name)))
        hdu.writeto(tmp, overwrite=True, checksum=False, output_verify="exception")

    try:
        truth_all = {"generator": "tests/support/reference_sensor.py (photon shooting)", "config": cfg}
        if "exposures" in cfg:
            airy = AiryRadii(cfg["optics"]["airy_radius_px"])
            records = []
            for k in range(len(cfg["exposures"])):
                _, adu, truth = simulate_exposure(cfg, k, airy)
                name = f"exposure_{k:03d}.fits"
                truth["file"] = name
                write_fits(exposure_hdu(cfg, k, adu), name)
                records.append(truth)
            truth_all.update({"airy_sampling": airy.describe(), "expected_plain": expected_plain(cfg),
                              "exposures": records})
        bs = cfg.get("boundary_shift")
        if bs is not None:
            truth_all["boundary_shift"] = boundary_shift_truth(cfg)
        if "flats" in cfg:
            pad = bs["range_px"] if shifts_active(cfg) else 0
            light = flat_illumination(cfg, pad)
            field = ShiftField(bs, light.shape) if shifts_active(cfg) else None
            flats = []
            for level in range(len(cfg["flats"]["levels_e"])):
                for frame in range(2 * cfg["flats"]["pairs_per_level"]):
                    _, adu, truth = simulate_flat(cfg, level, frame, light, field)
                    name = f"flat_{level:03d}_{frame}.fits"
                    truth["file"] = name
                    write_fits(flat_hdu(cfg, level, frame, adu), name)
                    flats.append(truth)
            truth_all["flat_margin_px"] = pad
            truth_all["flats"] = flats
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
    exposures = truth.get("exposures", [])
    summary = {"outdir": argv[2], "exposures": len(exposures),
               "electrons_collected": [e["electrons_collected"] for e in exposures]}
    if "flats" in truth:
        summary["flats"] = len(truth["flats"])
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
