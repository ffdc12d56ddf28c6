#!/usr/bin/env python3
"""Coverage of trend's headline intervals over simulated campaigns of one design.

For each of N seeds: `ccdpsf simulate` a campaign from the design (its seed replaced), then
`ccdpsf trend` on it, then compare the headline results with the simulation's own truth:

  alpha       fwhm_um_vs_wavelength alpha      truth: (alpha_x + alpha_y) / 2 (exact at I0)
  fwhm800     requirement fwhm_800nm's value   truth: sqrt(FWHM_x FWHM_y) at (I0, 800 nm)
  slope_x/y   fwhm_x/y_um_vs_intensity slope   truth: s_x, s_y (the simulated laws are linear)
  slope       fwhm_um_vs_intensity slope       truth: least-squares slope of
              sqrt(FWHM_x(I) FWHM_y(I)) at the design's 800 nm intensities (the geometric
              mean of two lines is not a line; the chord and the tangent at I0 differ by
              under 0.1 % for the demo's design, printed below)
  e800        requirement ellipticity_800nm's value  truth: |s_x^2 - s_y^2| / (s_x^2 + s_y^2)
              of the true CCD widths at (I0, 800 nm)

A 68 % (95 %) interval holds the truth when lo68 <= truth <= hi68 (lo95 .. hi95). The table
gives the fraction over campaigns with its binomial standard error sqrt(p (1 - p) / N).
The truth comes from each campaign's truth.json, written by the simulator; the comparison
and the statistics are this script's own.

Usage: bench/campaign_coverage.py --ccdpsf build/ccdpsf --design testdata/campaign_small.json
           --campaigns 20 --work /tmp/coverage [--first_seed 101] [--threads 2]
Output: a table on stdout and WORK/coverage.json (every campaign's numbers).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np


def truth_values(truth, design):
    rel = truth["relations"]
    i0 = rel["reference_intensity_e"]
    lam0 = rel["reference_wavelength_nm"]
    cx, sx = rel["fwhm_x_um_vs_intensity"]["intercept"], rel["fwhm_x_um_vs_intensity"]["slope"]
    cy, sy = rel["fwhm_y_um_vs_intensity"]["intercept"], rel["fwhm_y_um_vs_intensity"]["slope"]
    fx, fy = cx + sx * i0, cy + sy * i0  # at (I0, lambda0)
    intensities = sorted({s["peak_e"] for s in design["campaign"]["settings"] +
                          design["campaign"].get("focus_series", [])
                          if s["wavelength_nm"] == lam0})
    grid = np.array(intensities, dtype=float)
    geometric = np.sqrt((cx + sx * grid) * (cy + sy * grid))
    chord = np.polyfit(grid, geometric, 1)[0] if len(grid) >= 2 else math.nan
    tangent = (sx * fy + sy * fx) / (2.0 * math.sqrt(fx * fy))
    # sigma ratio from FWHM ratio: e depends on the widths' ratio only.
    e = abs(fx ** 2 - fy ** 2) / (fx ** 2 + fy ** 2)
    return {
        "alpha": rel["fwhm_um_vs_wavelength"]["alpha"],
        "fwhm800": math.sqrt(fx * fy),
        "slope": chord,
        "slope_x": sx,
        "slope_y": sy,
        "e800": e,
    }, tangent


def measured(trend):
    r = trend["relations"]
    req = {q["name"]: q for q in trend["requirements"]}

    def requirement(name):
        q = req[name]
        if q["at"]["wavelength_nm"] != 800.0:
            sys.exit("campaign_coverage: requirement %s is not at 800 nm" % name)
        return {k: q[k] for k in ("lo68", "hi68", "lo95", "hi95")} | {"median": q["value"]}

    return {
        "alpha": r["fwhm_um_vs_wavelength"]["alpha"],
        "fwhm800": requirement("fwhm_800nm"),
        "slope": r["fwhm_um_vs_intensity"]["slope"],
        "slope_x": r["fwhm_x_um_vs_intensity"]["slope"],
        "slope_y": r["fwhm_y_um_vs_intensity"]["slope"],
        "e800": requirement("ellipticity_800nm"),
    }


def run(cmd, log):
    with open(log, "w") as out:
        rc = subprocess.call(cmd, stdout=out, stderr=subprocess.STDOUT)
    if rc != 0:
        sys.exit("campaign_coverage: %s failed (exit %d), see %s" % (" ".join(cmd), rc, log))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ccdpsf", required=True)
    ap.add_argument("--design", required=True)
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--first_seed", type=int, default=101)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--work", required=True)
    a = ap.parse_args()
    with open(a.design) as f:
        design = json.load(f)
    os.makedirs(a.work, exist_ok=True)
    rows = []
    tangent = None
    for n in range(a.campaigns):
        seed = a.first_seed + n
        d = json.loads(json.dumps(design))
        d["campaign"]["seed"] = seed
        base = os.path.join(a.work, "seed%d" % seed)
        os.makedirs(base, exist_ok=True)
        cfg = os.path.join(base, "design.json")
        with open(cfg, "w") as f:
            json.dump(d, f)
        data, out = os.path.join(base, "data"), os.path.join(base, "trend")
        t0 = time.time()
        if not os.path.exists(os.path.join(data, "truth.json")):
            run([a.ccdpsf, "simulate", "--config=" + cfg, "--out=" + data],
                os.path.join(base, "simulate.log"))
        if not os.path.exists(os.path.join(out, "trend.json")):
            run([a.ccdpsf, "trend", "--threads=%d" % a.threads, "--seed=%d" % seed,
                 "--out=" + out, data], os.path.join(base, "trend.log"))
        with open(os.path.join(data, "truth.json")) as f:
            truth, tangent = truth_values(json.load(f), d)
        with open(os.path.join(out, "trend.json")) as f:
            got = measured(json.load(f))
        row = {"seed": seed, "seconds": time.time() - t0}
        for k, t in truth.items():
            g = got[k]
            row[k] = {"truth": t, "median": g["median"], "lo68": g["lo68"], "hi68": g["hi68"],
                      "lo95": g.get("lo95"), "hi95": g.get("hi95")}
        rows.append(row)
        print("seed %d: %s (%.1f s)" % (seed, ", ".join(
            "%s %.4g [%.4g, %.4g]" % (k, row[k]["median"], row[k]["lo68"], row[k]["hi68"])
            for k in truth), row["seconds"]), flush=True)
    n = len(rows)
    print("\n%d campaigns of %s; truth slope chord %.4g, tangent at I0 %.4g" %
          (n, a.design, rows[0]["slope"]["truth"], tangent))
    print("| quantity | truth (last) | 68 % coverage | 95 % coverage | mean pull (median - truth) / sd68 |")
    print("| --- | --- | --- | --- | --- |")
    summary = {}
    for k in rows[0]:
        if k in ("seed", "seconds"):
            continue
        in68 = [r[k]["lo68"] <= r[k]["truth"] <= r[k]["hi68"] for r in rows]
        in95 = [r[k]["lo95"] is not None and r[k]["lo95"] <= r[k]["truth"] <= r[k]["hi95"]
                for r in rows]
        pulls = [(r[k]["median"] - r[k]["truth"]) / (0.5 * (r[k]["hi68"] - r[k]["lo68"]))
                 for r in rows]
        p68, p95 = np.mean(in68), np.mean(in95)
        e68, e95 = math.sqrt(p68 * (1 - p68) / n), math.sqrt(p95 * (1 - p95) / n)
        summary[k] = {"cover68": p68, "cover68_se": e68, "cover95": p95, "cover95_se": e95,
                      "mean_pull": float(np.mean(pulls)), "sd_pull": float(np.std(pulls, ddof=1))}
        print("| %s | %.4g | %d/%d = %.2f +- %.2f | %d/%d = %.2f +- %.2f | %+.2f (sd %.2f) |" %
              (k, rows[-1][k]["truth"], sum(in68), n, p68, e68, sum(in95), n, p95, e95,
               summary[k]["mean_pull"], summary[k]["sd_pull"]))
    with open(os.path.join(a.work, "coverage.json"), "w") as f:
        json.dump({"design": a.design, "campaigns": rows, "summary": summary}, f, indent=1)


if __name__ == "__main__":
    main()
