#!/usr/bin/env python3
"""What a complete `ccdpsf fit` of one exposure spends outside its fitting engine.

Runs `ccdpsf fit` on a bundled exposure (testdata/campaign_small, 21 x 21, 1.6e5 e- peak)
--runs times for each picture choice (--plots=all, the default, and --plots=none, which
writes the pictures' data and scripts but runs no gnuplot), alternating the two, and prints
the medians of: the command's wall time; the engine's time from fit.json (fit.map_seconds,
the MAP search with the first render's table build, plus fit.seconds, the Laplace step,
MCMC and derived quantities); and the rest, the fixed costs (process start with its shared
libraries, reading and checking the FITS file, writing fit.json, chain.fits,
residuals.fits, report.md and the plot data with their fsyncs, the folder swap; with
--plots=all also gnuplot drawing the corner and residual pictures), as a share of the wall
time.

  /usr/bin/python3 bench/fit_cli_costs.py [--ccdpsf build/ccdpsf] [--runs 7] [--threads 2]
"""

import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
EXPOSURE = os.path.join(HERE, '..', 'testdata', 'campaign_small', 'g00_600nm_160200e',
                        'exposure_000.fits')


def run(ccdpsf, out, plots, threads):
    """One fit: (wall seconds, engine seconds)."""
    start = time.perf_counter()
    subprocess.run([ccdpsf, 'fit', '--out=' + out, '--plots=' + plots,
                    '--threads=' + str(threads), EXPOSURE],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    with open(os.path.join(out, 'fit.json')) as f:
        fit = json.load(f)
    # fit.seconds: the Laplace step, the MCMC and the derived quantities after the MAP.
    return wall, fit['fit']['map_seconds'] + fit['fit']['seconds']


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--ccdpsf', default=os.path.join(HERE, '..', 'build', 'ccdpsf'))
    parser.add_argument('--runs', type=int, default=7)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    choices = ('all', 'none')
    times = {c: [] for c in choices}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.runs):
            for c in choices:
                times[c].append(run(args.ccdpsf, os.path.join(tmp, c), c, args.threads))
    print(f'ccdpsf fit, one exposure, --threads={args.threads}, medians of {args.runs} runs')
    print(f'{"--plots":8s} {"wall [s]":>9s} {"engine [s]":>11s} {"fixed [s]":>10s} '
          f'{"fixed share":>12s}')
    for c in choices:
        wall = statistics.median(w for w, _ in times[c])
        engine = statistics.median(e for _, e in times[c])
        fixed = statistics.median(w - e for w, e in times[c])
        print(f'{c:8s} {wall:9.3f} {engine:11.3f} {fixed:10.3f} {fixed / wall:11.0%}')


if __name__ == '__main__':
    main()
