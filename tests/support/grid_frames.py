#!/usr/bin/env python3
"""Full-sensor spot-grid frames with known truth, to test `ccdpsf grid` on data it did not make.

    /usr/bin/python3 tests/support/grid_frames.py OUTDIR [--size 4096] [--grid 7]
        [--exposures 3] [--seed 1] [--flux_e 4e5] [--focus_um a,b,c,...]
        [--defocus_px d1,d2,...] [--no_extras] [--wavelength_nm 800]

Writes OUTDIR/frame_000.fits, frame_001.fits, ... (one per exposure), OUTDIR/truth.csv (one
row per spot) and OUTDIR/truth.json. Shares no code with ccdpsf (numpy, scipy, astropy only):
each spot is photon-shot by tests/support/reference_sensor.py's `simulate_exposure`, which
follows single photons through the Airy pattern and the Gaussian defocus, single electrons
through charge diffusion, and counts them in box pixels (see that script's docstring).

Options
-------
--size N        frame width = height [px], 64..4096 (default 4096)
--grid G        G x G spots, 1..64, cells of size / G >= 41 px (default 7)
--exposures K   number of frames, 1..100 (default 3, or the length of --focus_um /
                --defocus_px; counts that disagree are an error)
--seed S        integer 0..2^63-1 (default 1)
--flux_e F      mean photo-electrons per spot (default 4e5)
--focus_um      FOCUSPOS per exposure [um], comma-separated (default: no FOCUSPOS)
--defocus_px    Gaussian defocus sigma per exposure [px], comma-separated, 0..10 (default 0.41
                in every exposure). Both lists also take a leading minus: --focus_um -50,0,50.
--no_extras     grid spots only (default: also the crowded pair and the edge spot)
--wavelength_nm W   wavelength [nm], 550..900 (default 800): WAVELEN, and the Airy radius and
                the diffusion widths follow it (see Widths). A campaign of several wavelengths
                is one run per wavelength, each into its own OUTDIR, with the same --seed: the
                layout is then the same at every wavelength, the noise differs (Randomness).

Conventions (those of ccdpsf and reference_sensor.py): frame coordinates are 0-based with
pixel centres at integers, x = column (NAXIS1), y = row, numpy index data[y, x]; the frame
covers [-0.5, size - 0.5) on each axis. Lengths are in pixels unless a name says um.

Detector (every frame): gain 3.1 e-/ADU (GAIN), read noise 4.5 e- rms (RDNOISE), bias
1000 ADU (BIASLVL), 12 um pixels (PIXSIZE), SATURATE 65535 ADU, WAVELEN = --wavelength_nm
[nm] (default 800), EXPTIME 1 s, and FOCUSPOS [um] when --focus_um is given. Per pixel:
collected electrons (Poisson through photon shooting) + Normal(0, 4.5 e-) read noise on every
pixel, / gain + bias, rounded to whole ADU (halves up), clipped to [0, 65535], written as
16-bit unsigned (BITPIX 16, BZERO 32768).

Spots
-----
- Grid: grid x grid spots, one at the centre of each cell of a regular grid over the frame
  (cell = size / grid px): column i, row j has its nominal centre at
  (-0.5 + (i + 1/2) cell, -0.5 + (j + 1/2) cell), plus a sub-pixel offset uniform in
  [-0.5, 0.5) px on each axis drawn once from the seed (the same in every exposure).
- Extras (unless --no_extras; need --grid >= 2 and cells >= 64 px): sources a grid tool must
  refuse, with a reason. They sit on the cell boundary y = Y = -0.5 + floor(grid / 2) cell,
  midway between two rows of grid spots, so each is >= cell / 2 - 1 px (>= 31 px) from every
  grid spot in y (sub-pixel offsets <= 0.5 px each).
  "crowded": two spots 5.0 px apart along x, both with the grid's flux, centred on (Y, Y) (the
  corner shared by four cells near the middle) plus one common sub-pixel offset from the seed.
  "edge": one spot whose centre is 3 px from the frame's left edge (x = 2.5: its 21 x 21 stamp
  would need columns -7 .. 13), at y = Y plus a sub-pixel offset drawn from the seed.
- Drift: in exposure k every spot sits at its exposure-0 position + (0.03 k, 0.02 k) px, a
  projector's slow drift. truth gives the exposure-0 positions and the drift per exposure.
- Widths, smooth over the sensor: with u = 2 (x + 0.5) / size - 1 and v = 2 (y + 0.5) / size - 1
  in [-1, 1) at the spot's exposure-0 centre, at 800 nm
      ccd_sigma_x_px = 0.29 + 0.05 u + 0.03 v^2      (0.24 .. 0.37)
      ccd_sigma_y_px = 0.33 + 0.04 v - 0.02 u^2      (0.27 .. 0.37)
  charge-diffusion widths (per spot, the same in every exposure: the drift is < 0.1 px).
  At wavelength W [nm] each width follows a power law in W, with an exponent smooth over the
  sensor too (red light converts deeper in the silicon, nearer the pixels, and diffuses less):
      ccd_sigma_x_px(u, v, W) = ccd_sigma_x_px(u, v) (W / 800)^alpha_x,  alpha_x = -0.25 + 0.10 u
      ccd_sigma_y_px(u, v, W) = ccd_sigma_y_px(u, v) (W / 800)^alpha_y,  alpha_y = -0.20 + 0.08 v
  (alpha_x in -0.35 .. -0.15, alpha_y in -0.28 .. -0.12). Over the sensor sigma_x spans
  0.274 .. 0.391 px at 550 nm and 0.230 .. 0.364 px at 900 nm, sigma_y 0.300 .. 0.387 and
  0.261 .. 0.365 px: inside 0.2 .. 0.45 px, which the script checks per spot, for every
  allowed W. At 800 nm the factor is exactly 1.0, so the widths are the 800 nm law's bits.
  Airy radius (first dark ring) 0.47 (W / 800) px everywhere (diffraction: 1.22 lambda F# /
  pixel; 0.47 px at 800 nm, 0.323 at 550, 0.529 at 900); defocus a circular Gaussian of sigma
  --defocus_px (one per exposure; default 0.41 px in every exposure, at every wavelength).
- Flux: --flux_e mean photo-electrons per spot (every spot; Poisson-drawn per exposure).
  Each spot is photon-shot inside its own 41 x 41 px box centred on the pixel nearest its
  centre and added into the frame; light landing beyond the box (the Airy wings beyond
  ~20 px: about 0.33 % of the flux for r0 = 0.47, 2 r0 / (pi^2 Rz r) asymptotically, so
  0.23 % at 550 nm and 0.37 % at 900 nm) or beyond the frame is lost; truth.json counts it
  per spot and exposure.
- Saturation: the set is refused (exit 2, nothing written) if any pixel's electrons before
  read noise come within 5 sd (Poisson + read noise) of SATURATE: bias + (e + 5 sqrt(e +
  rn^2)) / gain >= 65535. With the defaults the brightest pixel holds ~1.5e5 e- (~4.9e4 ADU);
  at 4e5 e- a defocus of 0.3 px still fits (1.9e5 e-) and 0.25 px does not: a through-focus set
  reaching best focus needs a lower --flux_e (e.g. 2e5). Across 550 .. 900 nm the peak
  changes by < 2 % (the sharper Airy core at short wavelengths is offset by wider diffusion).

Randomness (numpy default_rng, explicit seeds; the same options give the same bytes):
  layout (sub-pixel offsets)      default_rng([seed, 0])   (no wavelength: the same positions
                                                            at every --wavelength_nm)
  read noise of exposure k        default_rng([seed, 1, k] + w)
  photons of spot s, exposure k   reference_sensor.simulate_exposure with config seed
                                  SeedSequence([seed, 2, k, s] + w).generate_state(1, uint64) >> 1
  where w = [] at W = 800 nm exactly (so the default set's frames are byte-for-byte those made
  before --wavelength_nm existed) and w = [round(W x 1000)] otherwise (each wavelength its own photon
  and read noise, independent of the other wavelengths' runs).

truth.csv (one row per spot: grid spots first, row-major from the bottom-left, i.e. by y then
x; then the crowded pair, then the edge spot)
  spot                 0-based index
  kind                 "grid", "crowded" or "edge"
  x_px, y_px           centre in exposure 0 [px, frame coordinates]
  ccd_sigma_x_px, ccd_sigma_y_px   the diffusion widths above at --wavelength_nm [px]
  airy_radius_px       0.47 (W / 800) [px]
  flux_e               mean photo-electrons [e-]
  defocus_px, total_sigma_x_px, total_sigma_y_px, total_fwhm_um
                       only for a single-focus set (every exposure's defocus equal):
                       total_sigma = sqrt(ccd_sigma^2 + defocus^2) per axis, total_fwhm_um =
                       2 sqrt(2 ln 2) sqrt(total_sigma_x total_sigma_y) pixel_um
  fwhm_um              2 sqrt(2 ln 2) sqrt(ccd_sigma_x ccd_sigma_y) pixel_um (always)
  ellipticity          |sx^2 - sy^2| / (sx^2 + sy^2) of the CCD sigmas (always)
  alpha_x, alpha_y     the spot's exponents of the widths' power law in wavelength
  wavelength_nm        --wavelength_nm [nm]
  (the last three come last, so the columns before them are those of sets made before
  --wavelength_nm existed, with the same values at 800 nm)
Numbers are written with Python's repr (they read back to the same float64).

truth.json: "spots" (the rows of truth.csv, same keys and values), "columns" (truth.csv's
header), the seed and options (with wavelength_nm), the detector, the optics (this set's
airy_radius_px and wavelength_nm; the 800 nm width laws; the wavelength laws of the Airy radius
and the widths and of alpha_x, alpha_y, as text; the allowed wavelengths and width bounds), the
layout, and per exposure: file, focus_um (or null), defocus_px, drift_x_px / drift_y_px,
exptime_s, the brightest pixel (electrons before noise) and, per spot, photons drawn and
electrons collected / lost beyond the box or the frame.

Errors (a bad option, a non-empty OUTDIR, a saturating set, an unwritable OUTDIR) are one line
on stderr and exit code 2. OUTDIR is created if missing (and removed again if the set is then
refused); every file is written under a temporary name and renamed when all are complete
(truth.json last).
"""

import argparse
import csv
import io
import json
import math
import os
import sys

import numpy as np
from astropy.io import fits

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference_sensor  # noqa: E402  (the independent photon-shooting simulator)

GAIN_E_PER_ADU = 3.1
READ_NOISE_E = 4.5
BIAS_ADU = 1000.0
PIXEL_UM = 12.0
SATURATION_ADU = 65535.0
REFERENCE_WAVELENGTH_NM = 800.0  # the wavelength at which the width laws' constants hold
WAVELENGTH_RANGE_NM = (550.0, 900.0)  # --wavelength_nm: where the widths stay in CCD_SIGMA_BOUNDS_PX
EXPTIME_S = 1.0
ADU_MAX = 65535
AIRY_RADIUS_AT_REFERENCE_PX = 0.47  # first dark ring at 800 nm; diffraction scales with lambda
CCD_SIGMA_BOUNDS_PX = (0.2, 0.45)  # every diffusion width, at every allowed wavelength
DEFAULT_DEFOCUS_PX = 0.41
DRIFT_PER_EXPOSURE_PX = (0.03, 0.02)  # (x, y) [px] per exposure index
CROWDED_SEPARATION_PX = 5.0
EDGE_X_PX = 2.5  # 3 px from the frame's left edge at x = -0.5
BOX_HALF_PX = 20  # photon-shooting box: 41 x 41 px
MIN_CELL_WITH_EXTRAS_PX = 64  # extras >= 64 / 2 - 1 = 31 px from grid spots (21 x 21 stamps apart)
SATURATION_MARGIN_SD = 5.0
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


class UsageError(Exception):
    """A bad option or an output problem: one line on stderr, exit code 2."""


class QuietParser(argparse.ArgumentParser):
    """argparse that reports a bad command line as one line (not usage + message)."""

    def error(self, message):
        raise UsageError(message)


# --------------------------------------------------------------------------------------------
# Options


def number_list(text, name):
    values = []
    for item in text.split(","):
        try:
            value = float(item)
        except ValueError:
            raise UsageError(f"--{name}: {item!r} is not a number") from None
        if not math.isfinite(value):
            raise UsageError(f"--{name}: {item!r} is not finite")
        values.append(value)
    return values


def join_list_values(argv):
    """'--focus_um -50,0,50' -> '--focus_um=-50,0,50': argparse takes a value starting with '-'
    for an option unless it is a single negative number."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] in ("--focus_um", "--defocus_px") and i + 1 < len(argv) and argv[i + 1][:1] == "-" \
                and argv[i + 1][1:2] in tuple("0123456789."):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def parse_options(argv):
    argv = join_list_values(argv)
    p = QuietParser(prog="grid_frames.py", add_help=True,
                    description="Full-sensor spot-grid frames with known truth (see the docstring).")
    p.add_argument("outdir")
    p.add_argument("--size", type=int, default=4096, help="frame width = height [px], 64..4096")
    p.add_argument("--grid", type=int, default=7, help="spots per row and column, 1..64")
    p.add_argument("--exposures", type=int, default=None,
                   help="number of frames (default 3, or the length of --focus_um/--defocus_px)")
    p.add_argument("--seed", type=int, default=1, help="integer >= 0")
    p.add_argument("--flux_e", type=float, default=4e5, help="mean photo-electrons per spot")
    p.add_argument("--focus_um", default=None, help="FOCUSPOS per exposure [um], comma-separated")
    p.add_argument("--defocus_px", default=None,
                   help="Gaussian defocus sigma per exposure [px], comma-separated (default 0.41)")
    p.add_argument("--no_extras", action="store_true", help="no crowded pair and no edge spot")
    p.add_argument("--wavelength_nm", type=float, default=REFERENCE_WAVELENGTH_NM,
                   help="wavelength [nm], 550..900 (default 800): WAVELEN, the Airy radius, the widths")
    a = p.parse_args(argv)

    if not 64 <= a.size <= 4096:
        raise UsageError(f"--size {a.size} is out of range (64..4096)")
    if not 1 <= a.grid <= 64:
        raise UsageError(f"--grid {a.grid} is out of range (1..64)")
    if a.size / a.grid < 2 * BOX_HALF_PX + 1:
        raise UsageError(f"--grid {a.grid} is too fine for --size {a.size}: cells of "
                         f"{a.size / a.grid:g} px < {2 * BOX_HALF_PX + 1} px")
    if not a.no_extras and a.grid < 2:
        raise UsageError("--grid 1 leaves no cell corner for the extra spots: use --grid >= 2 or --no_extras")
    if not a.no_extras and a.size / a.grid < MIN_CELL_WITH_EXTRAS_PX:
        raise UsageError(f"cells of {a.size / a.grid:g} px leave the extra spots too close to grid spots: "
                         f"need >= {MIN_CELL_WITH_EXTRAS_PX} px (fewer --grid) or --no_extras")
    if a.seed < 0 or a.seed >= 2**63:
        raise UsageError(f"--seed {a.seed} is out of range (0..2^63-1)")
    if not math.isfinite(a.flux_e) or not 0.0 < a.flux_e <= reference_sensor.MAX_FLUX_E:
        raise UsageError(f"--flux_e {a.flux_e:g} is out of range (> 0, <= {reference_sensor.MAX_FLUX_E:g})")
    lo, hi = WAVELENGTH_RANGE_NM
    if not math.isfinite(a.wavelength_nm) or not lo <= a.wavelength_nm <= hi:
        raise UsageError(f"--wavelength_nm {a.wavelength_nm:g} is out of range ({lo:g}..{hi:g} nm; > 0 "
                         f"and where the width laws keep every sigma in {CCD_SIGMA_BOUNDS_PX[0]:g}.."
                         f"{CCD_SIGMA_BOUNDS_PX[1]:g} px)")

    focus = number_list(a.focus_um, "focus_um") if a.focus_um is not None else None
    defocus = number_list(a.defocus_px, "defocus_px") if a.defocus_px is not None else None
    given = {name: len(v) for name, v in (("--focus_um", focus), ("--defocus_px", defocus)) if v is not None}
    if a.exposures is not None:
        given["--exposures"] = a.exposures
    counts = set(given.values())
    if len(counts) > 1:
        raise UsageError("the exposure counts disagree: " + ", ".join(f"{k} {v}" for k, v in given.items()))
    n = counts.pop() if counts else 3
    if not 1 <= n <= 100:
        raise UsageError(f"{n} exposures is out of range (1..100)")
    if defocus is None:
        defocus = [DEFAULT_DEFOCUS_PX] * n
    for d in defocus:
        if not 0.0 <= d <= 10.0:
            raise UsageError(f"--defocus_px {d:g} is out of range (0..10 px)")
    return {"outdir": a.outdir, "size": a.size, "grid": a.grid, "exposures": n, "seed": a.seed,
            "flux_e": a.flux_e, "focus_um": focus, "defocus_px": defocus,
            "extras": not a.no_extras, "wavelength_nm": a.wavelength_nm}


# --------------------------------------------------------------------------------------------
# The scene


def sensor_uv(x, y, size):
    """Frame position (x, y) [px] -> (u, v) in [-1, 1): the sensor's normalised coordinates."""
    return 2.0 * (x + 0.5) / size - 1.0, 2.0 * (y + 0.5) / size - 1.0


def ccd_alphas(x, y, size):
    """Power-law exponents (alpha_x, alpha_y) of the diffusion widths with wavelength at (x, y)."""
    u, v = sensor_uv(x, y, size)
    return -0.25 + 0.10 * u, -0.20 + 0.08 * v


def ccd_sigmas(x, y, size, wavelength_nm):
    """Charge-diffusion widths (sigma_x, sigma_y) [px] at frame position (x, y) and the
    wavelength [nm]: the 800 nm law across the sensor times (W / 800)^alpha per axis. At 800 nm
    the factor is exactly 1.0 (1.0 ** alpha), so the widths are those of the 800 nm law."""
    u, v = sensor_uv(x, y, size)
    alpha_x, alpha_y = ccd_alphas(x, y, size)
    ratio = wavelength_nm / REFERENCE_WAVELENGTH_NM
    return ((0.29 + 0.05 * u + 0.03 * v * v) * ratio ** alpha_x,
            (0.33 + 0.04 * v - 0.02 * u * u) * ratio ** alpha_y)


def airy_radius(wavelength_nm):
    """Radius of the Airy pattern's first dark ring [px]: 1.22 lambda F# / pixel, so linear in
    the wavelength (exactly 0.47 at 800 nm)."""
    return AIRY_RADIUS_AT_REFERENCE_PX * (wavelength_nm / REFERENCE_WAVELENGTH_NM)


def wavelength_entropy(wavelength_nm):
    """Extra seed words for the noise streams: none at 800 nm (the original streams, so the
    default set keeps its bytes), round(W x 1000) otherwise (each wavelength its own noise)."""
    if wavelength_nm == REFERENCE_WAVELENGTH_NM:
        return []
    return [int(round(wavelength_nm * 1000.0))]


def layout(opts):
    """The spots [(kind, x_px, y_px)] of exposure 0, in truth.csv's order."""
    size, grid = opts["size"], opts["grid"]
    cell = size / grid
    rng = np.random.default_rng([opts["seed"], 0])
    spots = []
    for j in range(grid):  # rows from the bottom, then columns from the left
        for i in range(grid):
            ox, oy = rng.random(2) - 0.5
            spots.append(("grid", -0.5 + (i + 0.5) * cell + ox, -0.5 + (j + 0.5) * cell + oy))
    if opts["extras"]:
        corner = -0.5 + (grid // 2) * cell  # Y: a cell boundary near the middle
        ox, oy = rng.random(2) - 0.5
        half = 0.5 * CROWDED_SEPARATION_PX
        spots.append(("crowded", corner - half + ox, corner + oy))
        spots.append(("crowded", corner + half + ox, corner + oy))
        spots.append(("edge", EDGE_X_PX, corner + rng.random() - 0.5))
    return spots


def truth_rows(opts, spots):
    """truth.csv's rows (dicts, in column order) and its column names."""
    defocus = opts["defocus_px"]
    wavelength = opts["wavelength_nm"]
    single_focus = all(d == defocus[0] for d in defocus)
    rows = []
    for index, (kind, x, y) in enumerate(spots):
        sx, sy = ccd_sigmas(x, y, opts["size"], wavelength)
        lo, hi = CCD_SIGMA_BOUNDS_PX
        if not (lo <= sx <= hi and lo <= sy <= hi):  # cannot happen for 550..900 nm (see the docstring)
            raise UsageError(f"spot {index}: diffusion widths ({sx:.3f}, {sy:.3f}) px leave {lo:g}..{hi:g} px "
                             f"at --wavelength_nm {wavelength:g}")
        alpha_x, alpha_y = ccd_alphas(x, y, opts["size"])
        row = {"spot": index, "kind": kind, "x_px": x, "y_px": y,
               "ccd_sigma_x_px": sx, "ccd_sigma_y_px": sy,
               "airy_radius_px": airy_radius(wavelength), "flux_e": opts["flux_e"]}
        if single_focus:
            d = defocus[0]
            tx, ty = math.sqrt(sx * sx + d * d), math.sqrt(sy * sy + d * d)
            row.update({"defocus_px": d, "total_sigma_x_px": tx, "total_sigma_y_px": ty,
                        "total_fwhm_um": FWHM_PER_SIGMA * math.sqrt(tx * ty) * PIXEL_UM})
        row["fwhm_um"] = FWHM_PER_SIGMA * math.sqrt(sx * sy) * PIXEL_UM
        row["ellipticity"] = abs(sx * sx - sy * sy) / (sx * sx + sy * sy)
        # Appended last: the columns of the 800 nm set before --wavelength_nm keep their places.
        row.update({"alpha_x": alpha_x, "alpha_y": alpha_y, "wavelength_nm": wavelength})
        rows.append(row)
    return rows, list(rows[0].keys())


def photon_seed(seed, exposure, spot, wavelength_nm):
    """The config seed reference_sensor gets for one spot in one exposure (63-bit integer)."""
    words = [seed, 2, exposure, spot] + wavelength_entropy(wavelength_nm)
    state = np.random.SeedSequence(words).generate_state(1, np.uint64)
    return int(state[0]) >> 1


def render_spot(opts, exposure, spot, x, y, sigma_x, sigma_y, airy):
    """Photon-shoots one spot into a 41 x 41 box: (electrons [int64], box x0, box y0, record)."""
    bx0, by0 = int(math.floor(x + 0.5)) - BOX_HALF_PX, int(math.floor(y + 0.5)) - BOX_HALF_PX
    n = 2 * BOX_HALF_PX + 1
    cfg = {
        "seed": photon_seed(opts["seed"], exposure, spot, opts["wavelength_nm"]),
        # Noise-free unit-gain detector: the electrons are taken before noise and ADUs.
        "detector": {"gain_e_per_adu": 1.0, "read_noise_e": 0.0, "bias_adu": 0.0,
                     "pixel_um": PIXEL_UM, "saturation_adu": SATURATION_ADU, "nx": n, "ny": n},
        "optics": {"airy_radius_px": airy.r0,
                   "defocus": {"kind": "gaussian", "sigma_px": opts["defocus_px"][exposure]},
                   "ccd_sigma_x_px": sigma_x, "ccd_sigma_y_px": sigma_y},
        "pixel_response": {"kind": "box", "width_px": 1.0},
        "brighter_fatter": {"strength": 0.0, "batches": 100},
        "exposures": [{"flux_e": opts["flux_e"], "x_px": x - bx0, "y_px": y - by0,
                       "exptime_s": EXPTIME_S, "wavelength_nm": opts["wavelength_nm"]}],
    }
    electrons, _, t = reference_sensor.simulate_exposure(cfg, 0, airy)
    return electrons, bx0, by0, {"photons": t["photons_drawn"], "in_box": t["electrons_collected"]}


def add_box(frame, box, bx0, by0):
    """Adds a box of electrons into the frame at (bx0, by0); returns the electrons that fell off."""
    size = frame.shape[0]
    n = box.shape[0]
    x0, y0 = max(bx0, 0), max(by0, 0)
    x1, y1 = min(bx0 + n, size), min(by0 + n, size)
    part = box[y0 - by0:y1 - by0, x0 - bx0:x1 - bx0]
    frame[y0:y1, x0:x1] += part
    return int(box.sum() - part.sum())


def check_saturation(opts, k, electrons, x0, y0):
    """The brightest pixel of an electron map placed at (x0, y0): (x, y, electrons); refuses the
    set if it comes within 5 sd (Poisson + read noise) of SATURATE."""
    j, i = np.unravel_index(int(np.argmax(electrons)), electrons.shape)
    peak = float(electrons[j, i])
    worst_adu = BIAS_ADU + (peak + SATURATION_MARGIN_SD * math.sqrt(peak + READ_NOISE_E ** 2)) / GAIN_E_PER_ADU
    if worst_adu >= SATURATION_ADU:
        raise UsageError(f"--flux_e {opts['flux_e']:g} saturates: exposure {k} pixel ({x0 + i}, {y0 + j}) "
                         f"holds {peak:.0f} e- (+5 sd -> {worst_adu:.0f} ADU >= SATURATE "
                         f"{SATURATION_ADU:.0f}); lower --flux_e")
    return int(x0 + i), int(y0 + j), peak


def render_exposure(opts, k, spots, rows, airy):
    """Exposure k: (ADU frame [uint16], record for truth.json)."""
    size = opts["size"]
    dx, dy = DRIFT_PER_EXPOSURE_PX[0] * k, DRIFT_PER_EXPOSURE_PX[1] * k
    electrons = np.zeros((size, size))
    per_spot = []
    for s, ((_, x, y), row) in enumerate(zip(spots, rows)):
        box, bx0, by0, rec = render_spot(opts, k, s, x + dx, y + dy,
                                         row["ccd_sigma_x_px"], row["ccd_sigma_y_px"], airy)
        check_saturation(opts, k, box, bx0, by0)  # early: a lone spot that saturates
        off_frame = add_box(electrons, box, bx0, by0)
        per_spot.append({"spot": s, "photons_drawn": rec["photons"],
                         "electrons_collected": rec["in_box"] - off_frame,
                         "lost_beyond_box": rec["photons"] - rec["in_box"],
                         "lost_beyond_frame": off_frame})

    peak_x, peak_y, peak = check_saturation(opts, k, electrons, 0, 0)  # overlapping spots too

    rng = np.random.default_rng([opts["seed"], 1, k] + wavelength_entropy(opts["wavelength_nm"]))
    electrons += rng.normal(0.0, READ_NOISE_E, size=electrons.shape)
    adu = np.floor(electrons / GAIN_E_PER_ADU + BIAS_ADU + 0.5)
    np.clip(adu, 0, ADU_MAX, out=adu)
    record = {"index": k, "file": f"frame_{k:03d}.fits",
              "focus_um": opts["focus_um"][k] if opts["focus_um"] is not None else None,
              "defocus_px": opts["defocus_px"][k], "drift_x_px": dx, "drift_y_px": dy,
              "exptime_s": EXPTIME_S,
              "peak_pixel": {"x": int(peak_x), "y": int(peak_y), "electrons": peak},
              "spots": per_spot}
    return adu.astype(np.uint16), record


def fits_hdu(adu, record, opts):
    hdu = fits.PrimaryHDU(data=adu)  # uint16 -> BITPIX 16, BZERO 32768
    h = hdu.header
    h["GAIN"] = (GAIN_E_PER_ADU, "[e-/ADU]")
    h["RDNOISE"] = (READ_NOISE_E, "[e-] read noise")
    h["BIASLVL"] = (BIAS_ADU, "[ADU] bias level")
    h["PIXSIZE"] = (PIXEL_UM, "[um]")
    h["SATURATE"] = (SATURATION_ADU, "[ADU] saturation level")
    h["WAVELEN"] = (opts["wavelength_nm"], "[nm]")
    h["EXPTIME"] = (record["exptime_s"], "[s]")
    if record["focus_um"] is not None:
        h["FOCUSPOS"] = (record["focus_um"], "[um] focus stage position")
    h["CREATOR"] = ("grid_frames.py", "spot-grid test frames (photon shooting)")
    h["SIMSEED"] = (opts["seed"], "grid_frames.py --seed")
    h["SIMINDEX"] = (record["index"], "exposure index")
    return hdu


# --------------------------------------------------------------------------------------------
# Output


def csv_text(rows, columns):
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([repr(row[c]) if isinstance(row[c], float) else row[c] for c in columns])
    return out.getvalue()


def prepare_outdir(outdir):
    if os.path.isdir(outdir):
        if os.listdir(outdir):
            raise UsageError(f"{outdir}: output folder is not empty (refusing to overwrite)")
    elif os.path.exists(outdir):
        raise UsageError(f"{outdir}: exists and is not a folder")
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as err:
        raise UsageError(f"{outdir}: cannot create the output folder ({err.strerror})") from None
    if not os.access(outdir, os.W_OK):
        raise UsageError(f"{outdir}: output folder not writable")


def temp_name(outdir, name):
    return os.path.join(outdir, f".{name}.tmp.{os.getpid()}")


def run(opts):
    outdir = opts["outdir"]
    created = not os.path.exists(outdir)
    prepare_outdir(outdir)
    try:
        return write_set(opts)
    except UsageError:
        if created and os.path.isdir(outdir) and not os.listdir(outdir):
            os.rmdir(outdir)  # leave no trace of a refused set
        raise


def write_set(opts):
    outdir = opts["outdir"]
    spots = layout(opts)
    rows, columns = truth_rows(opts, spots)
    airy = reference_sensor.AiryRadii(airy_radius(opts["wavelength_nm"]))
    temps = []  # (temporary path, final path), renamed only when all are written
    try:
        exposures = []
        for k in range(opts["exposures"]):
            adu, record = render_exposure(opts, k, spots, rows, airy)
            tmp = temp_name(outdir, record["file"])
            temps.append((tmp, os.path.join(outdir, record["file"])))
            fits_hdu(adu, record, opts).writeto(tmp, output_verify="exception")
            exposures.append(record)
        truth = {
            "generator": "tests/support/grid_frames.py (photon shooting by reference_sensor.py)",
            "seed": opts["seed"],
            "options": {key: opts[key] for key in
                        ("size", "grid", "exposures", "flux_e", "focus_um", "defocus_px", "extras",
                         "wavelength_nm")},
            "detector": {"gain_e_per_adu": GAIN_E_PER_ADU, "read_noise_e": READ_NOISE_E,
                         "bias_adu": BIAS_ADU, "pixel_um": PIXEL_UM,
                         "saturation_adu": SATURATION_ADU, "nx": opts["size"], "ny": opts["size"]},
            "optics": {"airy_radius_px": airy.r0, "wavelength_nm": opts["wavelength_nm"],
                       "defocus_kind": "gaussian",
                       "ccd_sigma_x_px": "0.29 + 0.05 u + 0.03 v^2",
                       "ccd_sigma_y_px": "0.33 + 0.04 v - 0.02 u^2",
                       "u_v": "u = 2 (x + 0.5) / size - 1, v = 2 (y + 0.5) / size - 1 "
                              "at the exposure-0 centre",
                       # The wavelength laws; the two width laws above hold at 800 nm.
                       "reference_wavelength_nm": REFERENCE_WAVELENGTH_NM,
                       "airy_radius_law": "0.47 (W / 800) px",
                       "ccd_sigma_wavelength_law": "ccd_sigma_x_px(u, v, W) = ccd_sigma_x_px(u, v) "
                                                   "(W / 800)^alpha_x, likewise y",
                       "alpha_x": "-0.25 + 0.10 u",
                       "alpha_y": "-0.20 + 0.08 v",
                       "wavelength_range_nm": list(WAVELENGTH_RANGE_NM),
                       "ccd_sigma_bounds_px": list(CCD_SIGMA_BOUNDS_PX)},
            "layout": {"cell_px": opts["size"] / opts["grid"],
                       "render_box_px": 2 * BOX_HALF_PX + 1,
                       "drift_px_per_exposure": list(DRIFT_PER_EXPOSURE_PX),
                       "crowded_separation_px": CROWDED_SEPARATION_PX if opts["extras"] else None},
            "exposures": exposures,
            "columns": columns,
            "spots": rows,
        }
        tmp = temp_name(outdir, "truth.csv")
        temps.append((tmp, os.path.join(outdir, "truth.csv")))
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            f.write(csv_text(rows, columns))
        tmp = temp_name(outdir, "truth.json")
        temps.append((tmp, os.path.join(outdir, "truth.json")))
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(truth, f, indent=1)
            f.write("\n")
        for tmp, final in temps:
            os.replace(tmp, final)
    except OSError as err:
        raise UsageError(f"{outdir}: cannot write ({err.strerror or err})") from None
    finally:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.remove(tmp)
    return truth


def main(argv):
    try:
        opts = parse_options(argv[1:])
        truth = run(opts)
    except UsageError as err:
        print(f"grid_frames: {err}", file=sys.stderr)
        return 2
    print(json.dumps({"outdir": opts["outdir"], "frames": len(truth["exposures"]),
                      "spots": len(truth["spots"])}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
