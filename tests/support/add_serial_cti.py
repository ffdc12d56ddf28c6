#!/usr/bin/env python3
"""Adds serial charge-transfer inefficiency to frames, to test ccdpsf on a defect it did not make.

    /usr/bin/python3 tests/support/add_serial_cti.py IN_DIR OUT_DIR --per_transfer C
        [--trail_length_px L]

Reads every IN_DIR/*.fits (a 16-bit frame with GAIN [e-/ADU] and BIASLVL [ADU] keywords, as
tests/support/grid_frames.py writes them) and writes OUT_DIR/<same name> with the same header.
Shares no code with ccdpsf (numpy and astropy only).

The defect: readout is towards column x = 0, so a charge packet in column x makes x + 1 serial
transfers to the output and leaves behind the fraction

    f(x) = C (x + 1)                       (C: --per_transfer, the CTI per transfer)

of its charge, which follows it in the pixels d = 1, 2, ... after it along +x with weights
(1 - r) r^(d - 1), r = exp(-1 / L) (L: --trail_length_px, default 1.5 px): an exponential trail
of e-folding length L that sums to f. Charge trailing past the last column is lost. Applied
row by row to the electrons (ADU - BIASLVL) x GAIN, which hold the read noise and one rounding
already: a trail of the noise is at most f x 4.5 e-, and the second rounding to whole ADU adds
GAIN^2 / 12 = 0.8 e-^2 to a variance of >= 20 e-^2. Then back to ADU, rounded (halves up) and
clipped to [0, 65535].

A spot centred at column x_c sees f between f(x_c - 10) and f(x_c + 10) over its 21-px stamp;
its light lies within ~2 px of x_c, so its effective fraction is f(x_c) to within 2 C, which a
test can treat as its truth.

Errors (a bad option, a missing keyword, an existing OUT_DIR) are one line on stderr, exit 2.
"""
import argparse
import glob
import math
import os
import sys

import numpy as np
from astropy.io import fits


def fail(message):
    print("add_serial_cti.py: " + message, file=sys.stderr)
    sys.exit(2)


def add_trail(electrons, per_transfer, trail_length_px):
    """The frame's rows with their serial CTI trails (float64, the same shape)."""
    ny, nx = electrons.shape
    r = math.exp(-1.0 / trail_length_px)
    out = np.empty_like(electrons)
    carry = np.zeros(ny)  # charge on its way into column x, from the columns before it
    for x in range(nx):
        f = per_transfer * (x + 1)
        q = electrons[:, x]
        out[:, x] = (1.0 - f) * q + carry
        carry = r * carry + (1.0 - r) * f * q
    return out


def main(argv):
    p = argparse.ArgumentParser(prog="add_serial_cti.py")
    p.add_argument("in_dir")
    p.add_argument("out_dir")
    p.add_argument("--per_transfer", type=float, required=True)
    p.add_argument("--trail_length_px", type=float, default=1.5)
    opts = p.parse_args(argv)
    if not (opts.trail_length_px > 0 and math.isfinite(opts.trail_length_px)):
        fail("--trail_length_px must be > 0")
    files = sorted(glob.glob(os.path.join(opts.in_dir, "*.fits")))
    if not files:
        fail("no FITS files in " + opts.in_dir)
    if os.path.exists(opts.out_dir):
        fail(opts.out_dir + " exists")
    frames = []
    for path in files:
        with fits.open(path) as hdul:
            header = hdul[0].header.copy()
            adu = hdul[0].data.astype(np.float64)
        for key in ("GAIN", "BIASLVL"):
            if key not in header:
                fail(path + " has no " + key)
        if not (0 <= opts.per_transfer and opts.per_transfer * adu.shape[1] < 1):
            fail("--per_transfer must be >= 0 and below 1 / (frame width)")
        frames.append((path, header, adu))
    # Checked before anything is written: a refused run leaves no OUT_DIR.
    os.makedirs(opts.out_dir)
    for path, header, adu in frames:
        gain, bias = float(header["GAIN"]), float(header["BIASLVL"])
        electrons = add_trail((adu - bias) * gain, opts.per_transfer, opts.trail_length_px)
        out = np.clip(np.floor(electrons / gain + bias + 0.5), 0, 65535).astype(np.uint16)
        hdu = fits.PrimaryHDU(out, header=header)
        hdu.writeto(os.path.join(opts.out_dir, os.path.basename(path)))

if __name__ == "__main__":
    main(sys.argv[1:])
