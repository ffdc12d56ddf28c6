#include "ccdpsf/truncated_normal.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace ccdpsf {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// The truncated density's mass on [lower, x] as a share of its mass on [lower, upper], by
// composite Simpson on 20,000 panels (error ~1e-15 of the mass for these smooth integrands):
// independent of the bisection and of erfc.
double TruncatedCdfBySimpson(double mean, double sd, double lower, double upper, double x) {
  auto mass = [&](double a, double b) {
    const int n = 20000;
    const double h = (b - a) / n;
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
      const double z = (a + i * h - mean) / sd;
      const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
      sum += w * std::exp(-0.5 * z * z);
    }
    return sum * h / 3.0;
  };
  return mass(lower, x) / mass(lower, upper);
}

TEST(TruncatedNormal, CdfMatchesTabulatedValues) {
  // Phi(1), Phi(-3) and Phi(-8) from standard tables (Abramowitz & Stegun 26.2).
  EXPECT_NEAR(NormalCdf(1.0), 0.8413447460685429, 1e-15);
  EXPECT_NEAR(NormalCdf(-3.0), 1.349898031630095e-3, 1e-17);
  EXPECT_NEAR(NormalCdf(-8.0) / 6.220960574271785e-16, 1.0, 1e-12);  // tail kept to full precision
}

TEST(TruncatedNormal, WithoutBoundsTheQuantilesAreMeanPlusKSd) {
  for (double k : {-3.0, -1.0, 0.0, 1.0, 3.0}) {
    // Tolerance: the bisection stops at a few ulp of |z| ~ 40, i.e. ~1e-13 in sd units.
    EXPECT_NEAR(TruncatedNormalQuantile(2.5, 0.1, -kInf, kInf, NormalCdf(k)), 2.5 + 0.1 * k, 1e-12)
        << k;
  }
}

TEST(TruncatedNormal, HalfNormalOneSdQuantileIsClosedForm) {
  // N(m, s^2) cut at m keeps its upper half; P(m <= X <= m + s | X >= m) = erf(1 / sqrt 2).
  const double q = std::erf(1.0 / std::sqrt(2.0));
  EXPECT_NEAR(TruncatedNormalQuantile(0.01, 0.003, 0.01, kInf, q), 0.013, 1e-14);
  EXPECT_NEAR(TruncatedNormalQuantile(0.01, 0.003, -kInf, 0.01, 1.0 - q), 0.007, 1e-14);
}

TEST(TruncatedNormal, BoundedQuantilesInvertTheIntegratedDensity) {
  struct Case {
    double mean, sd, lower, upper;
  };
  // A MAP at a bound, near one, between two close bounds, and a bound 6 sd out.
  const Case cases[] = {
      {0.0, 1e-3, 0.0, 0.05}, {2e-4, 1e-3, 0.0, 0.05}, {0.3, 0.2, 0.1, 0.5}, {1.0, 0.1, 0.4, 2.0}};
  for (const Case& c : cases) {
    for (double q : {NormalCdf(-3.0), NormalCdf(-1.0), 0.5, NormalCdf(1.0), NormalCdf(3.0)}) {
      const double x = TruncatedNormalQuantile(c.mean, c.sd, c.lower, c.upper, q);
      EXPECT_GE(x, c.lower);
      EXPECT_LE(x, c.upper);
      // Tolerance 1e-9: Simpson's error is far below, and the density is at most ~2/sd, so a
      // quantile error of 1e-12 sd moves the share by < 1e-11.
      EXPECT_NEAR(TruncatedCdfBySimpson(c.mean, c.sd, c.lower, c.upper, x), q, 1e-9)
          << c.mean << " " << c.lower << " q " << q;
    }
  }
}

}  // namespace
}  // namespace ccdpsf
