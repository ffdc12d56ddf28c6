// A Gaussian prior on named fit parameters, and the pieces every use of the posterior takes.
//
// Every prior in fit/ is flat within [lower, upper] (fit_model.h) unless
// FitModelOptions::gaussian_prior names parameters of theta: their joint prior is then the
// multivariate normal N(mean, covariance), truncated to their flat ranges. The truncation
// scales the density inside the box by a constant (1 over the normal's mass inside it), which
// no step of a fit needs, so the log densities here are the untruncated normal's. The first
// source is `--ptc=DIR/ptc.json` (ptc_prior.h): boundary_shift's a_10, a_01, a_11 as the flats
// measured them.
//
// With L the lower Cholesky factor of the covariance (covariance = L L^T) and theta_I the
// named parameters in the prior's order, the whitened residuals
//   r = L^-1 (theta_I - mean)
// give -log N(theta_I) = 1/2 |r|^2 + 1/2 log det(2 pi covariance), and the prior precision
// P = covariance^-1 = L^-T L^-1 is its Hessian (constant). The posterior takes them in:
//   MAP      r as one more Ceres residual block (map_fit.h, NewGaussianPriorCost), so that a
//            solve's cost 1/2 sum r^2 is minus the log posterior up to a constant, and the
//            starts are compared by it;
//   Laplace  P added to the likelihood's Fisher information on the named block
//            (GaussianPriorTerm::AddPrecision) before it is inverted;
//   MCMC     log N(theta_I) added to the log-likelihood (posterior_target.h, LogDensity).
// The likelihood itself (FitEvaluator::LogLikelihood, fit.json's fit.loglike) stays the
// likelihood.
#ifndef CCDPSF_FIT_GAUSSIAN_PRIOR_H_
#define CCDPSF_FIT_GAUSSIAN_PRIOR_H_

#include <string>
#include <vector>

namespace ccdpsf::fit {

// The prior as given: parameter names of theta (e.g. "boundary_shift.a_10"), the mean in
// their units and the covariance (row-major, names x names, their units squared).
struct GaussianPrior {
  std::vector<std::string> names;
  std::vector<double> mean;
  std::vector<double> covariance;
  // Where it came from, for the reports (e.g. the ptc.json's path).
  std::string source;
  bool empty() const { return names.empty(); }
};

// Whether `prior` is a Gaussian: names unique and non-empty, sizes that agree, finite
// numbers, a symmetric covariance (to 1e-9 of the diagonal's scale) that is positive definite
// (its correlation matrix's smallest eigenvalue above 1e-12). False with a one-line reason.
bool CheckGaussianPrior(const GaussianPrior& prior, std::string* error);

// A prior bound to a parameter vector's layout, factorised once.
class GaussianPriorTerm {
 public:
  // Binds `prior` to the parameters `theta_names`. An empty prior, or one that names none of
  // them, binds inactive (true): a prior on parameters a model does not fit says nothing of
  // it (e.g. the fit without effects that seeds one with them). False with a one-line reason
  // when it names some but not all of them, or CheckGaussianPrior fails.
  bool Bind(const GaussianPrior& prior, const std::vector<std::string>& theta_names,
            std::string* error);

  bool active() const { return !indices_.empty(); }
  int size() const { return static_cast<int>(indices_.size()); }
  const GaussianPrior& prior() const { return prior_; }
  // theta index of each named parameter, in the prior's order.
  const std::vector<int>& indices() const { return indices_; }
  // L^-1 (row-major, size x size): the whitened residuals' derivatives by theta_I.
  const std::vector<double>& whitening() const { return whitening_; }
  // P = covariance^-1 (row-major, size x size) [1 / units^2].
  const std::vector<double>& precision() const { return precision_; }

  // r = L^-1 (theta_I - mean), size() values.
  void WhitenedResiduals(const double* theta, double* r) const;
  // log N(theta_I; mean, covariance), the untruncated normal's (0 when inactive).
  double LogDensity(const double* theta) const;
  // Adds P into the (indices x indices) block of a dim x dim row-major information matrix.
  void AddPrecision(std::vector<double>* information, int dim) const;

 private:
  GaussianPrior prior_;
  std::vector<int> indices_;
  std::vector<double> whitening_, precision_;
  double log_normaliser_ = 0.0;  // -1/2 log det(2 pi covariance)
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_GAUSSIAN_PRIOR_H_
