#!/usr/bin/env python3
"""Times a complete ccdpsf single-exposure fit beside the 2015 approach on the same frame.

The 2015 approach (the paper, section 4): the pixel_centre model computed with numpy/scipy
(two scipy.signal.convolve2d, as tools/make_pixel_centre_reference.py transcribes it), the
paper's log-likelihood (its eq. simplifiedLikelihood with the noise model of eq. CCDnoise,
sigma^2 = M / g + (RN / g)^2 in ADU, constant terms omitted) under box priors, sampled by emcee
with 1000 walkers for 1700 steps. Running that takes ~20 minutes of CPU, so the script runs
emcee for --steps steps with the same 1000 walkers, measures the CPU per step (every step
evaluates the posterior once per walker, so the cost per step is constant) and scales it to
1700 steps. ccdpsf is timed running the whole command (`ccdpsf fit`, MAP + Laplace + MCMC to
ESS 1000, report, tables and plots), CPU of the process and its children (gnuplot), in both
samplings: pixel_centre (the 2015 model, exactly) and integrated (the default).

Run from the repository root after building (Debian 12: python3-numpy, -scipy, -astropy,
-emcee):

  /usr/bin/python3 bench/compare_2015.py [--ccdpsf build/ccdpsf] [--runs 5] [--steps 20]

It prints the machine, its load, medians over --runs runs (the 2015 figure is extrapolated
from each run's emcee steps) and the ratio. Nothing is written outside a temporary folder.
"""

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import timeit

import numpy as np
from astropy.io import fits

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tools'))
from make_pixel_centre_reference import pixel_centre_model  # noqa: E402

FRAME = 'testdata/campaign_small/g02_800nm_157800e/exposure_000.fits'
STAMP = 21
STEPS_2015 = 1700
WALKERS_2015 = 1000


def simulation_2015():
    """The paper's simulation (section 3.3, testdata/demo_simulation.json) in the 2015 model
    itself, on a 21 x 21 frame: the 2015 approach and `ccdpsf fit --sampling=pixel_centre`
    fit this one."""
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, '..', 'testdata', 'demo_simulation.json')) as f:
        config = json.load(f)
    config['seed'] = 2015
    config['image'] = {'nx': STAMP, 'ny': STAMP}
    config['model']['sampling'] = 'pixel_centre'
    config['exposures'] = [{'peak_e': 1.5e5, 'x_px': 10.07, 'y_px': 9.96}]
    return config


def cpu_model():
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def stamp_in_adu(path):
    """The 21 x 21 stamp around the brightest pixel, bias removed [ADU], and gain, read noise."""
    with fits.open(path) as hdul:
        header = hdul[0].header
        image = hdul[0].data.astype(np.float64)
    gain = float(header['GAIN'])
    read_noise_e = float(header['RDNOISE'])
    image = image - float(header['BIASLVL'])
    y, x = np.unravel_index(np.argmax(image), image.shape)
    half = STAMP // 2
    stamp = image[y - half:y + half + 1, x - half:x + half + 1]
    if stamp.shape != (STAMP, STAMP):
        raise SystemExit('%s: the brightest pixel is too close to the edge' % path)
    return stamp, gain, read_noise_e


class Posterior2015:
    """log posterior of the 2015 approach, parameters (m [ADU], x, y, r, sigma_f, sigma_x,
    sigma_y) on the stamp, box priors."""

    def __init__(self, data_adu, gain, read_noise_e):
        self.data = data_adu
        self.gain = gain
        self.rn2 = (read_noise_e / gain) ** 2
        c = STAMP // 2
        self.lo = np.array([1.0, c - 2.0, c - 2.0, 0.1, 0.02, 0.02, 0.02])
        self.hi = np.array([1e7, c + 2.0, c + 2.0, 2.0, 2.0, 2.0, 2.0])

    def __call__(self, p):
        if np.any(p < self.lo) or np.any(p > self.hi):
            return -np.inf
        model, _ = pixel_centre_model(STAMP, *p)
        var = np.maximum(model, 0.0) / self.gain + self.rn2
        return -0.5 * np.sum((self.data - model) ** 2 / var)


def start_point(data):
    c = STAMP // 2
    return np.array([data[c, c], c + 0.05, c - 0.05, 0.47, 0.41, 0.3, 0.3])


def time_2015(posterior, start, steps, seed):
    """CPU seconds per emcee step with 1000 walkers, and per posterior evaluation."""
    import emcee
    rng = np.random.default_rng(seed)
    scale = np.array([0.01 * start[0], 0.01, 0.01, 0.005, 0.01, 0.01, 0.01])
    p0 = start + scale * rng.standard_normal((WALKERS_2015, start.size))
    sampler = emcee.EnsembleSampler(WALKERS_2015, start.size, posterior)
    t0 = time.process_time()
    sampler.run_mcmc(p0, steps, progress=False)
    per_step = (time.process_time() - t0) / steps
    evaluation = min(timeit.repeat(lambda: posterior(start), number=200, repeat=5)) / 200
    return per_step, evaluation


def time_ccdpsf(binary, frame, sampling, out):
    """CPU seconds (user + system) of one complete `ccdpsf fit`, its children included."""
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall0 = time.perf_counter()
    result = subprocess.run([binary, 'fit', '--out=' + out, '--seed=1', '--sampling=' + sampling,
                             frame], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - wall0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode != 0:
        raise SystemExit('ccdpsf fit failed: ' + result.stderr.strip())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--ccdpsf', default='build/ccdpsf', help='the ccdpsf binary')
    parser.add_argument('--frame', default=FRAME, help='the frame of the integrated fit '
                        '(default: one exposure of the bundled campaign, 158 ke- peak)')
    parser.add_argument('--runs', type=int, default=5, help='runs of each measurement')
    parser.add_argument('--steps', type=int, default=20,
                        help='emcee steps actually run per 2015 measurement (1000 walkers)')
    args = parser.parse_args()
    if args.runs < 1 or args.steps < 1:
        raise SystemExit('--runs and --steps must be at least 1')
    if not os.access(args.ccdpsf, os.X_OK):
        raise SystemExit('%s: not an executable (build first, or give --ccdpsf)' % args.ccdpsf)

    print('machine: %s, %d cores; load average before: %.2f %.2f %.2f'
          % ((cpu_model(), os.cpu_count()) + os.getloadavg()))
    per_step, evaluation, fits_cpu = [], [], {'pixel_centre': [], 'integrated': []}
    fits_wall = {'pixel_centre': [], 'integrated': []}
    with tempfile.TemporaryDirectory() as scratch:
        config = os.path.join(scratch, 'sim_2015.json')
        with open(config, 'w') as f:
            json.dump(simulation_2015(), f)
        simulated = os.path.join(scratch, 'sim_2015')
        subprocess.run([args.ccdpsf, 'simulate', '--config=' + config, '--out=' + simulated],
                       check=True, stdout=subprocess.DEVNULL)
        frames = {'pixel_centre': os.path.join(simulated, 'exposure_000.fits'),
                  'integrated': args.frame}
        print('frames: %s (pixel_centre: the paper\'s simulation in the 2015 model, 150 ke- '
              'peak); %s (integrated)' % (frames['pixel_centre'], frames['integrated']))
        data, gain, read_noise_e = stamp_in_adu(frames['pixel_centre'])
        posterior = Posterior2015(data, gain, read_noise_e)
        start = start_point(data)
        for run in range(args.runs):
            step, ev = time_2015(posterior, start, args.steps, seed=run)
            per_step.append(step)
            evaluation.append(ev)
            for sampling in fits_cpu:
                cpu, wall = time_ccdpsf(args.ccdpsf, frames[sampling], sampling,
                                        os.path.join(scratch, sampling))
                fits_cpu[sampling].append(cpu)
                fits_wall[sampling].append(wall)
    print('load average after: %.2f %.2f %.2f' % os.getloadavg())

    step = statistics.median(per_step)
    total_2015 = step * STEPS_2015
    print()
    print('| | CPU [s], median of %d | wall [s] | 2015 / this |' % args.runs)
    print('|---|---|---|---|')
    print('| 2015 approach: numpy model %.0f us an evaluation, emcee %d walkers x %d steps '
          '(%.3f s a step, measured over %d steps) | %.0f | | 1 |'
          % (1e6 * statistics.median(evaluation), WALKERS_2015, STEPS_2015, step, args.steps,
             total_2015))
    for sampling in ('pixel_centre', 'integrated'):
        cpu = statistics.median(fits_cpu[sampling])
        wall = statistics.median(fits_wall[sampling])
        print('| ccdpsf fit --sampling=%s (MAP, Laplace, MCMC to ESS 1000, report, plots) '
              '| %.2f | %.2f | %.0f |' % (sampling, cpu, wall, total_2015 / cpu))


if __name__ == '__main__':
    main()
