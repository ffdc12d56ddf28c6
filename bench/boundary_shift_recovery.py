#!/usr/bin/env python3
"""Brighter-fatter measured twice on one sensor: from spot series and from flats, against truth.

    /usr/bin/python3 bench/boundary_shift_recovery.py BUILD/ccdpsf OUTDIR [--sets N] [--jobs J]
                     [--with_prior]

Each set s (seed s) is made by tests/support/reference_sensor.py (photon shooting; no ccdpsf
code), one sensor for both kinds of data: the sensor's default boundary shift (pixel boundaries
pushed by the charge already collected; a_10 1.66e-7, a_01 2.55e-7, a_11 3.19e-8 per e-), the
paper's spot (Airy r0 0.47 px, Gaussian defocus 0.41 px, diffusion 0.291 / 0.335 px), gain 3.1,
read noise 4.5 e-:
  spots   12 exposures from 2.6e4 to 5.9e5 e- (x1.33 apart: testdata/reference_sensor/
          intensity_series.json's levels) at random sub-pixel positions, collected in 100
          batches; fitted by `ccdpsf fit --joint --effects=boundary_shift`;
  flats   a bias pair and 12 flat pairs from 1e3 to 1.6e5 e- (geometric), 160 x 160 pixels,
          1 % PRNU, a 2 % gradient, collected in 16 batches; measured by `ccdpsf ptc`;
  prior   (--with_prior) the spots fitted again with the flats' ptc.json as the prior
          (`--ptc`), whose fit.json holds the tool's own spots-against-flats comparison.
The truth each is held against is the sensor's a_ij times its batches' first-order factor
(1 - 1/batches: truth.json), which the two kinds of data see differently.

Prints, per set, the a_ij from spots (median and 68 % interval), from flats (median, sd), the
truth and the differences in sd; then the coverage of the truth by the spots' 68 % intervals
and by the flats' +-1 sd (nominal 68 %, binomial sd 10 % at 20 sets), the CCD widths'
coverage, chi2/dof, and the spots-against-flats differences. Writes OUTDIR/recovery.json.
"""
import argparse
import json
import math
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SENSOR = HERE.parent / "tests" / "support" / "reference_sensor.py"
LAGS = ("a_10", "a_01", "a_11")
DETECTOR = {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000, "pixel_um": 12,
            "saturation_adu": 65535}
SPOT_FLUXES = [25900.0 * 1.33 ** k for k in range(12)]
CCD_SIGMA = {"ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335}


def spot_config(seed):
    rng = np.random.default_rng([seed, 977])
    return {"seed": seed,
            "detector": dict(DETECTOR, nx=48, ny=48),
            "optics": {"airy_radius_px": 0.47, "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                       **CCD_SIGMA},
            "boundary_shift": {},
            "exposures": [{"flux_e": f, "x_px": 24 + rng.uniform(-0.5, 0.5),
                           "y_px": 24 + rng.uniform(-0.5, 0.5),
                           "exptime_s": f / 2e5, "wavelength_nm": 800} for f in SPOT_FLUXES]}


def flat_config(seed):
    levels = [0.0] + [1e3 * 160.0 ** (k / 11.0) for k in range(12)]
    return {"seed": 1000 + seed,
            "detector": dict(DETECTOR, nx=160, ny=160),
            "boundary_shift": {"batches": 16},
            "flats": {"levels_e": levels, "prnu": 0.01, "gradient": [0.02, -0.01]}}


def make(config, folder):
    if (folder / "truth.json").exists():
        return json.loads((folder / "truth.json").read_text())
    folder.parent.mkdir(parents=True, exist_ok=True)
    cfg = folder.parent / (folder.name + ".config.json")
    cfg.write_text(json.dumps(config))
    subprocess.run(["/usr/bin/python3", str(SENSOR), str(cfg), str(folder)], check=True,
                   stdout=subprocess.DEVNULL)
    return json.loads((folder / "truth.json").read_text())


def ccdpsf_run(ccdpsf, args):
    """Runs ccdpsf; returns (seconds, the last line of its error or None)."""
    t0 = time.monotonic()
    r = subprocess.run([ccdpsf] + args, capture_output=True, text=True)
    seconds = time.monotonic() - t0
    if r.returncode != 0:
        lines = r.stderr.strip().splitlines()
        return seconds, lines[-1] if lines else f"exit {r.returncode}"
    return seconds, None


def run_set(ccdpsf, out, seed, with_prior):
    d = Path(out) / f"set_{seed:03d}"
    spot_truth = make(spot_config(seed), d / "spots")
    flat_truth = make(flat_config(seed), d / "flats")
    row = {"seed": seed}
    spot_factor = spot_truth["boundary_shift"]["batches_first_order_factor"]
    flat_factor = flat_truth["boundary_shift"]["flat_batches_first_order_factor"]
    a = spot_truth["boundary_shift"]["a"]
    row["truth_spots"] = {k: a[k] * spot_factor for k in LAGS}
    row["truth_flats"] = {k: a[k] * flat_factor for k in LAGS}
    exposures = sorted(str(p) for p in (d / "spots").glob("exposure_*.fits"))
    flats = [str(d / "flats" / f["file"]) for f in flat_truth["flats"]]

    ptc_json = d / "ptc" / "ptc.json"
    if not ptc_json.exists():
        row["ptc_seconds"], err = ccdpsf_run(ccdpsf, ["ptc", f"--out={d / 'ptc'}"] + flats)
        if err:
            row["error"] = "ptc: " + err
            return row
    ptc = json.loads(ptc_json.read_text())
    row["flats"] = {k: {"median": ptc["a"][k]["median"], "sd": ptc["a"][k]["sd"]} for k in LAGS}

    fits = [("spots", [])]
    if with_prior:
        fits.append(("prior", [f"--ptc={ptc_json}"]))
    for name, extra in fits:
        fit_json = d / ("fit_" + name) / "fit.json"
        if not fit_json.exists():
            row[name + "_seconds"], err = ccdpsf_run(
                ccdpsf, ["fit", "--joint", "--effects=boundary_shift", "--plots=none",
                         "--threads=1", f"--out={d / ('fit_' + name)}"] + extra + exposures)
            if err:
                row["error"] = name + ": " + err
                return row
        f = json.loads(fit_json.read_text())
        p = f["parameters"]
        keys = ["boundary_shift." + k for k in LAGS] + list(CCD_SIGMA) + ["boundary_shift.a_far",
                                                                  "boundary_shift.anisotropy"]
        row[name] = {k.replace("boundary_shift.", ""): {x: p[k][x] for x in
                                                         ("map", "median", "lo68", "hi68")}
                     for k in keys}
        row[name + "_chi2_per_dof"] = f["fit"]["chi2_per_dof"]
        row[name + "_verdict"] = f["quality"]["verdict"]
        if "boundary_shift_vs_flats" in f:
            row[name + "_vs_flats"] = f["boundary_shift_vs_flats"]
    return row


def summarise(rows, with_prior):
    ok = [r for r in rows if "error" not in r]
    n = len(ok)
    print(f"\n{n} sets ({len(rows) - n} failed)")
    if n == 0:
        return

    def half68(e):
        return 0.5 * (e["hi68"] - e["lo68"])

    print("\n| a_ij | truth (spots) | spots: inside 68 % | spots: mean, rms pull | "
          "flats: inside +-1 sd | flats: mean, rms pull | spots - flats: mean, rms [sd] |")
    print("|---|---|---|---|---|---|---|")
    for k in LAGS:
        t_s = ok[0]["truth_spots"][k]
        inside = sum(1 for r in ok if r["spots"][k]["lo68"] <= r["truth_spots"][k] <=
                     r["spots"][k]["hi68"])
        pulls = np.array([(r["spots"][k]["median"] - r["truth_spots"][k]) / half68(r["spots"][k])
                          for r in ok])
        fin = sum(1 for r in ok if abs(r["flats"][k]["median"] - r["truth_flats"][k]) <=
                  r["flats"][k]["sd"])
        fp = np.array([(r["flats"][k]["median"] - r["truth_flats"][k]) / r["flats"][k]["sd"]
                       for r in ok])
        diff = np.array([(r["spots"][k]["median"] - r["flats"][k]["median"]) /
                         math.hypot(half68(r["spots"][k]), r["flats"][k]["sd"]) for r in ok])
        print(f"| {k} | {t_s:.3g} | {inside}/{n} | {pulls.mean():+.2f}, "
              f"{np.sqrt((pulls ** 2).mean()):.2f} | {fin}/{n} | {fp.mean():+.2f}, "
              f"{np.sqrt((fp ** 2).mean()):.2f} | {diff.mean():+.2f}, "
              f"{np.sqrt((diff ** 2).mean()):.2f} |")
    for k, t in CCD_SIGMA.items():
        inside = sum(1 for r in ok if r["spots"][k]["lo68"] <= t <= r["spots"][k]["hi68"])
        med = np.median([r["spots"][k]["median"] for r in ok])
        print(f"{k}: truth {t} inside the 68 % interval in {inside}/{n}; median of medians "
              f"{med:.4f}")
    eta = np.array([r["spots"]["anisotropy"]["median"] for r in ok])
    print(f"anisotropy (the reference sensor's nearest shifts correspond to ~ -0.09): median "
          f"{np.median(eta):+.3f}, range {eta.min():+.3f} to {eta.max():+.3f}")
    chi = np.array([r["spots_chi2_per_dof"] for r in ok])
    print(f"chi2/dof: median {np.median(chi):.4f}, range {chi.min():.4f}-{chi.max():.4f}; "
          f"verdicts: {sorted(set(r['spots_verdict'] for r in ok))}")
    secs = [r["spots_seconds"] for r in ok if "spots_seconds" in r]
    if secs:
        print(f"fit seconds (one thread): median {np.median(secs):.1f}")
    if with_prior:
        print("\nwith the flats as the prior (--ptc):")
        for k in LAGS:
            inside = sum(1 for r in ok if r["prior"][k]["lo68"] <= r["truth_spots"][k] <=
                         r["prior"][k]["hi68"])
            d = [r["prior_vs_flats"][k]["difference_sd"] for r in ok
                 if r.get("prior_vs_flats", {}).get(k, {}).get("difference_sd") is not None]
            dd = np.array(d) if d else np.array([np.nan])
            print(f"  {k}: truth inside 68 % in {inside}/{n}; the tool's spots-alone minus "
                  f"flats: mean {dd.mean():+.2f}, rms {np.sqrt((dd ** 2).mean()):.2f} sd "
                  f"({len(d)} sets)")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("ccdpsf")
    ap.add_argument("out")
    ap.add_argument("--sets", type=int, default=20)
    ap.add_argument("--first", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--with_prior", action="store_true")
    a = ap.parse_args()
    seeds = range(a.first, a.first + a.sets)
    rows = []
    with ThreadPoolExecutor(a.jobs) as pool:
        for row in pool.map(lambda s: run_set(a.ccdpsf, a.out, s, a.with_prior), seeds):
            rows.append(row)
            if "error" in row:
                print(f"set {row['seed']:3d}: {row['error']}", flush=True)
                continue
            cells = " ".join(f"{k} {row['spots'][k]['median']:.3g} "
                             f"[{row['spots'][k]['lo68']:.3g}, {row['spots'][k]['hi68']:.3g}] "
                             f"flats {row['flats'][k]['median']:.3g}+-{row['flats'][k]['sd']:.2g}"
                             for k in LAGS)
            print(f"set {row['seed']:3d}: {cells}; chi2/dof {row['spots_chi2_per_dof']:.3f}",
                  flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    Path(a.out, "recovery.json").write_text(json.dumps(rows, indent=1))
    summarise(rows, a.with_prior)


if __name__ == "__main__":
    sys.exit(main())
