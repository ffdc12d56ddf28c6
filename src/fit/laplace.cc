#include "ccdpsf/fit/laplace.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "ccdpsf/random.h"

namespace ccdpsf::fit {

LaplaceResult ComputeLaplace(const FitModel& model, const std::vector<double>& theta_map,
                             const std::vector<double>& fisher) {
  // A through-focus series has no such degeneracy (its defocus varies per exposure).
  const bool explain = model.options().model.sampling == model::Sampling::kIntegrated &&
                       model.options().model.defocus == model::DefocusKind::kGaussian &&
                       !model.through_focus();
  return ComputeLaplace(model.names(), model.lower(), model.upper(), theta_map, fisher, explain);
}

LaplaceResult ComputeLaplace(const std::vector<std::string>& names,
                             const std::vector<double>& lower, const std::vector<double>& upper,
                             const std::vector<double>& theta_map,
                             const std::vector<double>& fisher, bool explain_defocus) {
  const int n = static_cast<int>(names.size());
  LaplaceResult out;
  out.dim = n;
  out.scales.resize(n);
  Eigen::MatrixXd f = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic,
                                                     Eigen::RowMajor>>(fisher.data(), n, n);
  Eigen::VectorXd w(n);
  for (int i = 0; i < n; ++i) w[i] = out.scales[i] = upper[i] - lower[i];
  const Eigen::MatrixXd fs = w.asDiagonal() * f * w.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (fs + fs.transpose()));
  const Eigen::VectorXd lambda = eig.eigenvalues();
  const Eigen::MatrixXd v = eig.eigenvectors();
  // Eigenvalues below this fraction of the largest are numerically zero (rounding in J^T J
  // is ~1e-16 of the largest; 1e-12 leaves room).
  const double floor = 1e-12 * std::max(lambda.maxCoeff(), 0.0);
  Eigen::MatrixXd cov_scaled = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd unconstrained_load = Eigen::VectorXd::Zero(n);
  out.eigenvectors.resize(static_cast<size_t>(n) * n);
  out.eigen_sd.resize(n);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) out.eigenvectors[i * n + j] = v(i, j);
    const double sd = lambda[j] > floor ? 1.0 / std::sqrt(lambda[j]) : INFINITY;
    out.eigen_sd[j] = sd;
    if (sd <= kUnconstrainedSdFraction) {
      cov_scaled += v.col(j) * v.col(j).transpose() / lambda[j];
      continue;
    }
    unconstrained_load += v.col(j).cwiseAbs2();
    UnconstrainedDirection d;
    d.sd_fraction_of_prior = sd;
    // In parameter units: delta theta_i = w_i v_i; normalise the largest to +1.
    Eigen::VectorXd dir = w.cwiseProduct(v.col(j));
    int big = 0;
    for (int i = 0; i < n; ++i) {
      if (std::fabs(v(i, j)) > std::fabs(v(big, j))) big = i;
    }
    dir /= dir[big];
    d.direction.assign(dir.data(), dir.data() + n);
    std::ostringstream text;
    std::vector<std::string> loaded;
    for (int i = 0; i < n; ++i) {
      if (std::fabs(v(i, j)) > kLoadingThreshold) loaded.push_back(names[i]);
    }
    const bool defocus_ccd = std::count(loaded.begin(), loaded.end(), names[kDefocusPx]) &&
                             (std::count(loaded.begin(), loaded.end(), "ccd_sigma_x_px") ||
                              std::count(loaded.begin(), loaded.end(), "ccd_sigma_y_px"));
    for (size_t i = 0; i < loaded.size(); ++i) text << (i ? ", " : "") << loaded[i];
    text << (std::isinf(sd) ? ": the data do not constrain this combination at all"
                            : ": the data constrain this combination less than the prior does");
    if (defocus_ccd && explain_defocus) {
      text << " (a Gaussian defocus and the Gaussian CCD kernel convolve to one Gaussian: only "
              "defocus^2 + ccd_sigma_x^2 and defocus^2 + ccd_sigma_y^2 are identified; see "
              "total_sigma_x_px / total_sigma_y_px)";
    }
    d.description = text.str();
    out.unconstrained.push_back(d);
  }
  out.covariance.assign(static_cast<size_t>(n) * n, 0.0);
  out.sd.assign(n, NAN);
  out.constrained.assign(n, false);
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) out.covariance[a * n + b] = w[a] * cov_scaled(a, b) * w[b];
  }
  for (int a = 0; a < n; ++a) {
    std::vector<double> unit(n, 0.0);
    unit[a] = 1.0;
    out.sd[a] = DerivedSd(out, unit);
    out.constrained[a] = std::isfinite(out.sd[a]);
  }
  for (int i = 0; i < n; ++i) {
    // Near a bound on the scale of the prior and of the posterior: a wide prior (e.g. the
    // 2015 peak meta-parameter's eight decades) must not make a well-measured value count.
    double tol = kAtBoundFraction * w[i];
    if (std::isfinite(out.sd[i])) tol = std::min(tol, 2.0 * out.sd[i]);
    if (theta_map[i] - lower[i] < tol || upper[i] - theta_map[i] < tol) {
      out.at_bound.push_back(i);
    }
  }
  return out;
}

double DerivedSd(const LaplaceResult& laplace, const std::vector<double>& gradient) {
  const int n = laplace.dim;
  double var = 0.0;
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) var += gradient[a] * laplace.covariance[a * n + b] * gradient[b];
  }
  // Spread from the unconstrained directions, each across the prior (sd 1/sqrt(12) of the
  // prior-scaled unit width, or the likelihood's own sd where that is smaller).
  double spread2 = 0.0;
  for (int j = 0; j < n; ++j) {
    if (laplace.eigen_sd[j] <= kUnconstrainedSdFraction) continue;
    double dot = 0.0;  // d f / d t along eigenvector j of the prior-scaled problem
    for (int i = 0; i < n; ++i) {
      dot += laplace.eigenvectors[i * n + j] * laplace.scales[i] * gradient[i];
    }
    const double extent = std::min(laplace.eigen_sd[j], kUnconstrainedSdFraction);
    spread2 += dot * dot * extent * extent;
  }
  const double sd = std::sqrt(std::max(var, 0.0));
  if (spread2 > 0.0 && std::sqrt(spread2) > kUnconstrainedSpreadRatio * sd) return NAN;
  return sd;
}

bool SeedWalkers(const LaplaceResult& laplace, const std::vector<double>& centre, int count,
                 std::mt19937_64& engine,
                 const std::function<double(const double*)>& log_density,
                 std::vector<double>* walkers, std::string* error) {
  const int n = laplace.dim;
  walkers->assign(static_cast<size_t>(count) * n, 0.0);
  std::vector<double> u(n), theta(n);
  const int kMaxTries = 2000;
  for (int k = 0; k < count; ++k) {
    bool found = false;
    for (int attempt = 0; attempt < kMaxTries && !found; ++attempt) {
      // Late attempts shrink the Gaussian part, in case the box cuts it hard.
      const double shrink = attempt < kMaxTries / 2 ? 1.0 : 0.1;
      std::fill(u.begin(), u.end(), 0.0);
      for (int j = 0; j < n; ++j) {
        const double sd = laplace.eigen_sd[j];
        const double t = sd <= kUnconstrainedSdFraction ? shrink * sd * StandardNormal(engine)
                                                        : Uniform01(engine) - 0.5;
        for (int i = 0; i < n; ++i) u[i] += t * laplace.eigenvectors[i * n + j];
      }
      for (int i = 0; i < n; ++i) theta[i] = centre[i] + u[i] * laplace.scales[i];
      if (!std::isfinite(log_density(theta.data()))) continue;
      std::copy(theta.begin(), theta.end(), walkers->begin() + static_cast<size_t>(k) * n);
      found = true;
    }
    if (!found) {
      *error = "could not place MCMC walker " + std::to_string(k) +
               " inside the prior around the MAP point";
      return false;
    }
  }
  return true;
}

}  // namespace ccdpsf::fit
