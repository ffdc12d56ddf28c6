// The defocus integrated out of the Gaussian-defocus posterior: the weight W(t) against a
// closed form and a brute-force integral, the conditional quantiles against the brute-force
// CDF, and the allowed range against hand computation.
#include "ccdpsf/fit/defocus_marginal.h"

#include <cmath>

#include "gtest/gtest.h"

namespace ccdpsf::fit {
namespace {

double Jacobian(double tx, double ty, double d) {
  return tx * ty / std::sqrt((tx * tx - d * d) * (ty * ty - d * d));
}

// Composite Simpson's rule in d on n panels: J is smooth on [lo, hi] (bounded because
// sigma >= 0.05 px), and its steepest variation, near hi, has a scale ~sigma_min^2 / t ~ 5e-3
// px, which 2e6 panels over < 1.5 px resolve to far better than 1e-9.
double BruteForce(double tx, double ty, double lo, double hi, int n = 2000000) {
  const double h = (hi - lo) / n;
  double sum = Jacobian(tx, ty, lo) + Jacobian(tx, ty, hi);
  for (int i = 1; i < n; ++i) sum += (i % 2 ? 4.0 : 2.0) * Jacobian(tx, ty, lo + i * h);
  return sum * h / 3.0;
}

TEST(DefocusMarginal, AllowedRangeByHand) {
  const WidthBounds b;  // defocus [0, 1.5], widths [0.05, 1.5]
  double lo, hi;
  ASSERT_TRUE(AllowedDefocus(0.5, 0.6, b, &lo, &hi));
  EXPECT_EQ(lo, 0.0);
  EXPECT_NEAR(hi, std::sqrt(0.25 - 0.0025), 1e-15);  // sigma_x >= 0.05 binds first
  // A total width beyond the CCD width's upper bound needs some defocus.
  ASSERT_TRUE(AllowedDefocus(1.6, 0.6, b, &lo, &hi));
  EXPECT_NEAR(lo, std::sqrt(1.6 * 1.6 - 1.5 * 1.5), 1e-15);
  EXPECT_NEAR(hi, std::sqrt(0.36 - 0.0025), 1e-15);
  // ... and none is possible when the two axes' requirements cross.
  EXPECT_FALSE(AllowedDefocus(1.6, 0.3, b, &lo, &hi));
  EXPECT_FALSE(AllowedDefocus(0.04, 0.6, b, &lo, &hi));
}

TEST(DefocusMarginal, WeightMatchesClosedFormForEqualWidths) {
  // t_x = t_y = t: J = t^2 / (t^2 - d^2), whose integral is t atanh(d / t).
  const double t = 0.45, lo = 0.0, hi = std::sqrt(t * t - 0.0025);
  EXPECT_NEAR(DefocusMarginalWeight(t, t, lo, hi), t * (std::atanh(hi / t) - std::atanh(lo / t)),
              1e-12);
}

TEST(DefocusMarginal, WeightMatchesBruteForce) {
  // The paper's total widths and harder cases: very different axes, near-equal axes, a
  // lower limit set by the width bound. Relative tolerance 1e-9: both sides are converged
  // far beyond it (see BruteForce).
  const WidthBounds b;
  const double cases[][2] = {{0.51, 0.53}, {0.3, 0.9}, {0.45, 0.4500001}, {1.6, 0.9}, {0.06, 0.2}};
  for (const auto& c : cases) {
    double lo, hi;
    ASSERT_TRUE(AllowedDefocus(c[0], c[1], b, &lo, &hi)) << c[0] << " " << c[1];
    const double w = DefocusMarginalWeight(c[0], c[1], lo, hi);
    EXPECT_NEAR(w, BruteForce(c[0], c[1], lo, hi), 1e-9 * w) << c[0] << " " << c[1];
  }
}

TEST(DefocusMarginal, QuantilesInvertTheBruteForceCdf) {
  // The quantile function is tabulated with f linear inside 48 panels: its CDF error is
  // ~1e-5 (see the header); we allow 5e-5.
  const WidthBounds b;
  const double cases[][2] = {{0.51, 0.53}, {0.3, 0.9}, {1.6, 0.9}};
  for (const auto& c : cases) {
    double lo, hi;
    ASSERT_TRUE(AllowedDefocus(c[0], c[1], b, &lo, &hi));
    const double w = BruteForce(c[0], c[1], lo, hi);
    for (double u : {0.0, 0.01, 0.1, 0.5, 0.9, 0.99, 1.0}) {
      const double d = DefocusQuantile(c[0], c[1], lo, hi, u);
      ASSERT_GE(d, lo);
      ASSERT_LE(d, hi);
      const double cdf = d > lo ? BruteForce(c[0], c[1], lo, d, 200000) / w : 0.0;
      EXPECT_NEAR(cdf, u, 5e-5) << "t = (" << c[0] << ", " << c[1] << "), u = " << u;
    }
  }
}

}  // namespace
}  // namespace ccdpsf::fit
