// The disc-averaged Airy pattern by the circle integral (src/internal/airy_disc_average.cc)
// against the definition: a direct quadrature over the disc of the Airy intensity computed
// with std::cyl_bessel_j (no table, no divergence theorem), and derivatives by finite
// differences of that quadrature.
#include "internal/airy_disc_average.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "ccdpsf/model/airy.h"
#include "ccdpsf/model/spot_model.h"
#include "gtest/gtest.h"
#include "internal/airy_table_simd.h"
#include "internal/gauss_legendre.h"
#include "support/slow_test.h"

namespace ccdpsf::internal {
namespace {

double AiryIntensityDirect(double rho, double k) {
  const double v = k * rho;
  const double a = v < 1e-8 ? 1.0 : 2.0 * std::cyl_bessel_j(1.0, v) / v;
  return k * k / (4.0 * M_PI) * a * a;
}

// (1 / (pi R^2)) integral over the disc, Gauss-Legendre in radius and midpoints in angle,
// both with far more nodes than the integrands' frequencies need (the angular integrand at
// radius rho has frequencies up to ~2 k rho; the radial one is entire).
double DiscAverageDirect(double d, double k, double radius) {
  const int n_rho = static_cast<int>(k * radius) + 40;
  const int n_theta = static_cast<int>(2.0 * k * radius) + 80;  // full circle
  const GaussLegendreRule& gl = GaussLegendre(n_rho);
  double sum = 0.0;
  for (int m = 0; m < n_rho; ++m) {
    const double rho = 0.5 * radius * (gl.nodes[m] + 1.0);
    double ring = 0.0;
    for (int l = 0; l < n_theta; ++l) {
      const double theta = 2.0 * M_PI * (l + 0.5) / n_theta;
      ring += AiryIntensityDirect(std::hypot(d + rho * std::cos(theta), rho * std::sin(theta)), k);
    }
    sum += 0.5 * radius * gl.weights[m] * rho * 2.0 * M_PI * ring / n_theta;
  }
  return sum / (M_PI * radius * radius);
}

// Fourth-order central difference of f at x with step h: error ~h^4 f^(5) / 30.
template <typename F>
double Derivative(F f, double x, double h) {
  return (8.0 * (f(x + h) - f(x - h)) - (f(x + 2 * h) - f(x - 2 * h))) / (12.0 * h);
}

struct Case {
  double airy_radius, disc_radius, d;
};

// Airy radii and disc radii over the range the fits use (and past it), and distances at the
// centre, inside the disc, on its edge (the circle passes through the Airy centre, where the
// integrand is sharpest), just outside it and far out in the Airy tail.
std::vector<Case> Cases() {
  std::vector<Case> cases;
  for (const double r : {0.3, 0.47, 0.9}) {
    for (const double radius : {0.05, 0.2, 0.6, 1.5, 3.0}) {
      for (const double d : {0.0, 0.3 * radius, radius, radius + 0.01, 2.5, 9.7}) {
        cases.push_back({r, radius, d});
      }
    }
  }
  return cases;
}

// The encircled-energy ratio e(v) = E(v) / v^2 of model/airy.h, from its table and without
// it, against the definition: E(v) = integral_0^v (t a(t)^2 / 2) dt, the flux of the unit
// Airy pattern within v, by Gauss-Legendre on unit intervals (20 nodes for an entire
// integrand of frequency 2: converged to rounding, ~1e-16 of E) with a from
// std::cyl_bessel_j. At series-to-Bessel switch (v = 2), inside pieces and on nodes.
// Tolerance: 1e-13 absolute (e(0) = 1/4); the quintic pieces measured 2.3e-14 when this was
// written.
TEST(EncircledRatio, TableAndDirectMatchTheIntegralOfTheIntensity) {
  const GaussLegendreRule& gl = GaussLegendre(20);
  const auto integrand = [](double t) {
    const double a = t < 1e-8 ? 1.0 : 2.0 * std::cyl_bessel_j(1.0, t) / t;
    return 0.5 * t * a * a;
  };
  const auto encircled = [&](double v) {
    double sum = 0.0;
    for (double lo = 0.0; lo < v; lo += 1.0) {
      const double hi = std::min(v, lo + 1.0), half = 0.5 * (hi - lo);
      for (size_t m = 0; m < gl.nodes.size(); ++m)
        sum += half * gl.weights[m] * integrand(lo + half * (gl.nodes[m] + 1.0));
    }
    return sum;
  };
  model::EnsureEncircledRatioTable(200.0);
  const double* table = model::EncircledRatioTableCoefficients();
  for (const double v :
       {1e-3, 0.3, 1.0, 1.99, 2.0, 2.0137, 3.7, 10.3, 47.9, 100.0, 150.21, 199.6}) {
    const double expected = encircled(v) / (v * v);
    double from_table, direct;
    TablePolynomial(table, v, &from_table, nullptr);
    model::EncircledRatioDirect(v, &direct);
    EXPECT_NEAR(from_table, expected, 1e-13) << "v " << v;
    EXPECT_NEAR(direct, expected, 1e-13) << "v " << v;
  }
  double at_zero;
  TablePolynomial(table, 0.0, &at_zero, nullptr);
  EXPECT_EQ(at_zero, 0.25);
}

// Values. Tolerance: 1e-11 of the Airy peak k^2 / (4 pi), an upper bound of S. The table
// behind a(v) is good to ~1e-12 (airy.h), and J0 = a + v a' / 2 inherits a' 's error times
// v / 2; the direct quadrature is converged to ~1e-15. In a render, an error of 1e-11 of the
// peak per node is at most ~5e-11 of the flux in any pixel, inside the renderer's 1e-10.
TEST(AiryDiscAverage, MatchesDirectQuadratureOverTheDisc) {
  double worst = 0.0;
  for (const Case& c : Cases()) {
    const double k = M_PI * model::kAiryRz / c.airy_radius;
    EnsureDiscAverageTables(k * (c.d + c.disc_radius) + 1.0);
    const AiryDiscAverage average(k, c.disc_radius);
    double s;
    average.Evaluate(c.d, &s, nullptr, nullptr);
    const double peak = k * k / (4.0 * M_PI);
    const double expected = DiscAverageDirect(c.d, k, c.disc_radius);
    const double error = std::fabs(s - expected) / peak;
    worst = std::max(worst, error);
    EXPECT_LT(error, 1e-11) << "r " << c.airy_radius << " R " << c.disc_radius << " d " << c.d
                            << ": " << s << " vs " << expected;
  }
  RecordProperty("max_error_of_peak", std::to_string(worst));
}

// Derivatives by the disc radius and by k. Tolerance: 1e-8 of the scale of each derivative
// (peak / R and peak / k): the fourth-order differences at steps 1e-3 R and 1e-3 k have
// truncation errors ~(2 k h)^4 / 30 < 1e-9 relative for these k R, and rounding ~1e-15 / 1e-3.
TEST(AiryDiscAverage, DerivativesMatchFiniteDifferencesOfTheDirectQuadrature) {
  CCDPSF_RELEASE_ONLY();  // many quadratures; the same code runs sanitized in
  // AiryDiscAverage.MatchesDirectQuadratureOverTheDisc
  for (const Case& c : Cases()) {
    if (c.disc_radius < 0.2 || c.d > 5.0) continue;  // keeps the test's run time short
    const double k = M_PI * model::kAiryRz / c.airy_radius;
    EnsureDiscAverageTables((k * 1.01) * (c.d + c.disc_radius * 1.01) + 1.0);
    const AiryDiscAverage average(k, c.disc_radius);
    double s, ds_dk, ds_dR;
    average.Evaluate(c.d, &s, &ds_dk, &ds_dR);
    const double peak = k * k / (4.0 * M_PI);
    const double by_R = Derivative([&](double radius) { return DiscAverageDirect(c.d, k, radius); },
                                   c.disc_radius, 1e-3 * c.disc_radius);
    const double by_k = Derivative(
        [&](double kk) { return DiscAverageDirect(c.d, kk, c.disc_radius); }, k, 1e-3 * k);
    const std::string where = "r " + std::to_string(c.airy_radius) + " R " +
                              std::to_string(c.disc_radius) + " d " + std::to_string(c.d);
    EXPECT_NEAR(ds_dR, by_R, 1e-8 * peak / c.disc_radius) << where;
    EXPECT_NEAR(ds_dk, by_k, 1e-8 * peak / k) << where;
  }
}

// Shrinking the disc gives back the Airy intensity: S = I + O(R^2).
TEST(AiryDiscAverage, SmallDiscIsTheAiryIntensity) {
  const double k = M_PI * model::kAiryRz / 0.47;
  EnsureDiscAverageTables(k * 5.0);
  const double radius = 1e-4;
  const AiryDiscAverage average(k, radius);
  for (const double d : {0.0, 0.2, 0.5, 1.3, 4.0}) {
    double s;
    average.Evaluate(d, &s, nullptr, nullptr);
    // The O(R^2) term is (R^2 / 8) Laplacian(I), at most (R^2 / 8) (2 k)^2 peak (I is
    // band-limited to 2 k): 3.3e-7 of the peak here (at d = 0 it is (R k)^2 / 8 of it).
    const double peak = k * k / (4.0 * M_PI);
    EXPECT_NEAR(s, AiryIntensityDirect(d, k), 0.5 * radius * radius * k * k * peak) << "d " << d;
  }
}

// The piecewise profile against the circle integral it tabulates, at 1004 distances that are
// not its sample points (every sub-piece holds several), all at once and one by one (a
// point's lanes must round alike however the points are grouped), and at every 25th distance
// against the direct quadrature over the disc, the independent truth. Tolerances: the
// truncated series are below 1e-12 of the peak (J_40(16) ~ 3e-13 per piece, J_20(4) ~ 4e-13
// per sub-piece) and the conversion to power series rounds at ~1e-14 of it, but the circle
// integral's samples carry the Airy table's wiggles, which the series smooths. Measured over
// these distances: up to 2.4e-12 of the peak between the profile and the circle integral
// (2.7e-12 with 44 and 24 terms; 7e-12 for the earlier profile of 48-term Chebyshev series
// summed by Clenshaw's rule: the circle integral's own error, cf. the 1e-11 of
// MatchesDirectQuadratureOverTheDisc), and up to 9.5e-13 from the direct quadrature (44 and
// 24 terms: 6.9e-13; the Clenshaw profile: 1.5e-12). dS/dR = (2 / R) (<I> - S) carries the wiggles
// of both terms times 2 / R (measured up to 4.7e-12 of peak / R, at R = 0.05 px; 5.4e-12 with 44
// and 24). So, against the circle integral, 1.5e-11 of the peak for S and 2e-11 of peak / k and
// peak / R for the derivatives; against the direct quadrature, 5e-12 of the peak.
TEST(AiryDiscProfile, MatchesTheCircleIntegralBetweenItsPoints) {
  CCDPSF_RELEASE_ONLY();  // a dense scan; the profile runs sanitized in
  // AiryDiscAverage.MatchesDirectQuadratureOverTheDisc
  for (const double r : {0.3, 0.47, 0.9}) {
    for (const double radius : {0.05, 0.6, 3.0}) {
      const double k = M_PI * model::kAiryRz / r;
      const double d_max = 21.3;
      EnsureDiscAverageTables(k * (AiryDiscProfile::Reach(k, d_max) + radius) + 1.0);
      const AiryDiscAverage average(k, radius);
      AiryDiscProfile profile;
      profile.Build(k, radius, d_max, true);
      std::vector<double> d;
      for (int i = 0; i < 1003; ++i) d.push_back(d_max * (i + 0.37) / 1003.0);
      d.push_back(d_max);
      const int n = static_cast<int>(d.size());
      std::vector<double> s(n), s_dk(n), s_dR(n), values_only(n);
      profile.Evaluate(d.data(), n, s.data(), s_dk.data(), s_dR.data());
      AiryDiscProfile values;
      values.Build(k, radius, d_max, false);
      values.Evaluate(d.data(), n, values_only.data(), nullptr, nullptr);
      const double peak = k * k / (4.0 * M_PI);
      for (int i = 0; i < n; ++i) {
        double e, e_dk, e_dR, one;
        average.Evaluate(d[i], &e, &e_dk, &e_dR);
        profile.Evaluate(&d[i], 1, &one, nullptr, nullptr);
        const std::string where = "r " + std::to_string(r) + " R " + std::to_string(radius) +
                                  " d " + std::to_string(d[i]);
        ASSERT_NEAR(s[i], e, 1.5e-11 * peak) << where;
        ASSERT_NEAR(s_dk[i], e_dk, 2e-11 * peak / k) << where;
        ASSERT_NEAR(s_dR[i], e_dR, 2e-11 * peak / radius) << where;
        if (i % 25 == 7) {
          ASSERT_NEAR(s[i], DiscAverageDirect(d[i], k, radius), 5e-12 * peak) << where;
        }
        ASSERT_EQ(values_only[i], s[i]) << where;
        ASSERT_EQ(one, s[i]) << where;  // the remainder rounds as the vector lanes do
      }
    }
  }
}

}  // namespace
}  // namespace ccdpsf::internal
