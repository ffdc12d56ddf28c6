#!/usr/bin/env python3
"""Writes testdata/pixel_centre_reference.json: the `pixel_centre` model of the authors' 2015
code, as docs/conventions.md (Sampling) describes it, computed with numpy/scipy on a few stamps.

This is a literal transcription of that description, kept deliberately naive (no
normalisation, scipy.signal.convolve2d with mode='same' and its zero padding) so that the C++
compatibility mode (Sampling::kPixelCentre) can be checked against it to rounding error:

  stamp n x n, X, Y = np.meshgrid(np.arange(n), np.arange(n))  (X column, Y row; arrays [y, x])
  c  = int(n/2 - 0.5)                                          (centre pixel, 10 for n = 21)
  A  = amp [2 J1(pi q) / (pi q)]^2, q = hypot(X - x, Y - y) / (r / Rz), value amp at q = 0,
       amp such that A[c, c] = m                               (m: peak meta-parameter)
  F  = exp(-((X - x)^2 + (Y - y)^2) / (2 sigma_f^2))           (unit peak, on the spot)
  M1 = convolve2d(A, F, mode='same')
  G  = exp(-(X - n/2 + 0.5)^2 / (2 sigma_x^2) - (Y - n/2 + 0.5)^2 / (2 sigma_y^2))
  M  = convolve2d(M1, G, mode='same')

Regenerate (Debian 12: the system interpreter has python3-numpy and python3-scipy):

  /usr/bin/python3 tools/make_pixel_centre_reference.py testdata/pixel_centre_reference.json

The output is deterministic (fixed seed); json writes every float with repr, i.e. the
shortest string that reads back to the same double.
"""

import argparse
import json
import sys

import numpy as np
import scipy
from scipy.signal import convolve2d
from scipy.special import j1

# astropy AiryDisk2D's constant: the first zero of J1(pi x).
RZ = 1.2196698912665045


def airy_profile(q):
    """[2 J1(pi q) / (pi q)]^2, with its limit 1 at q = 0 (astropy's AiryDisk2D form)."""
    out = np.ones_like(q)
    nonzero = q > 0
    z = np.pi * q[nonzero]
    out[nonzero] = (2.0 * j1(z) / z) ** 2
    return out


def pixel_centre_model(n, m, x, y, r, sigma_f, sigma_x, sigma_y):
    """The 2015 model M (n x n, indexed [y, x]) and the Airy profile at the centre pixel."""
    X, Y = np.meshgrid(np.arange(n), np.arange(n))
    c = int(n / 2 - 0.5)
    q = np.hypot(X - x, Y - y) / (r / RZ)
    profile = airy_profile(q)
    amp = m / profile[c, c]
    A = amp * profile
    F = np.exp(-((X - x) ** 2 + (Y - y) ** 2) / (2.0 * sigma_f ** 2))
    M1 = convolve2d(A, F, mode='same')
    G = np.exp(-(X - n / 2 + 0.5) ** 2 / (2.0 * sigma_x ** 2)
               - (Y - n / 2 + 0.5) ** 2 / (2.0 * sigma_y ** 2))
    M = convolve2d(M1, G, mode='same')
    return M, profile[c, c]


def check_same_mode_convention(n):
    """convolve2d(..., mode='same'): kernel index (c, c) is zero shift (docs/conventions.md)."""
    c = int(n / 2 - 0.5)
    rng = np.random.default_rng(1)
    image = rng.random((n, n))
    delta = np.zeros((n, n))
    delta[c, c] = 1.0
    assert np.array_equal(convolve2d(image, delta, mode='same'), image), n


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('output', help='path of the JSON file to write')
    args = parser.parse_args()

    cases = [
        # The paper's values on its 21 x 21 stamp.
        dict(name='paper_21', n=21, m=1.5e5, x=10.07, y=9.96, r=0.47, sigma_f=0.41,
             sigma_x=0.291, sigma_y=0.335),
        # Even stamp: c = 9 while G is centred on 9.5, so G also shifts the image by half a
        # pixel; any error in the 'same' offset or a flipped kernel shows here.
        dict(name='even_20', n=20, m=8.0e4, x=9.62, y=9.31, r=0.62, sigma_f=0.35,
             sigma_x=0.25, sigma_y=0.4),
        # Off-centre spot: the normalising pixel (c, c) = (7, 7) lies on the first bright ring
        # (q = 1.84), so amp is ~57 m, and F shifts the image by (x - c, y - c).
        dict(name='off_centre_15', n=15, m=2.0e4, x=6.2, y=8.1, r=0.9, sigma_f=0.3,
             sigma_x=0.5, sigma_y=0.2),
        # Spot exactly on the centre pixel: q = 0 there, so amp = m.
        dict(name='on_centre_pixel_17', n=17, m=1.0e5, x=8.0, y=8.0, r=0.35, sigma_f=0.2,
             sigma_x=0.3, sigma_y=0.3),
    ]
    rng = np.random.default_rng(20150)
    for k, n in enumerate((11, 24)):
        c = int(n / 2 - 0.5)
        cases.append(dict(
            name='random_%d' % k, n=n, m=float(rng.uniform(1e4, 2e5)),
            x=float(c + rng.uniform(-0.5, 0.5)), y=float(c + rng.uniform(-0.5, 0.5)),
            r=float(rng.uniform(0.3, 0.9)), sigma_f=float(rng.uniform(0.1, 0.8)),
            sigma_x=float(rng.uniform(0.1, 0.8)), sigma_y=float(rng.uniform(0.1, 0.8))))

    for case in cases:
        check_same_mode_convention(case['n'])
        model, profile_at_c = pixel_centre_model(
            case['n'], case['m'], case['x'], case['y'], case['r'], case['sigma_f'],
            case['sigma_x'], case['sigma_y'])
        # The normalising pixel must not sit near an Airy zero, or the fixture would test
        # J1's relative accuracy near its zeros rather than the model.
        assert profile_at_c > 1e-3, (case['name'], profile_at_c)
        assert np.all(np.isfinite(model)) and np.all(model >= 0.0), case['name']
        case['model'] = [[float(v) for v in row] for row in model]

    # One model row per line keeps the file readable and diffs small.
    lines = ['{',
             '  "description": %s,' % json.dumps(
                 'pixel_centre model of the 2015 Python code (docs/conventions.md, Sampling); '
                 'model[y][x] is the value at stamp pixel (x, y); parameters m [e-], '
                 'x, y [px, stamp indices], r, sigma_f, sigma_x, sigma_y [px]'),
             '  "generator": "tools/make_pixel_centre_reference.py",',
             '  "numpy_version": %s,' % json.dumps(np.__version__),
             '  "scipy_version": %s,' % json.dumps(scipy.__version__),
             '  "cases": [']
    for i, case in enumerate(cases):
        lines.append('    {')
        for key in ('name', 'n', 'm', 'x', 'y', 'r', 'sigma_f', 'sigma_x', 'sigma_y'):
            lines.append('      %s: %s,' % (json.dumps(key), json.dumps(case[key])))
        lines.append('      "model": [')
        rows = [json.dumps(row) for row in case['model']]
        lines.append(',\n'.join('        ' + row for row in rows))
        lines.append('      ]')
        lines.append('    }' + (',' if i + 1 < len(cases) else ''))
    lines.append('  ]')
    lines.append('}')
    text = '\n'.join(lines) + '\n'

    # The file must read back to exactly the arrays computed above.
    parsed = json.loads(text)
    for case, back in zip(cases, parsed['cases']):
        assert back['model'] == case['model'], case['name']

    with open(args.output, 'w') as f:
        f.write(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
