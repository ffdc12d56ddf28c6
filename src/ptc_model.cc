// The flat-field covariance model of ptc_model.h: Astier et al. 2019's equation solved per
// spatial frequency (exact in a_ij, first order in b_ij) and transformed back to lags.
#include "ccdpsf/ptc_model.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace ccdpsf {
namespace {

// Below this |x| the functions are summed as series (terms to x^24: the first left out is
// < 1 / 25! ~ 6e-26 relative), above it taken in closed form, where the cancellation costs
// at most a factor ~3 of the double's precision.
constexpr double kSeriesBelow = 1.0;
constexpr int kSeriesTerms = 25;
using Coefficients = std::array<double, kSeriesTerms>;

// The series' coefficients: f0 = sum x^n / (n + 1)!; h = sum [1 / (n + 1)! - 2 / (n + 3)!] x^n.
const Coefficients& F0Coefficients() {
  static const Coefficients table = [] {
    Coefficients c;
    double factorial = 1.0;  // (n + 1)!
    for (int n = 0; n < kSeriesTerms; ++n) {
      factorial *= n + 1;
      c[n] = 1.0 / factorial;
    }
    return c;
  }();
  return table;
}

const Coefficients& HCoefficients() {
  static const Coefficients table = [] {
    Coefficients c;
    double factorial = 1.0;  // (n + 1)!
    for (int n = 0; n < kSeriesTerms; ++n) {
      factorial *= n + 1;
      c[n] = 1.0 / factorial - 2.0 / (factorial * (n + 2) * (n + 3));
    }
    return c;
  }();
  return table;
}

// sum_n c_n x^n and its derivative, by Horner's rule.
double Polynomial(const Coefficients& c, double x, double* derivative) {
  double value = 0.0, slope = 0.0;
  for (int n = kSeriesTerms - 1; n >= 0; --n) {
    slope = slope * x + value;
    value = value * x + c[n];
  }
  if (derivative != nullptr) *derivative = slope;
  return value;
}

}  // namespace

double PtcF0(double x, double* derivative) {
  if (std::fabs(x) < kSeriesBelow) return Polynomial(F0Coefficients(), x, derivative);
  const double em1 = std::expm1(x);
  if (derivative != nullptr) *derivative = (x * std::exp(x) - em1) / (x * x);
  return em1 / x;
}

double PtcH(double x, double* derivative) {
  if (std::fabs(x) < kSeriesBelow) return Polynomial(HCoefficients(), x, derivative);
  const double e = std::exp(x), x2 = x * x, x3 = x2 * x;
  const double tail = std::expm1(x) - x;  // e^x - 1 - x
  if (derivative != nullptr) {
    *derivative = e / x - e / x2 - 2.0 * (std::expm1(x) / x3 - 3.0 * tail / (x3 * x));
  }
  return e / x - 2.0 * tail / x3;
}

PtcCovarianceModel::PtcCovarianceModel(int max_lag) : max_lag_(std::max(0, max_lag)) {
  const int side = max_lag_ + 1;
  const int n = std::max(64, 16 * max_lag_ + (16 * max_lag_) % 2);
  const int half = n / 2;
  const int freqs = (half + 1) * (half + 1);
  const int lags = side * side;
  forward_.resize(freqs, lags);
  inverse_.resize(freqs, lags);
  const double two_pi = 2.0 * M_PI;
  for (int ky = 0; ky <= half; ++ky) {
    for (int kx = 0; kx <= half; ++kx) {
      const int row = ky * (half + 1) + kx;
      const double wx = (kx == 0 || kx == half) ? 1.0 : 2.0;
      const double wy = (ky == 0 || ky == half) ? 1.0 : 2.0;
      for (int j = 0; j <= max_lag_; ++j) {
        for (int i = 0; i <= max_lag_; ++i) {
          const double c = std::cos(two_pi * kx * i / n) * std::cos(two_pi * ky * j / n);
          const double m = (i == 0 ? 1.0 : 2.0) * (j == 0 ? 1.0 : 2.0);
          forward_(row, j * side + i) = m * c;
          inverse_(row, j * side + i) = wx * wy * c / (static_cast<double>(n) * n);
        }
      }
    }
  }
}

void PtcCovarianceModel::Evaluate(const Eigen::VectorXd& a, const Eigen::VectorXd& b, double mu_e,
                                  Eigen::VectorXd* k, Eigen::MatrixXd* dk_da,
                                  Eigen::MatrixXd* dk_db, Eigen::VectorXd* dk_dmu) const {
  const bool with_b = b.size() == a.size();
  const Eigen::VectorXd alpha = forward_ * a;
  const Eigen::VectorXd beta =
      with_b ? Eigen::VectorXd(forward_ * a.cwiseProduct(b)) : Eigen::VectorXd::Zero(alpha.size());
  const int freqs = static_cast<int>(alpha.size());
  Eigen::VectorXd khat(freqs), d_alpha(freqs), d_beta(freqs), d_mu(freqs);
  const double mu = mu_e, mu2 = mu * mu, mu3 = mu2 * mu;
  for (int f = 0; f < freqs; ++f) {
    const double x = 2.0 * alpha(f) * mu;
    double f0_slope = 0.0, h_slope = 0.0;
    const double f0 = PtcF0(x, &f0_slope);
    const double h = with_b ? PtcH(x, &h_slope) : 0.0;
    khat(f) = mu * f0 + beta(f) * mu3 * h;
    // d/d alpha through x = 2 alpha mu; d/d beta; d/d mu (x depends on mu too).
    d_alpha(f) = 2.0 * mu2 * f0_slope + 2.0 * beta(f) * mu3 * mu * h_slope;
    d_beta(f) = mu3 * h;
    d_mu(f) = f0 + 2.0 * alpha(f) * mu * f0_slope + 3.0 * beta(f) * mu2 * h +
              2.0 * alpha(f) * beta(f) * mu3 * h_slope;
  }
  *k = inverse_.transpose() * khat;
  if (dk_da != nullptr) {
    // dK_l / da_m = sum_k inverse(k, l) [dK^/dalpha forward(k, m) + dK^/dbeta b_m forward(k, m)].
    Eigen::VectorXd scale = d_alpha;
    *dk_da = inverse_.transpose() * scale.asDiagonal() * forward_;
    if (with_b) {
      *dk_da += (inverse_.transpose() * d_beta.asDiagonal() * forward_) * b.asDiagonal();
    }
  }
  if (dk_db != nullptr) {
    *dk_db = with_b ? Eigen::MatrixXd((inverse_.transpose() * d_beta.asDiagonal() * forward_) *
                                      a.asDiagonal())
                    : Eigen::MatrixXd::Zero(a.size(), a.size());
  }
  if (dk_dmu != nullptr) *dk_dmu = inverse_.transpose() * d_mu;
}

}  // namespace ccdpsf
