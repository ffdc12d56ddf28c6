// chi^2 tail probabilities (chi_square.h).
#include "ccdpsf/chi_square.h"

#include <algorithm>
#include <cmath>

namespace ccdpsf {
namespace {

// Regularized incomplete gamma: P(a, x) by its series (x < a + 1) or Q(a, x) by the
// continued fraction (modified Lentz). Returns the one computed directly; *is_lower says
// which.
double IncompleteGamma(double a, double x, bool* is_lower) {
  const double log_prefactor = -x + a * std::log(x) - std::lgamma(a);
  if (x < a + 1.0) {
    *is_lower = true;
    double ap = a, term = 1.0 / a, sum = term;
    for (int n = 0; n < 100000; ++n) {
      ap += 1.0;
      term *= x / ap;
      sum += term;
      if (std::fabs(term) < std::fabs(sum) * 1e-16) break;
    }
    return sum * std::exp(log_prefactor);
  }
  *is_lower = false;
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 100000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::fabs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(log_prefactor) * h;
}

}  // namespace

double ChiSquareUpperTail(double chi2, double dof) {
  if (!(dof >= 1) || !std::isfinite(chi2) || chi2 < 0.0) return NAN;
  if (chi2 == 0.0) return 1.0;
  bool lower = false;
  const double v = IncompleteGamma(0.5 * dof, 0.5 * chi2, &lower);
  return std::clamp(lower ? 1.0 - v : v, 0.0, 1.0);
}

double ChiSquareLowerTail(double chi2, double dof) {
  if (!(dof >= 1) || !std::isfinite(chi2) || chi2 < 0.0) return NAN;
  if (chi2 == 0.0) return 0.0;
  bool lower = false;
  const double v = IncompleteGamma(0.5 * dof, 0.5 * chi2, &lower);
  return std::clamp(lower ? v : 1.0 - v, 0.0, 1.0);
}

}  // namespace ccdpsf
