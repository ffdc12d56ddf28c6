// The vectorised normal tail and density (src/internal/normal_tail.cc) against glibc's erfc and
// exp, an independent implementation.
#include "internal/normal_tail.h"

#include <cmath>
#include <limits>
#include <vector>

#include "gtest/gtest.h"

namespace ccdpsf::internal {
namespace {

// Tolerance: both sides round z^2 / 2 (or |z| / sqrt 2) before their exponential, which alone
// moves either by up to ~1.1e-16 x z^2 relative; the rest (the series, exp's polynomial, glibc's
// own error) is a few units of 1.1e-16. So 2e-15 + 2.5e-16 z^2.
double Tolerance(double z) { return 2e-15 + 2.5e-16 * z * z; }

TEST(NormalTail, MatchesGlibcErfcAndExpFromMinus37To37) {
  std::vector<double> z;
  for (int i = -37000; i <= 37000; ++i) z.push_back(i * 1e-3 + 1.234567e-5 * (i % 7));
  const int n = static_cast<int>(z.size());
  std::vector<double> tail(n), density(n);
  NormalTailsAndDensities(z.data(), n, tail.data(), density.data());
  for (int e = 0; e < n; ++e) {
    const double expected_tail = 0.5 * std::erfc(std::fabs(z[e]) / std::sqrt(2.0));
    const double expected_density = std::exp(-0.5 * z[e] * z[e]) / std::sqrt(2.0 * M_PI);
    ASSERT_NEAR(tail[e], expected_tail, Tolerance(z[e]) * expected_tail) << "z = " << z[e];
    ASSERT_NEAR(density[e], expected_density, Tolerance(z[e]) * expected_density) << "z = " << z[e];
  }
}

// A value depends only on its z: the same z at every place of arrays of every length (the
// vector groups of four and the padded last group), with or without densities.
TEST(NormalTail, ValueDoesNotDependOnPlaceOrLength) {
  const double probe = 1.7320508075688772;
  double reference_tail = 0.0, reference_density = 0.0;
  NormalTailsAndDensities(&probe, 1, &reference_tail, &reference_density);
  for (int n = 1; n <= 9; ++n) {
    for (int at = 0; at < n; ++at) {
      std::vector<double> z(n, 0.5), tail(n), density(n);
      z[at] = probe;
      NormalTailsAndDensities(z.data(), n, tail.data(), at % 2 == 0 ? density.data() : nullptr);
      EXPECT_EQ(tail[at], reference_tail) << "n " << n << " at " << at;
      if (at % 2 == 0) {
        EXPECT_EQ(density[at], reference_density) << "n " << n << " at " << at;
      }
    }
  }
}

// NormalDensities alone gives NormalTailsAndDensities' densities bit for bit (the glibc check
// above then covers both), at every place of arrays of every length, NaN and far tails included.
TEST(NormalTail, DensitiesAloneAreTheSameBits) {
  for (int n = 1; n <= 11; ++n) {
    std::vector<double> z(n);
    for (int e = 0; e < n; ++e) z[e] = -5.3 + 1.37 * e + 1e-3 * n;
    if (n > 8) z[n - 1] = std::numeric_limits<double>::quiet_NaN();
    if (n > 9) z[n - 2] = 60.0;
    std::vector<double> tail(n), both(n), alone(n);
    NormalTailsAndDensities(z.data(), n, tail.data(), both.data());
    NormalDensities(z.data(), n, alone.data());
    for (int e = 0; e < n; ++e) {
      if (std::isnan(z[e])) {
        EXPECT_TRUE(std::isnan(alone[e]));
      } else {
        EXPECT_EQ(alone[e], both[e]) << "n " << n << " at " << e;
      }
    }
  }
}

TEST(NormalTail, FarTailsAndNaN) {
  const double z[4] = {-60.0, 60.0, std::numeric_limits<double>::infinity(),
                       std::numeric_limits<double>::quiet_NaN()};
  double tail[4], density[4];
  NormalTailsAndDensities(z, 4, tail, density);
  for (int e = 0; e < 3; ++e) {
    // The true values are below the smallest double; anything at or below 1e-307 is as good.
    EXPECT_GE(tail[e], 0.0);
    EXPECT_LE(tail[e], 1e-307);
    EXPECT_GE(density[e], 0.0);
    EXPECT_LE(density[e], 1e-307);
  }
  EXPECT_TRUE(std::isnan(tail[3]));
  EXPECT_TRUE(std::isnan(density[3]));
}

}  // namespace
}  // namespace ccdpsf::internal
