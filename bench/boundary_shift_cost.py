#!/usr/bin/env python3
"""What boundary_shift costs a complete joint fit (MAP, Laplace, MCMC) of an intensity series.

Fits each reference-sensor series (12 exposures, 2.6e4 to 5.9e5 e- in the peak, pixel
boundaries moved by the collected charge: the sets `bench/boundary_shift_recovery.py` writes,
SETS/set_NNN/spots/*.fits) twice, `ccdpsf fit --joint` without any effect and with
`--effects=boundary_shift`, one thread, no pictures, --runs times each (alternating), and
prints per set the median wall time of each, their ratio, and the MCMC's steps, walkers and
Laplace-move acceptance from fit.json; then the median ratio over the sets. Both fits see
the same data: the question is what the effect adds to the same work.

  /usr/bin/python3 bench/boundary_shift_cost.py BUILD/ccdpsf SETS [--sets 5] [--runs 3]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def fit(ccdpsf, files, out, with_shift):
    """One fit: (wall seconds, fit.json's mcmc block)."""
    args = [ccdpsf, "fit", "--joint", "--threads=1", "--plots=none", "--out=" + out]
    if with_shift:
        args.append("--effects=boundary_shift")
    start = time.perf_counter()
    r = subprocess.run(args + files, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                       text=True)
    wall = time.perf_counter() - start
    if r.returncode != 0:
        lines = r.stderr.strip().splitlines()
        sys.exit("ccdpsf fit failed: " + (lines[-1] if lines else "exit %d" % r.returncode))
    with open(os.path.join(out, "fit.json")) as f:
        return wall, json.load(f)["mcmc"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ccdpsf")
    ap.add_argument("sets", type=Path)
    ap.add_argument("--sets", dest="num_sets", type=int, default=5)
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    dirs = sorted(p for p in a.sets.glob("set_*") if (p / "spots").is_dir())[: a.num_sets]
    if not dirs:
        sys.exit("no SETS/set_*/spots folders in %s" % a.sets)
    print("| set | without [s] | with [s] | ratio | steps without / with | walkers | "
          "Laplace acceptance without / with |")
    print("|---|---|---|---|---|---|---|")
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in dirs:
            files = sorted(str(p) for p in (d / "spots").glob("*.fits"))
            times = {False: [], True: []}
            mcmc = {}
            for run in range(a.runs):
                for with_shift in (False, True):
                    out = os.path.join(tmp, "%s_%d_%d" % (d.name, with_shift, run))
                    wall, mcmc[with_shift] = fit(a.ccdpsf, files, out, with_shift)
                    times[with_shift].append(wall)
            t0, t1 = statistics.median(times[False]), statistics.median(times[True])
            ratios.append(t1 / t0)

            def acc(m):
                v = m.get("laplace_move_acceptance")
                return "-" if v is None else "%.2f" % v

            print("| %s | %.2f | %.2f | %.2f | %d / %d | %d / %d | %s / %s |" % (
                d.name, t0, t1, t1 / t0, mcmc[False]["steps"], mcmc[True]["steps"],
                mcmc[False]["walkers"], mcmc[True]["walkers"], acc(mcmc[False]),
                acc(mcmc[True])), flush=True)
    print("\nmedian ratio over %d sets: %.2f (range %.2f-%.2f); load average at the end: %s" % (
        len(ratios), statistics.median(ratios), min(ratios), max(ratios),
        " ".join("%.2f" % x for x in os.getloadavg())))


if __name__ == "__main__":
    main()
