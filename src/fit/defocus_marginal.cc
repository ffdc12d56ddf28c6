#include "ccdpsf/fit/defocus_marginal.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "internal/gauss_legendre.h"

namespace ccdpsf::fit {
namespace {

// The integrand in w (see the header): J(d) dd / dw at d = t_m tanh(w),
//   f(w) = t_M t_m sech(w) / sqrt(t_M^2 - t_m^2 tanh^2(w)).
// With e = exp(2 w) - 1 (expm1: exact near w = 0), tanh = e / (e + 2) and
// sech = 2 sqrt(e + 1) / (e + 2), so
//   f = 2 t_M t_m sqrt((e + 1) / (4 t_M^2 (e + 1) + (t_M^2 - t_m^2) e^2)),
// a sum of two positive terms under the root (no cancellation when t_M ~ t_m), and one
// exponential instead of tanh and cosh: the weight is computed at every MCMC evaluation and
// the quantile for every state of the chain.
struct Integrand {
  Integrand(double t_big, double t_small)
      : scale(2.0 * t_big * t_small),
        four_big2(4.0 * t_big * t_big),
        diff2((t_big - t_small) * (t_big + t_small)) {}
  double operator()(double w) const {
    const double e = std::expm1(2.0 * w);
    return scale * std::sqrt((e + 1.0) / (four_big2 * (e + 1.0) + diff2 * e * e));
  }
  double scale, four_big2, diff2;
};

// The two rules used, looked up once: GaussLegendre() takes a lock, and the weight is
// computed at every MCMC evaluation on every thread.
const internal::GaussLegendreRule& Rule(int n) {
  static const internal::GaussLegendreRule& rule3 = internal::GaussLegendre(3);
  static const internal::GaussLegendreRule& rule64 = internal::GaussLegendre(64);
  return n == 3 ? rule3 : n == 64 ? rule64 : internal::GaussLegendre(n);
}

double IntegrateGL(const Integrand& f, double a, double b, int n) {
  const internal::GaussLegendreRule& rule = Rule(n);
  const double half = 0.5 * (b - a), mid = 0.5 * (a + b);
  double sum = 0.0;
  for (size_t i = 0; i < rule.nodes.size(); ++i)
    sum += rule.weights[i] * f(mid + half * rule.nodes[i]);
  return sum * half;
}

}  // namespace

bool AllowedDefocus(double t_x, double t_y, const WidthBounds& b, double* lower, double* upper) {
  if (!(t_x > b.sigma_x_lower && t_y > b.sigma_y_lower)) return false;
  // sigma = sqrt(t^2 - d^2) <= sigma_upper  <=>  d >= sqrt(t^2 - sigma_upper^2).
  const double lo = std::max(
      {b.defocus_lower, std::sqrt(std::max(0.0, t_x * t_x - b.sigma_x_upper * b.sigma_x_upper)),
       std::sqrt(std::max(0.0, t_y * t_y - b.sigma_y_upper * b.sigma_y_upper))});
  // sigma >= sigma_lower  <=>  d <= sqrt(t^2 - sigma_lower^2).
  const double hi =
      std::min({b.defocus_upper, std::sqrt(t_x * t_x - b.sigma_x_lower * b.sigma_x_lower),
                std::sqrt(t_y * t_y - b.sigma_y_lower * b.sigma_y_lower)});
  if (!(lo <= hi)) return false;
  *lower = lo;
  *upper = hi;
  return true;
}

double DefocusMarginalWeight(double t_x, double t_y, double lower, double upper) {
  const double t_small = std::min(t_x, t_y);
  const Integrand f(std::max(t_x, t_y), t_small);
  return IntegrateGL(f, std::atanh(lower / t_small), std::atanh(upper / t_small), 64);
}

double DefocusQuantile(double t_x, double t_y, double lower, double upper, double u) {
  constexpr int kPanels = 48;
  const double t_small = std::min(t_x, t_y);
  const Integrand f(std::max(t_x, t_y), t_small);
  const double w0 = std::atanh(lower / t_small), w1 = std::atanh(upper / t_small);
  const double h = (w1 - w0) / kPanels;
  if (!(h > 0)) return lower;
  std::array<double, kPanels + 1> cumulative{};
  for (int p = 0; p < kPanels; ++p) {
    cumulative[p + 1] = cumulative[p] + IntegrateGL(f, w0 + p * h, w0 + (p + 1) * h, 3);
  }
  const double target = std::clamp(u, 0.0, 1.0) * cumulative[kPanels];
  const int p =
      std::clamp(static_cast<int>(std::upper_bound(cumulative.begin(), cumulative.end(), target) -
                                  cumulative.begin()) -
                     1,
                 0, kPanels - 1);
  const double mass = cumulative[p + 1] - cumulative[p];
  const double r = mass > 0 ? std::clamp((target - cumulative[p]) / mass, 0.0, 1.0) : 0.0;
  // Within the panel take f linear from fa to fb: the mass fraction reached at x in [0, h] is
  // (fa x + (fb - fa) x^2 / (2 h)) / ((fa + fb) h / 2); solve that = r for x.
  const double a = w0 + p * h;
  const double fa = f(a), fb = f(a + h);
  const double m = r * 0.5 * (fa + fb) * h;
  const double c2 = (fb - fa) / (2 * h);
  double x;
  if (std::fabs(c2) * h < 1e-9 * fa) {
    x = m / fa;
  } else {
    x = (-fa + std::sqrt(std::max(0.0, fa * fa + 4 * c2 * m))) / (2 * c2);
  }
  const double d = t_small * std::tanh(a + std::clamp(x, 0.0, h));
  return std::clamp(d, lower, upper);
}

}  // namespace ccdpsf::fit
