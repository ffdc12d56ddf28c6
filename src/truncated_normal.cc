#include "ccdpsf/truncated_normal.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace ccdpsf {

double NormalCdf(double z) { return 0.5 * std::erfc(-z / M_SQRT2); }

double TruncatedNormalQuantile(double mean, double sd, double lower, double upper, double q) {
  // Standardised bounds, clipped where the normal's mass beyond is below double precision.
  constexpr double kFar = 40.0;
  const double a = std::max((lower - mean) / sd, -kFar);
  const double b = std::min((upper - mean) / sd, kFar);
  const double cdf_a = NormalCdf(a), cdf_b = NormalCdf(b);
  const double target = cdf_a + q * (cdf_b - cdf_a);
  // Work on the side where the distribution function has no cancellation: its upper tail
  // 1 - Phi(z) = Phi(-z) when the target is above one half.
  const bool upper_side = target > 0.5;
  const double tail = upper_side ? NormalCdf(-b) + (1.0 - q) * (cdf_b - cdf_a) : target;
  double lo = a, hi = b;
  for (int i = 0; i < 200 && hi - lo > 4 * std::numeric_limits<double>::epsilon() *
                                           std::max(1.0, std::fabs(lo) + std::fabs(hi));
       ++i) {
    const double mid = 0.5 * (lo + hi);
    const bool below = upper_side ? NormalCdf(-mid) > tail : NormalCdf(mid) < tail;
    (below ? lo : hi) = mid;
  }
  return mean + sd * 0.5 * (lo + hi);
}

}  // namespace ccdpsf
