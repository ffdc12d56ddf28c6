#!/usr/bin/env python3
"""Adds one ordinary laboratory defect to a clean frame written by `ccdpsf simulate`.

    /usr/bin/python3 tests/support/lab_defects.py CASE IN.fits OUT.fits [--seed N] [--spot X Y]
    /usr/bin/python3 tests/support/lab_defects.py --list

The point is to test ccdpsf on defects it did not make itself, so this script shares no code
with it: numpy and astropy only. IN.fits is read, never written; OUT.fits is written under a
temporary name and renamed, so a failure leaves no half-written file. One line of JSON on
stdout says what was done (the case, the defect's frame coordinates, its size in e- and ADU,
keywords removed or changed). The output depends only on the input, the case and --seed.

Conventions (those of ccdpsf): coordinates are 0-based frame pixels with centres at integers,
x = column (NAXIS1), y = row, numpy index data[y, x]. Electrons = (ADU - BIASLVL) * GAIN with
the file's own GAIN [e-/ADU] and BIASLVL [ADU]. The spot is the brightest pixel of the
bias-subtracted data region (the prescan excluded) unless --spot X Y gives it; defects are
placed relative to the pixel nearest the spot (the "peak pixel").

Errors are one line on stderr and exit code 2.
"""

import argparse
import json
import math
import os
import sys

import numpy as np
from astropy.io import fits

COSMIC_E = 8000.0  # deposit of one cosmic-ray hit [e-]; a typical muon leaves a few thousand
HOT_COLUMN_DARK_E = 400.0  # extra dark charge in every pixel of the hot column [e-]
SECOND_SPOT_FRACTION = 0.6  # second source flux / main spot's 7x7 signal
SECOND_SPOT_SIGMA_PX = 0.6  # its Gaussian sigma [px]
CLIP_FRACTION = 0.7  # clipped_core: clip level / peak pixel value (raw ADU)
PEAK_8BIT_ADU = 200.0  # 8-bit cases: the peak pixel's signal above the black level [ADU]
MEF_AMPS = [  # (EXTNAME, bias [ADU], read noise [e-]) of the two amplifiers
    ("AMP1", 1000.0, 4.5),
    ("AMP2", 1350.0, 6.0),
]
MEF_OVERSCAN_COLUMNS = 10


class DefectError(Exception):
    """A problem with the input or the request; reported as one line, exit code 2."""


def round_half_up(values):
    """Nearest integer (halves up) as int64: the ADC's rounding, the same for every case."""
    return np.floor(np.asarray(values, dtype=np.float64) + 0.5).astype(np.int64)


def parse_section(text):
    """IRAF section '[x1:x2,y1:y2]' (1-based, inclusive) -> 0-based half-open (x0, x1, y0, y1)."""
    try:
        xs, ys = text.strip().strip("[]").split(",")
        x1, x2 = (int(v) for v in xs.split(":"))
        y1, y2 = (int(v) for v in ys.split(":"))
    except ValueError:
        raise DefectError(f"cannot parse section {text!r}") from None
    if x1 < 1 or y1 < 1 or x2 < x1 or y2 < y1:
        raise DefectError(f"section {text!r} is not ascending and 1-based")
    return x1 - 1, x2, y1 - 1, y2


def format_section(x0, x1, y0, y1):
    """0-based half-open ranges -> IRAF section string (1-based, inclusive)."""
    return f"[{x0 + 1}:{x1},{y0 + 1}:{y1}]"


class Frame:
    """The input image with what every case needs: ADU values, gain, bias, spot, peak pixel."""

    def __init__(self, path, spot):
        if not os.path.isfile(path):
            raise DefectError(f"{path}: no such file")
        try:
            with fits.open(path, memmap=False) as hdul:
                hdu = hdul[0]
                if hdu.data is None or hdu.data.ndim != 2:
                    raise DefectError(f"{path}: primary HDU holds no 2-D image")
                self.dtype = hdu.data.dtype  # uint16 for BITPIX 16 with BZERO 32768
                self.adu = hdu.data.astype(np.float64)  # exact for any 16-bit integer
                self.header = hdu.header.copy()
        except OSError as err:
            raise DefectError(f"{path}: not a readable FITS file ({err})") from None
        h = self.header
        if "GAIN" not in h:
            raise DefectError(f"{path}: no GAIN keyword")
        self.gain = float(h["GAIN"])  # [e-/ADU]
        if not self.gain > 0:
            raise DefectError(f"{path}: GAIN = {h['GAIN']} is not positive")
        self.ny, self.nx = self.adu.shape
        # The prescan's columns (BIASSEC), excluded from the spot search and from the MEF split.
        self.prescan = parse_section(h["BIASSEC"]) if "BIASSEC" in h else None
        if "BIASLVL" in h:
            self.bias, self.bias_source = float(h["BIASLVL"]), "BIASLVL"
        elif self.prescan:
            x0, x1, y0, y1 = self.prescan
            self.bias, self.bias_source = float(np.median(self.adu[y0:y1, x0:x1])), "BIASSEC median"
        else:
            raise DefectError(f"{path}: neither BIASLVL nor BIASSEC gives the bias")
        self.data_x0, self.data_x1 = self._data_columns()
        if spot is None:
            signal = self.adu[:, self.data_x0:self.data_x1] - self.bias
            py, px = np.unravel_index(np.argmax(signal), signal.shape)
            self.spot = (float(px + self.data_x0), float(py))
            self.spot_source = "brightest pixel"
        else:
            self.spot = (float(spot[0]), float(spot[1]))
            self.spot_source = "--spot"
        self.px, self.py = int(math.floor(self.spot[0] + 0.5)), int(math.floor(self.spot[1] + 0.5))
        self.check_inside(self.px, self.py, "the spot's peak pixel")

    def _data_columns(self):
        """Columns [x0, x1) holding the image: all but a prescan at the left or right edge."""
        if self.prescan is None:
            return 0, self.nx
        x0, x1 = self.prescan[0], min(self.prescan[1], self.nx)
        if x0 == 0:
            return x1, self.nx
        if x1 == self.nx:
            return 0, x0
        raise DefectError(f"BIASSEC {self.header['BIASSEC']} is not at the left or right edge")

    def electrons(self, adu):
        """Signal [e-] of ADU values: (ADU - BIASLVL) * GAIN."""
        return (np.asarray(adu, dtype=np.float64) - self.bias) * self.gain

    def check_inside(self, x, y, what):
        if not (0 <= x < self.nx and 0 <= y < self.ny):
            raise DefectError(f"{what} ({x}, {y}) is outside the {self.nx} x {self.ny} frame")

    def box(self, cx, cy, half, what):
        """Slices of the (2 half + 1)^2 box centred on pixel (cx, cy); it must lie in the frame."""
        self.check_inside(cx - half, cy - half, f"{what} (box corner)")
        self.check_inside(cx + half, cy + half, f"{what} (box corner)")
        return slice(cy - half, cy + half + 1), slice(cx - half, cx + half + 1)


def to_storage(adu, dtype):
    """ADU values -> the input's integer type, clipped to its range; returns (array, n_clipped)."""
    if not np.issubdtype(dtype, np.integer):
        return adu.astype(dtype), 0
    info = np.iinfo(dtype)
    values = round_half_up(adu)
    clipped = np.clip(values, info.min, info.max)
    return clipped.astype(dtype), int(np.count_nonzero(clipped != values))


def add_deposits(frame, deposits):
    """Adds charge [e-] to single pixels: each deposit is (x, y, electrons), added as whole ADU."""
    adu = frame.adu.copy()
    pixels = []
    for x, y, e in deposits:
        frame.check_inside(x, y, "defect pixel")
        added = int(round_half_up(e / frame.gain))  # [ADU]
        adu[y, x] += added
        pixels.append({"x": x, "y": y, "e": e, "adu": added})
    return adu, {"pixels": pixels}


def cosmic_adjacent(frame, rng):
    """A cosmic-ray hit in the pixel right of the peak (x+1, y): 8000 e- of extra charge in that
    one pixel, added as round(8000 / GAIN) ADU. No noise: the deposit is what it is."""
    return add_deposits(frame, [(frame.px + 1, frame.py, COSMIC_E)])


def cosmic_3px(frame, rng):
    """A short cosmic-ray track near the spot: 8000 e- at (x+3, y) and 30 % of that (2400 e-) in
    its neighbour (x+4, y), each added as whole ADU (e- / GAIN, rounded)."""
    return add_deposits(frame, [(frame.px + 3, frame.py, COSMIC_E),
                                (frame.px + 4, frame.py, 0.3 * COSMIC_E)])


def hot_column(frame, rng):
    """A hot column at x+4, every row: each pixel collects a mean dark charge of 400 e- with its
    own Poisson noise (drawn in e-, converted with GAIN, rounded to whole ADU)."""
    x = frame.px + 4
    frame.check_inside(x, 0, "hot column")
    dark_e = rng.poisson(HOT_COLUMN_DARK_E, size=frame.ny)
    added = round_half_up(dark_e / frame.gain)  # [ADU] per row
    adu = frame.adu.copy()
    adu[:, x] += added
    return adu, {"column_x": x, "rows": [0, frame.ny - 1], "dark_e": HOT_COLUMN_DARK_E,
                 "dark_adu": HOT_COLUMN_DARK_E / frame.gain,
                 "drawn_e_total": int(dark_e.sum()), "added_adu_total": int(added.sum()),
                 "added_adu_mean": float(added.mean())}


def integrated_gaussian_1d(n, centre, sigma):
    """Fraction of a unit 1-D Gaussian falling in each pixel 0..n-1 (pixel i spans i +- 0.5):
    0.5 [erf((i + 0.5 - c) / (sigma sqrt 2)) - erf((i - 0.5 - c) / (sigma sqrt 2))]."""
    scale = 1.0 / (sigma * math.sqrt(2.0))
    edges = [0.5 * math.erf((i - 0.5 - centre) * scale) for i in range(n + 1)]
    return np.diff(np.array(edges))


def second_spot(frame, rng):
    """A second, fainter source at (x+6, y): a circular Gaussian of sigma 0.6 px integrated
    exactly over each pixel, of total flux 60 % of the main spot's signal [e-] in the 7 x 7 box
    round its peak pixel; Poisson noise drawn in e-, added as whole ADU."""
    ys, xs = frame.box(frame.px, frame.py, 3, "main spot 7x7 box")
    main_e = float(frame.electrons(frame.adu[ys, xs]).sum())
    flux_e = SECOND_SPOT_FRACTION * main_e
    cx, cy = frame.px + 6, frame.py
    half = 4  # 9 x 9 box: the light beyond 4.5 px = 7.5 sigma is < 1e-13 of the flux
    ys, xs = frame.box(cx, cy, half, "second spot 9x9 box")
    w = integrated_gaussian_1d(2 * half + 1, half, SECOND_SPOT_SIGMA_PX)
    expected_e = flux_e * np.outer(w, w)  # separable: the integral of a circular Gaussian
    drawn_e = rng.poisson(expected_e)
    added = round_half_up(drawn_e / frame.gain)  # [ADU]
    adu = frame.adu.copy()
    adu[ys, xs] += added
    return adu, {"x": cx, "y": cy, "sigma_px": SECOND_SPOT_SIGMA_PX,
                 "box": [cx - half, cx + half, cy - half, cy + half],
                 "main_7x7_e": main_e, "flux_e": flux_e, "flux_adu": flux_e / frame.gain,
                 "drawn_e": int(drawn_e.sum()), "added_adu": int(added.sum()),
                 "centre_pixel_e": float(expected_e[half, half]),
                 "centre_pixel_adu": float(expected_e[half, half] / frame.gain)}


def clipped_core(frame, rng):
    """An ADC or amplifier clipping below full well: every pixel at or above 70 % of the peak
    pixel's raw value [ADU] (bias included) is set to that level, rounded down to whole ADU;
    SATURATE is removed, so the reader is not told where the clipping is."""
    peak_adu = float(frame.adu[frame.py, frame.px])
    clip = float(math.floor(CLIP_FRACTION * peak_adu))
    hit = frame.adu >= clip
    rows, cols = np.nonzero(hit)
    adu = frame.adu.copy()
    lost_adu = float((adu[hit] - clip).sum())
    adu[hit] = clip
    removed = []
    if "SATURATE" in frame.header:
        del frame.header["SATURATE"]
        removed.append("SATURATE")
    return adu, {"clip_adu": clip, "clip_e": float(frame.electrons(clip)),
                 "peak_adu": peak_adu, "peak_e": float(frame.electrons(peak_adu)),
                 "n_pixels": int(hit.sum()),
                 "pixels": [[int(x), int(y)] for y, x in zip(rows, cols)],
                 "removed_adu": lost_adu, "removed_e": lost_adu * frame.gain,
                 "keywords_removed": removed}


def to_8bit(frame, black_adu):
    """Shared by the 8-bit cases: a gain g8 [e-/ADU] (4 significant digits) that puts the peak
    pixel's signal at 200 ADU above the black level; value = clip(round(e-/g8 + black), 0, 255)."""
    peak_e = float(frame.electrons(frame.adu[frame.py, frame.px]))
    if not peak_e > 0:
        raise DefectError("the peak pixel holds no signal above the bias")
    g8 = float(f"{peak_e / PEAK_8BIT_ADU:.4g}")
    values = np.clip(round_half_up(frame.electrons(frame.adu) / g8 + black_adu), 0, 255)
    h = frame.header
    changed = {"BITPIX": [h.get("BITPIX"), 8], "GAIN": [h["GAIN"], g8],
               "SATURATE": [h.get("SATURATE"), 255]}
    removed = [k for k in ("BZERO", "BSCALE", "BLANK") if k in h]
    for k in removed:
        del h[k]
    h["GAIN"] = (g8, "gain [e-/ADU]")
    h["SATURATE"] = (255, "saturation [ADU]")
    report = {"gain8_e_per_adu": g8, "black_adu": black_adu, "peak_e": peak_e,
              "peak_adu": int(values[frame.py, frame.px]),
              "n_at_0": int((values == 0).sum()), "n_at_255": int((values == 255).sum()),
              "keywords_changed": changed, "keywords_removed": removed}
    frame.dtype = np.dtype(np.uint8)  # BITPIX 8: astropy writes uint8 without BZERO
    return values, report


def quantised_8bit(frame, rng):
    """An 8-bit camera: one ADU is g8 = peak signal / 200 e- (about 800 e- here), the black level
    is 10 ADU, values are rounded and clipped to 0..255 (BITPIX 8). GAIN, BIASLVL and SATURATE
    describe the new frame; RDNOISE [e-] and BIASSEC still hold."""
    values, report = to_8bit(frame, 10.0)
    h = frame.header
    report["keywords_changed"]["BIASLVL"] = [h.get("BIASLVL"), 10]
    h["BIASLVL"] = (10, "bias level [ADU]")
    return values, report


def clipped_black(frame, rng):
    """An 8-bit camera with its black level at 0 ADU: as quantised_8bit but negative values clip
    to 0 (the dark pixels' read noise is lost), and BIASLVL and RDNOISE are removed (such a
    camera records neither). BIASSEC is kept: its pixels are now (nearly) all 0."""
    values, report = to_8bit(frame, 0.0)
    for k in ("BIASLVL", "RDNOISE"):
        if k in frame.header:
            del frame.header[k]
            report["keywords_removed"].append(k)
    return values, report


def mef_segments(frame, rng):
    """A two-amplifier test-stand file: an empty primary HDU, then AMP1 and AMP2 image extensions,
    each holding its share of the data columns (the prescan dropped) followed by its own
    10-column overscan. The split lies 12 columns before the spot's peak pixel (after it when
    that would leave AMP1 without columns), so that the spot and its 21 x 21 stamp sit inside
    one amplifier, as a test stand's spots sit inside a segment. Each amplifier has its own bias [ADU] and read noise [e-]: data =
    signal [e-] / GAIN + bias + extra Gaussian noise of sqrt(rn_amp^2 - rn_in^2) e-; overscan =
    bias + Gaussian noise of rn_amp e-. No BIASLVL: the overscan is the bias."""
    h = frame.header
    if "RDNOISE" in h:
        rn_in, rn_source = float(h["RDNOISE"]), "RDNOISE"
    else:
        rn_in, rn_source = 0.0, "none (taken as 0)"
    x0, x1 = frame.data_x0, frame.data_x1
    split = frame.px - 12 if frame.px - 12 > x0 else frame.px + 12  # AMP1 [x0, split), AMP2 [split, x1)
    if not x0 < split < x1:
        raise DefectError("the data region is too narrow to split beside the spot")
    hdus = [fits.PrimaryHDU()]
    for k in ("SIMSEED", "SIMINDEX", "SAMPLING"):  # provenance, to find the truth again
        if k in h:
            hdus[0].header[k] = (h[k], h.comments[k])
    amps = []
    for (name, bias_adu, rn_e), (c0, c1) in zip(MEF_AMPS, [(x0, split), (split, x1)]):
        ncol = c1 - c0
        extra_e = math.sqrt(max(rn_e ** 2 - rn_in ** 2, 0.0))
        signal_e = frame.electrons(frame.adu[:, c0:c1])
        extra_adu = rng.normal(0.0, extra_e, signal_e.shape) / frame.gain
        data = signal_e / frame.gain + bias_adu + extra_adu
        overscan = bias_adu + rng.normal(0.0, rn_e, (frame.ny, MEF_OVERSCAN_COLUMNS)) / frame.gain
        values, n_clipped = to_storage(np.hstack([data, overscan]), np.dtype(np.uint16))
        hdu = fits.ImageHDU(data=values, name=name)
        datasec = format_section(0, ncol, 0, frame.ny)
        biassec = format_section(ncol, ncol + MEF_OVERSCAN_COLUMNS, 0, frame.ny)
        hdu.header["DATASEC"] = (datasec, "image pixels")
        hdu.header["BIASSEC"] = (biassec, "overscan (bias) region")
        hdu.header["GAIN"] = (frame.gain, "gain [e-/ADU]")
        hdu.header["RDNOISE"] = (rn_e, "read noise [e-]")
        for k in ("WAVELEN", "EXPTIME", "PIXSIZE", "SATURATE", "FOCUSPOS"):
            if k in h:
                hdu.header[k] = (h[k], h.comments[k])
        hdus.append(hdu)
        amps.append({"extname": name, "frame_columns": [c0, c1 - 1], "DATASEC": datasec,
                     "BIASSEC": biassec, "bias_adu": bias_adu, "read_noise_e": rn_e,
                     "extra_noise_e": extra_e, "n_clipped": n_clipped})
    # Where the spot went: its peak pixel decides the extension; the 7 x 7 signal may straddle.
    spot_amp = 0 if frame.px < split else 1
    offset = x0 if spot_amp == 0 else split
    ys = slice(max(frame.py - 3, 0), frame.py + 4)
    left = frame.electrons(frame.adu[ys, max(frame.px - 3, x0):min(frame.px + 4, split)]).sum()
    right = frame.electrons(frame.adu[ys, max(frame.px - 3, split):min(frame.px + 4, x1)]).sum()
    report = {"split_frame_x": split,
              "input_read_noise_e": rn_in, "input_read_noise_source": rn_source,
              "amps": amps, "spot_extension": MEF_AMPS[spot_amp][0],
              "spot_ext_x": frame.spot[0] - offset, "spot_ext_y": frame.spot[1],
              "peak_ext_xy": [frame.px - offset, frame.py],
              "spot_7x7_e_by_extension": {"AMP1": float(left), "AMP2": float(right)},
              "keywords_removed": [k for k in ("BIASLVL",) if k in h]}
    return fits.HDUList(hdus), report


CASES = {f.__name__: f for f in (cosmic_adjacent, cosmic_3px, hot_column, second_spot,
                                 clipped_core, quantised_8bit, clipped_black, mef_segments)}


def write_atomically(hdul, out_path):
    """Writes a hidden temporary file beside OUT (same file system, .fits suffix), renames it."""
    directory, name = os.path.split(os.path.abspath(out_path))
    tmp = os.path.join(directory, f".{name}.tmp.{os.getpid()}.fits")
    try:
        hdul.writeto(tmp, overwrite=True, checksum=False)
        os.replace(tmp, out_path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def same_file(a, b):
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)


class OneLineParser(argparse.ArgumentParser):
    def error(self, message):
        raise DefectError(message)


def run(argv):
    p = OneLineParser(description="Adds one laboratory defect to a clean ccdpsf frame.")
    p.add_argument("case", nargs="?")
    p.add_argument("input", nargs="?")
    p.add_argument("output", nargs="?")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--spot", type=float, nargs=2, metavar=("X", "Y"))
    p.add_argument("--list", action="store_true", help="print the case names")
    a = p.parse_args(argv)
    if a.list:
        print("\n".join(CASES))
        return
    if a.output is None:
        raise DefectError("usage: lab_defects.py CASE IN.fits OUT.fits [--seed N] [--spot X Y]"
                          " | --list")
    if a.case not in CASES:
        raise DefectError(f"unknown case {a.case!r} (cases: {', '.join(CASES)})")
    if not os.path.isdir(os.path.dirname(os.path.abspath(a.output))):
        raise DefectError(f"{a.output}: its directory does not exist")
    if same_file(a.input, a.output):
        raise DefectError(f"OUT.fits {a.output} is IN.fits: refusing to overwrite the input")
    frame = Frame(a.input, a.spot)
    rng = np.random.default_rng(a.seed)
    result, details = CASES[a.case](frame, rng)
    history = f"lab_defects.py {a.case} seed={a.seed}"
    if isinstance(result, fits.HDUList):
        result[0].header["HISTORY"] = history
        hdul = result
    else:
        values, n_clipped = to_storage(result, frame.dtype)
        details.setdefault("n_clipped", n_clipped)
        frame.header["HISTORY"] = history
        hdul = fits.HDUList([fits.PrimaryHDU(data=values, header=frame.header)])
    write_atomically(hdul, a.output)
    report = {"case": a.case, "seed": a.seed, "input": a.input, "output": a.output,
              "gain_e_per_adu": frame.gain,
              "bias_adu": frame.bias, "bias_source": frame.bias_source,
              "spot": list(frame.spot), "spot_source": frame.spot_source,
              "peak_pixel": [frame.px, frame.py], "keywords_removed": [], "keywords_changed": {}}
    report.update(details)
    print(json.dumps(report))


def main():
    try:
        run(sys.argv[1:])
    except (DefectError, OSError, ValueError, KeyError) as err:
        print(f"lab_defects.py: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
