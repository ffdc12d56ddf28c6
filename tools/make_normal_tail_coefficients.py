#!/usr/bin/env python3
"""Prints the Chebyshev coefficients behind src/internal/normal_tail.cc.

The upper tail of the standard normal, Q(x) = P(Z > x) = erfc(x / sqrt 2) / 2 for x >= 0, is
written as Q(x) = phi(x) R(x), with phi the density and R the Mills ratio,
R(x) = sqrt(pi / 2) exp(x^2 / 2) erfc(x / sqrt 2), smooth and decreasing from sqrt(pi / 2) at 0
like 1/x. With t = K / (K + x), which maps [0, inf) onto (0, 1], G(t) = R(x) / t is analytic on
[0, 1] (G(0) = 1 / K, from R(x) ~ 1/x), so a short Chebyshev series in u = 2 t - 1 holds it:
  G(t) = sum_k c_k T_k(u),  R(x) = t G(t).
This script computes c_k with mpmath at 40 digits by interpolation at N Chebyshev points, keeps
the terms down to 1e-17, checks the series evaluated in double precision (Clenshaw, as the C++
does) against mpmath's Q at 4000 points of [0, 37] (phi(37) ~ 1e-298; past ~37.5 it is subnormal), and prints the C++ array.

  /usr/bin/python3 tools/make_normal_tail_coefficients.py   (Debian 12: python3-mpmath)
"""

import mpmath as mp

K = 4
N = 60          # interpolation points (the coefficients past ~25 are below 1e-20)
CUTOFF = 1e-17  # drop trailing coefficients below this (G is ~0.25..1.25)


def mills_ratio(x):
    return mp.sqrt(mp.pi / 2) * mp.exp(x * x / 2) * mp.erfc(x / mp.sqrt(2))


def g(t):
    if t == 0:
        return 1 / mp.mpf(K)
    x = K * (1 - t) / t
    return mills_ratio(x) / t


def chebyshev_coefficients():
    nodes = [mp.cos(mp.pi * (j + mp.mpf(1) / 2) / N) for j in range(N)]
    values = [g((u + 1) / 2) for u in nodes]
    c = []
    for k in range(N):
        c.append(2 * mp.fsum(values[j] * mp.cos(mp.pi * k * (j + mp.mpf(1) / 2) / N)
                             for j in range(N)) / N)
    c[0] /= 2
    last = max(i for i in range(N) if abs(c[i]) > CUTOFF)
    return [float(v) for v in c[:last + 1]]


def tail_in_double(x, c):
    """Q(x) as the C++ computes it, in double precision (phi from mpmath, rounded)."""
    t = K / (K + x)
    u = 2.0 * t - 1.0
    b1 = b2 = 0.0
    for ck in reversed(c[1:]):
        b1, b2 = 2.0 * u * b1 - b2 + ck, b1
    series = u * b1 - b2 + c[0]
    phi = float(mp.exp(-mp.mpf(x) ** 2 / 2) / mp.sqrt(2 * mp.pi))
    return phi * (t * series)


def main():
    mp.mp.dps = 40
    c = chebyshev_coefficients()
    worst = 0.0
    for i in range(4001):
        x = 37.0 * i / 4000
        exact = mp.erfc(mp.mpf(x) / mp.sqrt(2)) / 2
        worst = max(worst, float(abs(tail_in_double(x, c) - exact) / exact))
    print('// %d coefficients; largest relative error of Q on [0, 37] in double: %.2g'
          % (len(c), worst))
    print('constexpr double kMillsChebyshev[%d] = {' % len(c))
    for i in range(0, len(c), 3):
        print('    ' + ' '.join('%s,' % repr(v) for v in c[i:i + 3]))
    print('};')


if __name__ == '__main__':
    main()
