#include "ccdpsf/fit/data_alone_estimate.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "ccdpsf/fit/laplace.h"

namespace ccdpsf::fit {
namespace {

// Eigenvalues of F_bb below this fraction of F's largest are rounding (as laplace.cc's floor).
constexpr double kNullEigenvalueFraction = 1e-12;

}  // namespace

DataAloneEstimate EstimateFromDataAlone(const FitModel& model,
                                        const std::vector<double>& theta_map,
                                        const std::vector<double>& fisher) {
  DataAloneEstimate out;
  const GaussianPriorTerm& term = model.gaussian_prior();
  if (!term.active()) {
    out.why_not = "the model has no Gaussian prior";
    return out;
  }
  const int n = model.dim(), m = term.size();
  out.indices = term.indices();
  std::vector<int> others;
  for (int i = 0; i < n; ++i) {
    if (std::find(out.indices.begin(), out.indices.end(), i) == out.indices.end()) {
      others.push_back(i);
    }
  }
  const int nb = static_cast<int>(others.size());
  // Prior-scaled coordinates: u_i = theta_i / w_i, F_u = W F W.
  auto width = [&](int i) { return model.upper()[i] - model.lower()[i]; };
  auto f_scaled = [&](int i, int j) { return width(i) * fisher[static_cast<size_t>(i) * n + j] * width(j); };
  Eigen::MatrixXd faa(m, m), fab(m, nb), fbb(nb, nb);
  for (int a = 0; a < m; ++a) {
    for (int c = 0; c < m; ++c) faa(a, c) = f_scaled(out.indices[a], out.indices[c]);
    for (int b = 0; b < nb; ++b) fab(a, b) = f_scaled(out.indices[a], others[b]);
  }
  for (int b = 0; b < nb; ++b) {
    for (int c = 0; c < nb; ++c) fbb(b, c) = f_scaled(others[b], others[c]);
  }
  if (!faa.allFinite() || !fab.allFinite() || !fbb.allFinite()) {
    out.why_not = "the likelihood's Fisher information is not finite at the MAP";
    return out;
  }
  double largest = faa.cwiseAbs().maxCoeff();
  Eigen::MatrixXd fbb_pinv = Eigen::MatrixXd::Zero(nb, nb);
  if (nb > 0) {
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (fbb + fbb.transpose()));
    largest = std::max(largest, eig.eigenvalues().maxCoeff());
    const double floor = kNullEigenvalueFraction * largest;
    for (int j = 0; j < nb; ++j) {
      const double lambda = eig.eigenvalues()[j];
      if (lambda > floor) {
        fbb_pinv += eig.eigenvectors().col(j) * eig.eigenvectors().col(j).transpose() / lambda;
      }
    }
  }
  Eigen::MatrixXd s = faa - fab * fbb_pinv * fab.transpose();
  s = 0.5 * (s + s.transpose());
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> seig(s);
  const Eigen::VectorXd lambda = seig.eigenvalues();
  for (int j = 0; j < m; ++j) {
    const double sd = lambda[j] > 0.0 ? 1.0 / std::sqrt(lambda[j]) : INFINITY;
    if (sd <= kUnconstrainedSdFraction) continue;
    // Name the parameters along the direction the data leave open.
    std::string names;
    for (int a = 0; a < m; ++a) {
      if (std::fabs(seig.eigenvectors()(a, j)) > kLoadingThreshold) {
        names += (names.empty() ? "" : ", ") + model.names()[out.indices[a]];
      }
    }
    out.why_not = "the data alone do not constrain " + names +
                  (std::isinf(sd) ? " at all"
                                  : " (their likelihood is wider than the flat prior range)");
    return out;
  }
  // Back to the parameters' units: S^-1 = W_a S_u^-1 W_a.
  const Eigen::MatrixXd s_inverse_scaled =
      seig.eigenvectors() * lambda.cwiseInverse().asDiagonal() * seig.eigenvectors().transpose();
  Eigen::MatrixXd covariance(m, m), precision(m, m);
  Eigen::VectorXd offset(m);  // a_post - mean
  for (int a = 0; a < m; ++a) {
    offset[a] = theta_map[out.indices[a]] - term.prior().mean[a];
    for (int c = 0; c < m; ++c) {
      covariance(a, c) = width(out.indices[a]) * s_inverse_scaled(a, c) * width(out.indices[c]);
      precision(a, c) = term.precision()[static_cast<size_t>(a) * m + c];
    }
  }
  const Eigen::VectorXd shift = covariance * (precision * offset);
  out.mean.resize(m);
  out.sd.resize(m);
  out.covariance.resize(static_cast<size_t>(m) * m);
  for (int a = 0; a < m; ++a) {
    out.mean[a] = theta_map[out.indices[a]] + shift[a];
    out.sd[a] = std::sqrt(covariance(a, a));
    for (int c = 0; c < m; ++c) out.covariance[static_cast<size_t>(a) * m + c] = covariance(a, c);
  }
  out.available = true;
  return out;
}

}  // namespace ccdpsf::fit
