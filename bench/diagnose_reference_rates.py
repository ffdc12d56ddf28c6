#!/usr/bin/env python3
"""How often `ccdpsf diagnose` gives the right answer on physics it did not simulate.

    /usr/bin/python3 bench/diagnose_reference_rates.py BUILD/ccdpsf OUTDIR [--sets N] [--jobs J]
                     [--cases clean,series,pillbox,response,bf,intrapixel,series12,boundary]

Each set is made by tests/support/reference_sensor.py (photon shooting; no ccdpsf code) with
the paper's spot (Airy r0 0.47 px, CCD diffusion 0.291 / 0.335 px, gain 3.1, read noise 4.5 e-)
and five exposures at random sub-pixel positions, seed = set number:

  clean       Gaussian defocus 0.41 px, 4.26e5 e- each             right: no missing effect
  series      as clean at 2e4, 5e4, 1e5, 2e5, 4e5 e-                right: no missing effect
  pillbox     pillbox defocus R = 1.0 px, 4.26e5 e-                 right: pillbox_defocus
  response    pixel collecting window 0.8 px wide, 4.26e5 e-        right: pixel_response
  intrapixel  sensitivity falling linearly to 0.5 at the pixel edges (not modelled)
                                                                     right: pixel_response or
                                                                     unexplained
  bf          the series with brighter-fatter (diffusion variance growing by 6e-6 per e- already
              collected)                                            right: brighter_fatter or
                                                                     boundary_shift, or
                                                                     unexplained with one partial
  series12    12 exposures from 2.6e4 to 5.9e5 e- (x1.33 apart, testdata/reference_sensor/
              intensity_series.json's levels), no brighter-fatter   right: no missing effect
  boundary    series12 on a sensor whose pixel boundaries move with the collected charge (the
              sensor's default boundary_shift: a_10 1.66e-7, a_01 2.55e-7, a_11 3.2e-8 per e-)
                                                                     right: boundary_shift
                                                                     (brighter_fatter, the
                                                                     empirical law, may be a
                                                                     close rival), or
                                                                     unexplained with it partial

"Confidently wrong" is a verdict that names, as explaining, an effect that is not the truth.
Writes OUTDIR/rates.json and prints a markdown table; each diagnosis is timed (wall clock,
`--threads=1`, J at a time).
"""
import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SENSOR = HERE.parent / "tests" / "support" / "reference_sensor.py"

SERIES = [2e4, 5e4, 1e5, 2e5, 4e5]
SERIES12 = [25900.0 * 1.33 ** k for k in range(12)]
# names: what explains the set; rivals: names that may stand beside it as close (ambiguous)
# without making the verdict wrong.
RIGHT = {
    "clean": {"names": [], "unexplained_ok": False},
    "series": {"names": [], "unexplained_ok": False},
    "pillbox": {"names": ["pillbox_defocus"], "unexplained_ok": True},
    "response": {"names": ["pixel_response"], "unexplained_ok": True},
    "intrapixel": {"names": ["pixel_response"], "unexplained_ok": True},
    "bf": {"names": ["brighter_fatter", "boundary_shift"], "unexplained_ok": True,
           "any_of": True},
    "series12": {"names": [], "unexplained_ok": False},
    "boundary": {"names": ["boundary_shift"], "rivals": ["brighter_fatter"],
                 "unexplained_ok": True},
}


def config(case, seed):
    rng = np.random.default_rng([seed, 977])
    c = {"seed": seed,
         "detector": {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000,
                      "pixel_um": 12, "saturation_adu": 65535, "nx": 48, "ny": 48},
         "optics": {"airy_radius_px": 0.47, "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                    "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335}}
    fluxes = [4.26e5] * 5
    if case == "pillbox":
        c["optics"]["defocus"] = {"kind": "pillbox", "radius_px": 1.0}
    elif case == "response":
        c["pixel_response"] = {"kind": "box", "width_px": 0.8}
    elif case == "intrapixel":
        c["pixel_response"] = {"kind": "intrapixel", "edge_sensitivity": 0.5}
    elif case in ("series", "bf"):
        fluxes = SERIES
        if case == "bf":
            c["brighter_fatter"] = {"strength": 6e-6, "batches": 100}
    elif case in ("series12", "boundary"):
        fluxes = SERIES12
        if case == "boundary":
            c["boundary_shift"] = {}
    c["exposures"] = [{"flux_e": f, "x_px": 24 + rng.uniform(-0.5, 0.5),
                       "y_px": 24 + rng.uniform(-0.5, 0.5),
                       "exptime_s": 4.1 * f / max(fluxes), "wavelength_nm": 800}
                      for f in fluxes]
    return c


def run_one(ccdpsf, out, case, seed):
    d = Path(out) / f"{case}_{seed:03d}"
    d.mkdir(parents=True, exist_ok=True)
    cfg = d / "config.json"
    cfg.write_text(json.dumps(config(case, seed)))
    if not (d / "data" / "truth.json").exists():
        subprocess.run(["/usr/bin/python3", str(SENSOR), str(cfg), str(d / "data")], check=True,
                       stdout=subprocess.DEVNULL)
    files = sorted(str(p) for p in (d / "data").glob("exposure_*.fits"))
    t0 = time.monotonic()
    r = subprocess.run([ccdpsf, "diagnose", "--threads=1", f"--out={d / 'diagnose'}"] + files,
                       capture_output=True, text=True)
    seconds = time.monotonic() - t0
    row = {"case": case, "seed": seed, "seconds": seconds, "exit": r.returncode}
    if r.returncode != 0:
        row["error"] = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "?"
        return row
    j = json.loads((d / "diagnose" / "diagnose.json").read_text())
    row.update({"verdict": j["verdict"], "named": j["named_effects"], "explained": j["explained"],
                "partial": [p["name"] for p in j["partial"]],
                "ambiguous": [a["name"] for a in j["ambiguous"]],
                "chi2_before": j["rounds"][0]["chi2_per_dof"],
                "chi2_after": j["rounds"][-1]["chi2_per_dof"]})
    params = {}
    for a in j["attributions"]:
        for k, v in a.get("parameters", {}).items():
            params[k] = v["map"]
    shift = j["final_fit"]["effects"].get("boundary_shift")
    if shift:
        for k in ("a_10", "a_01", "a_11", "a_far"):
            if k in shift:
                params["boundary_shift." + k] = shift[k].get("map")
    bf = j["final_fit"]["effects"].get("brighter_fatter")
    if bf:
        params["total_slope_x_px_per_e"] = bf.get("total_slope_x_px_per_e", {}).get("map")
    if j["width_trend"]["measured"]:
        params["width_trend_x_percent_per_1e5"] = j["width_trend"]["x"]["percent_per_1e5_e"]
        params["width_trend_x_percent_sd"] = j["width_trend"]["x"]["percent_sd"]
    row["parameters"] = params
    return row


def judge(row):
    """right / unexplained / wrong (a confident wrong name) / failed."""
    if row.get("exit") != 0:
        return "failed"
    right = RIGHT[row["case"]]
    named = set(row["named"]) | set(row["ambiguous"])
    wrong = named - set(right["names"]) - set(right.get("rivals", []))
    if wrong:
        return "wrong"
    truth = set(right["names"])
    found = (bool(named & truth) and len(set(row["named"])) == 1) if right.get("any_of") \
        else set(row["named"]) == truth
    if row["explained"] and found:
        return "right"
    if not row["explained"]:
        return "unexplained"
    return "missed"  # explained, but without the true name (a clean verdict on altered data)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("ccdpsf")
    ap.add_argument("out")
    ap.add_argument("--sets", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cases", default="clean,series,pillbox,response,intrapixel,bf")
    a = ap.parse_args()
    cases = a.cases.split(",")
    for c in cases:
        if c not in RIGHT:
            sys.exit(f"unknown case '{c}'")
    jobs = [(c, s) for c in cases for s in range(a.sets)]
    rows = []
    with ThreadPoolExecutor(a.jobs) as pool:
        for row in pool.map(lambda cs: run_one(a.ccdpsf, a.out, *cs), jobs):
            row["outcome"] = judge(row)
            rows.append(row)
            print(f"{row['case']:10s} {row['seed']:3d} {row['outcome']:11s} "
                  f"{row.get('verdict', row.get('error', ''))[:90]} ({row['seconds']:.1f} s)",
                  flush=True)
    Path(a.out, "rates.json").write_text(json.dumps(rows, indent=1))
    print("\n| case | sets | right | unexplained | missed | confidently wrong | failed | "
          "median s |\n|---|---|---|---|---|---|---|---|")
    for c in cases:
        r = [x for x in rows if x["case"] == c]
        n = {k: sum(1 for x in r if x["outcome"] == k)
             for k in ("right", "unexplained", "missed", "wrong", "failed")}
        print(f"| {c} | {len(r)} | {n['right']} | {n['unexplained']} | {n['missed']} | "
              f"{n['wrong']} | {n['failed']} | {np.median([x['seconds'] for x in r]):.1f} |")


if __name__ == "__main__":
    main()
