#!/usr/bin/env python3
"""How a joint fit's cost grows with its number of exposures.

Simulates eight exposures of the paper's spot (testdata/demo_simulation.json: section 3.3
values, 4.26e5 e-; sub-pixel positions of their own) with `ccdpsf simulate`, then runs
`ccdpsf fit --joint` on the first N = 1, 2, 3, 5, 8 of them, one thread, --runs times each, and prints the medians of: the
MCMC's seconds per posterior evaluation (mcmc.seconds / (steps x walkers), from fit.json),
that per exposure, and the whole command's wall time. A per-exposure cost that falls with N
is the sub-linear growth issue 18 asks for (the exposures share the Airy image of a proposal).

  /usr/bin/python3 bench/joint_scaling.py [--ccdpsf build/ccdpsf] [--runs 3]
"""

import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time

COUNTS = (1, 2, 3, 5, 8)
POSITIONS = [(32.07, 23.96), (31.98, 24.05), (32.02, 23.91), (31.93, 24.02), (32.09, 24.08),
             (31.95, 23.93), (32.04, 24.10), (31.91, 23.99)]


def simulation():
    """testdata/demo_simulation.json (the paper's spot and detector) with eight exposures."""
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, '..', 'testdata', 'demo_simulation.json')) as f:
        config = json.load(f)
    config['seed'] = 18
    flux = config['exposures'][0]['flux_e']
    config['exposures'] = [{'flux_e': flux, 'x_px': x, 'y_px': y} for x, y in POSITIONS]
    return config


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--ccdpsf', default='build/ccdpsf', help='the ccdpsf binary')
    parser.add_argument('--runs', type=int, default=3, help='runs per exposure count')
    args = parser.parse_args()
    if args.runs < 1:
        raise SystemExit('--runs must be at least 1')
    if not os.access(args.ccdpsf, os.X_OK):
        raise SystemExit('%s: not an executable (build first, or give --ccdpsf)' % args.ccdpsf)
    print('load average before: %.2f %.2f %.2f' % os.getloadavg())
    with tempfile.TemporaryDirectory() as scratch:
        config = os.path.join(scratch, 'sim.json')
        with open(config, 'w') as f:
            json.dump(simulation(), f)
        frames = os.path.join(scratch, 'frames')
        subprocess.run([args.ccdpsf, 'simulate', '--config=' + config, '--out=' + frames],
                       check=True, stdout=subprocess.DEVNULL)
        files = [os.path.join(frames, 'exposure_%03d.fits' % k) for k in range(len(POSITIONS))]
        print('| exposures | us per evaluation | us per evaluation and exposure | '
              'steps x walkers | command wall [s] |')
        print('|---|---|---|---|---|')
        for n in COUNTS:
            per_eval, walls, sizes = [], [], []
            for _ in range(args.runs):
                out = os.path.join(scratch, 'fit')
                command = [args.ccdpsf, 'fit', '--out=' + out, '--threads=1', '--seed=1']
                command += (['--joint'] if n > 1 else []) + files[:n]
                start = time.perf_counter()
                subprocess.run(command, check=True, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
                walls.append(time.perf_counter() - start)
                with open(os.path.join(out, 'fit.json')) as f:
                    mcmc = json.load(f)['mcmc']
                evaluations = mcmc['steps'] * mcmc['walkers']
                per_eval.append(1e6 * mcmc['seconds'] / evaluations)
                sizes.append(evaluations)
            e = statistics.median(per_eval)
            print('| %d | %.1f | %.1f | %d | %.2f |'
                  % (n, e, e / n, statistics.median(sizes), statistics.median(walls)))
    print('load average after: %.2f %.2f %.2f' % os.getloadavg())


if __name__ == '__main__':
    main()
