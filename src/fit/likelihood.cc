#include "ccdpsf/fit/likelihood.h"

#include <algorithm>
#include <cmath>

namespace ccdpsf::fit {

bool ParseLikelihoodKind(const std::string& text, LikelihoodKind* kind) {
  if (text == "gaussian") {
    *kind = LikelihoodKind::kGaussian;
  } else if (text == "poisson_normal") {
    *kind = LikelihoodKind::kPoissonNormal;
  } else {
    return false;
  }
  return true;
}

std::string ToString(LikelihoodKind kind) {
  return kind == LikelihoodKind::kGaussian ? "gaussian" : "poisson_normal";
}

double GaussianLogLikelihood(double data_e, double expected_e, const CcdNoise& noise) {
  const double var = noise.VarianceE2(expected_e);
  const double r = data_e - expected_e;
  return -0.5 * (r * r / var + std::log(2.0 * M_PI * var));
}

double PoissonNormalLogLikelihood(double data_e, double expected_e, const CcdNoise& noise) {
  const double m = std::max(expected_e, 0.0);
  if (m > kPoissonNormalGaussianAbove) return GaussianLogLikelihood(data_e, m, noise);
  const double s2 = noise.VarianceE2(0.0);  // read noise and rounding only
  // Terms beyond 12 standard deviations of either factor are below exp(-72) of the peak.
  const double spread = 12.0 * std::sqrt(m + s2) + 12.0;
  const long k_lo = std::max(0L, static_cast<long>(std::floor(std::min(data_e, m) - spread)));
  const long k_hi = static_cast<long>(std::ceil(std::max(data_e, m) + spread));
  const double log_m = m > 0 ? std::log(m) : 0.0;
  const double norm = -0.5 * std::log(2.0 * M_PI * s2);
  // log-sum-exp in two passes.
  double best = -INFINITY;
  for (int pass = 0; pass < 2; ++pass) {
    double sum = 0.0;
    for (long k = k_lo; k <= k_hi; ++k) {
      if (m == 0.0 && k > 0) break;
      const double log_poisson = (m == 0.0) ? 0.0 : -m + k * log_m - std::lgamma(k + 1.0);
      const double r = data_e - static_cast<double>(k);
      const double term = log_poisson + norm - 0.5 * r * r / s2;
      if (pass == 0) {
        best = std::max(best, term);
      } else {
        sum += std::exp(term - best);
      }
    }
    if (pass == 1) return best + std::log(sum);
  }
  return best;
}

void GaussianLogLikelihoodSum::Renormalise() {
  int e = 0;
  product_ = std::frexp(product_, &e);
  exponent_ += e;
  since_renormalised_ = 0;
}

double GaussianLogLikelihoodSum::Total() {
  Renormalise();
  const double log_var_sum = std::log(product_) + static_cast<double>(exponent_) * M_LN2;
  return -0.5 * (chi2_ + log_var_sum + static_cast<double>(count_) * std::log(2.0 * M_PI));
}

}  // namespace ccdpsf::fit
