#!/usr/bin/env python3
"""The charge a boundary shift moves in the pixels of one bright spot, as the reference sensor
makes it: testdata/reference_sensor/boundary_shift_pixels.json, read by
tests/unit/boundary_shift_sensor_test.cc.

    /usr/bin/python3 tests/support/boundary_shift_pixels.py OUT.json [--seeds N] [--work DIR]

For each case, N seeds of tests/support/reference_sensor.py (photon shooting; no ccdpsf code):
one exposure of the paper's spot (Airy r0 0.47 px, Gaussian defocus 0.41 px, diffusion 0.291 /
0.335 px) with 5.9e5 e- centred on pixel (24, 24) of a 48 x 48 frame, collected in 1000
batches, drawn once with the case's boundary shift and once without it (same seed). Gain 8 e-
/ ADU (the frame's 16-bit range holds the 2.2e5 e- peak), no read noise, no bias. The
difference of each pair is the charge the shift moved plus the photon noise of two
independent draws; its mean over the seeds and the standard error of that mean are written
for the 7 x 7 pixels around the centre [e-], with the case's coefficients (truth.json's a_ij
times the batches' first-order factor).

Cases: "isotropic" (B_x = B_y = 1.6e-7: the shifts are a potential field) and "default" (the
sensor's defaults, B_x 1.4e-7 / B_y 1.8e-7: anisotropic, eta = (B_x - B_y) / (B_x + B_y)).
"""
import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from astropy.io import fits

SENSOR = Path(__file__).resolve().parent / "reference_sensor.py"
GAIN = 8.0
CENTRE = 24
HALF = 3
CASES = {"isotropic": {"strength_x": 1.6e-7, "strength_y": 1.6e-7, "batches": 1000},
         "default": {"batches": 1000}}


def config(seed, shift):
    c = {"seed": seed,
         "detector": {"gain_e_per_adu": GAIN, "read_noise_e": 0.0, "bias_adu": 0,
                      "pixel_um": 12, "saturation_adu": 65535, "nx": 48, "ny": 48},
         "optics": {"airy_radius_px": 0.47, "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                    "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335},
         "exposures": [{"flux_e": 5.9e5, "x_px": CENTRE, "y_px": CENTRE, "exptime_s": 1,
                        "wavelength_nm": 800}]}
    if shift is not None:
        c["boundary_shift"] = shift
    return c


def draw(work, name, cfg):
    path = work / (name + ".json")
    path.write_text(json.dumps(cfg))
    subprocess.run(["/usr/bin/python3", str(SENSOR), str(path), str(work / name)], check=True,
                   stdout=subprocess.DEVNULL)
    image = GAIN * fits.getdata(work / name / "exposure_000.fits").astype(np.float64)
    return image, json.loads((work / name / "truth.json").read_text())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--work")
    args = ap.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="boundary_shift_pixels_"))
    work.mkdir(parents=True, exist_ok=True)
    out = {"generator": "tests/support/boundary_shift_pixels.py --seeds %d" % args.seeds,
           "flux_e": 5.9e5, "centre_px": [CENTRE, CENTRE], "half": HALF, "cases": {}}
    window = np.s_[CENTRE - HALF:CENTRE + HALF + 1, CENTRE - HALF:CENTRE + HALF + 1]
    for case, shift in CASES.items():
        diffs = []
        for seed in range(1, args.seeds + 1):
            on, truth = draw(work, f"{case}_on_{seed}", config(seed, shift))
            off, _ = draw(work, f"{case}_off_{seed}", config(seed, None))
            diffs.append((on - off)[window])
        diffs = np.array(diffs)
        bs = truth["boundary_shift"]
        factor = bs["batches_first_order_factor"]
        a = {k: bs["a"][k] * factor for k in ("a_10", "a_01", "a_11", "a_20", "a_02")}
        sx, sy = bs["parameters"]["strength_x"], bs["parameters"]["strength_y"]
        out["cases"][case] = {
            "boundary_shift": shift, "a": a,
            "anisotropy": (sx - sy) / (sx + sy),
            "seeds": args.seeds,
            # [row j][column i] around the centre: y = 24 - 3 + j, x = 24 - 3 + i [e-].
            "moved_e": np.round(diffs.mean(axis=0), 2).tolist(),
            "moved_sem_e": np.round(diffs.std(axis=0, ddof=1) / np.sqrt(len(diffs)), 2).tolist()}
        print(case, "done", flush=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
