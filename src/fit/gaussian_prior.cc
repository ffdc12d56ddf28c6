#include "ccdpsf/fit/gaussian_prior.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <set>

namespace ccdpsf::fit {
namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A correlation matrix's smallest eigenvalue must exceed this for the covariance to count as
// positive definite: below it the precision would be rounding (a correlation of 1 - 1e-12).
constexpr double kMinCorrelationEigenvalue = 1e-12;

}  // namespace

bool CheckGaussianPrior(const GaussianPrior& prior, std::string* error) {
  const size_t n = prior.names.size();
  if (n == 0) {
    *error = "the Gaussian prior names no parameters";
    return false;
  }
  const std::set<std::string> unique(prior.names.begin(), prior.names.end());
  if (unique.size() != n || unique.count("") > 0) {
    *error = "the Gaussian prior's parameter names must be distinct and non-empty";
    return false;
  }
  if (prior.mean.size() != n || prior.covariance.size() != n * n) {
    *error = "the Gaussian prior has " + std::to_string(n) + " parameters but " +
             std::to_string(prior.mean.size()) + " means and " +
             std::to_string(prior.covariance.size()) + " covariance entries";
    return false;
  }
  for (size_t i = 0; i < n; ++i) {
    if (!std::isfinite(prior.mean[i])) {
      *error = "the Gaussian prior's mean of " + prior.names[i] + " is not a finite number";
      return false;
    }
    const double var = prior.covariance[i * n + i];
    if (!(var > 0.0) || !std::isfinite(var)) {
      *error = "the Gaussian prior's variance of " + prior.names[i] +
               " is not a positive finite number";
      return false;
    }
  }
  RowMatrix correlation(n, n);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < n; ++j) {
      const double c = prior.covariance[i * n + j], t = prior.covariance[j * n + i];
      const double scale =
          std::sqrt(prior.covariance[i * n + i] * prior.covariance[j * n + j]);
      if (!std::isfinite(c) || std::fabs(c - t) > 1e-9 * scale) {
        *error = "the Gaussian prior's covariance is not a symmetric matrix of finite numbers";
        return false;
      }
      correlation(i, j) = 0.5 * (c + t) / scale;
    }
  }
  const Eigen::SelfAdjointEigenSolver<RowMatrix> eig(correlation, Eigen::EigenvaluesOnly);
  if (eig.info() != Eigen::Success || !(eig.eigenvalues().minCoeff() > kMinCorrelationEigenvalue)) {
    *error = "the Gaussian prior's covariance is not positive definite";
    return false;
  }
  return true;
}

bool GaussianPriorTerm::Bind(const GaussianPrior& prior,
                             const std::vector<std::string>& theta_names, std::string* error) {
  *this = GaussianPriorTerm();
  if (prior.empty()) return true;
  if (!CheckGaussianPrior(prior, error)) return false;
  const int n = static_cast<int>(prior.names.size());
  std::vector<int> indices;
  std::vector<std::string> missing;
  for (const std::string& name : prior.names) {
    const auto it = std::find(theta_names.begin(), theta_names.end(), name);
    if (it == theta_names.end()) {
      missing.push_back(name);
    } else {
      indices.push_back(static_cast<int>(it - theta_names.begin()));
    }
  }
  if (static_cast<int>(missing.size()) == n) return true;  // inactive: none of them is fitted
  if (!missing.empty()) {
    std::string list;
    for (const std::string& m : missing) list += (list.empty() ? "" : ", ") + m;
    *error = "the Gaussian prior names parameters the model does not fit (" + list +
             ") beside ones it does";
    return false;
  }
  prior_ = prior;
  indices_ = indices;
  const RowMatrix covariance = Eigen::Map<const RowMatrix>(prior.covariance.data(), n, n);
  const Eigen::LLT<RowMatrix> llt(0.5 * (covariance + covariance.transpose()));
  const RowMatrix l = llt.matrixL();
  const RowMatrix l_inverse = l.triangularView<Eigen::Lower>().solve(RowMatrix::Identity(n, n));
  const RowMatrix precision = l_inverse.transpose() * l_inverse;
  whitening_.assign(l_inverse.data(), l_inverse.data() + n * n);
  precision_.assign(precision.data(), precision.data() + n * n);
  // log det(2 pi C) = n log(2 pi) + 2 sum log L_ii.
  double log_det = n * std::log(2.0 * M_PI);
  for (int i = 0; i < n; ++i) log_det += 2.0 * std::log(l(i, i));
  log_normaliser_ = -0.5 * log_det;
  return true;
}

void GaussianPriorTerm::WhitenedResiduals(const double* theta, double* r) const {
  const int n = size();
  for (int i = 0; i < n; ++i) {
    double sum = 0.0;
    for (int j = 0; j <= i; ++j) {  // L^-1 is lower triangular
      sum += whitening_[i * n + j] * (theta[indices_[j]] - prior_.mean[j]);
    }
    r[i] = sum;
  }
}

double GaussianPriorTerm::LogDensity(const double* theta) const {
  if (!active()) return 0.0;
  std::vector<double> r(size());
  WhitenedResiduals(theta, r.data());
  double sum = 0.0;
  for (double v : r) sum += v * v;
  return log_normaliser_ - 0.5 * sum;
}

void GaussianPriorTerm::AddPrecision(std::vector<double>* information, int dim) const {
  const int n = size();
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) {
      (*information)[static_cast<size_t>(indices_[a]) * dim + indices_[b]] += precision_[a * n + b];
    }
  }
}

}  // namespace ccdpsf::fit
