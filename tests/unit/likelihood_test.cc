#include "ccdpsf/fit/likelihood.h"

#include <cmath>

#include "gtest/gtest.h"

namespace ccdpsf::fit {
namespace {

// Direct evaluation of sum_k Poisson(k; m) Normal(d - k; 0, s^2) in long double over every k
// that matters (no log-sum-exp), as an independent check of the production code.
double DirectPoissonNormal(double d, double m, double s2) {
  long double sum = 0.0L;
  long double poisson = std::exp(static_cast<long double>(-m));  // k = 0
  for (int k = 0; k < 400; ++k) {
    if (k > 0) poisson *= static_cast<long double>(m) / k;
    const long double r = d - k;
    sum += poisson * std::exp(-0.5L * r * r / s2) / std::sqrt(2.0L * M_PIl * s2);
  }
  return static_cast<double>(std::log(sum));
}

TEST(Likelihood, PoissonNormalMatchesDirectSum) {
  CcdNoise noise{3.1, 4.5, true};
  const double s2 = noise.VarianceE2(0.0);
  for (double m : {0.0, 0.5, 3.0, 20.0, 100.0}) {
    for (double d : {-10.0, 0.0, 2.0, 15.0, 130.0}) {
      // Both are sums of the same positive terms; long double rounding ~1e-18 relative.
      EXPECT_NEAR(PoissonNormalLogLikelihood(d, m, noise), DirectPoissonNormal(d, m, s2), 1e-9)
          << "m " << m << " d " << d;
    }
  }
}

// At high counts Poisson -> Normal(m, m): the exact likelihood approaches the Gaussian with
// variance m + s^2. The difference is the Poisson's skewness term, O(1/sqrt(m)) times a
// Hermite polynomial of the standardised residual: below 0.05 at m = 900 within 1 sd.
TEST(Likelihood, PoissonNormalTendsToTheGaussianAtHighCounts) {
  CcdNoise noise{3.1, 4.5, true};
  const double m = 900.0;
  const double sd = std::sqrt(noise.VarianceE2(m));
  for (double z : {-1.0, 0.0, 1.0}) {
    const double d = m + z * sd;
    EXPECT_NEAR(PoissonNormalLogLikelihood(d, m, noise), GaussianLogLikelihood(d, m, noise), 0.05);
  }
  // Above the switch the Gaussian form is used exactly.
  EXPECT_EQ(PoissonNormalLogLikelihood(5000.0, 4900.0, noise),
            GaussianLogLikelihood(5000.0, 4900.0, noise));
}

TEST(Likelihood, GaussianIsTheNormalDensityWithModelVariance) {
  CcdNoise noise{2.0, 3.0, false};
  // var = 16 + 9 = 25: log N(24; 16, 25) = -0.5 (64 / 25 + log(2 pi 25)).
  EXPECT_NEAR(GaussianLogLikelihood(24.0, 16.0, noise), -0.5 * (64.0 / 25 + std::log(50 * M_PI)),
              1e-14);
}

// The stamp sum against the term-by-term sum in long double, over a bright spot's range of
// expectations (1e-3 to 1e6 e-: variances up to 2^20, so the mantissa product must be
// renormalised to stay finite) and a few thousand pixels. Tolerance: each of n factors
// rounds to 1.1e-16 relative, so the log of the product is off by <= n * 1.1e-16 absolute;
// the chi^2 and the total are summed in double, off by <= n * 1.1e-16 * sum |terms|.
TEST(Likelihood, StampSumMatchesTheSumOfPixelTerms) {
  const CcdNoise noise{1.7, 4.5, true};
  GaussianLogLikelihoodSum sum(noise);
  long double direct = 0.0L, magnitude = 0.0L;
  const int n = 4000;
  for (int q = 0; q < n; ++q) {
    const double expected = std::pow(10.0, -3.0 + 9.0 * ((q * 37) % n) / n);
    const double data = expected + std::sqrt(noise.VarianceE2(expected)) * std::sin(0.7 * q);
    sum.Add(data, expected);
    const long double var = noise.VarianceE2(expected);
    const long double r = data - expected;
    const long double term = -0.5L * (r * r / var + std::log(2.0L * M_PIl * var));
    direct += term;
    magnitude += std::fabs(term);
  }
  EXPECT_NEAR(sum.Total(), static_cast<double>(direct),
              n * 1.1e-16 * (1.0 + static_cast<double>(magnitude)));
}

}  // namespace
}  // namespace ccdpsf::fit
