// Laplace approximation at the MAP point, honest about what the data do not constrain.
//
// The Fisher information F of the whitened problem (FitEvaluator::FisherInformation) is
// analysed in prior-scaled coordinates u_i = theta_i / w_i, w_i the width of parameter i's
// flat prior, so that every direction is measured against what the prior already says.
// Eigen-decomposing W F W: along an eigenvector v with eigenvalue lambda the likelihood alone
// has standard deviation 1 / sqrt(lambda) (prior widths). A flat prior of unit width has sd
// 1 / sqrt(12) ~ 0.29; where the likelihood is broader than that (or lambda <= 0, a null
// direction of the Jacobian) the data do not constrain the direction, the posterior along it
// is the prior's, and a Gaussian covariance there would be a fiction (docs/trust.md, single focus:
// with a Gaussian defocus only sigma_f^2 + sigma_x^2 and sigma_f^2 + sigma_y^2 are
// identified, so the Jacobian has an exact null direction). Such directions are listed, the
// covariance is the inverse on the constrained subspace only, and a parameter that loads on
// an unconstrained direction gets no Laplace sd. The sampler is seeded with the Gaussian on
// the constrained subspace and spread uniformly over the prior along the rest.
#ifndef CCDPSF_FIT_LAPLACE_H_
#define CCDPSF_FIT_LAPLACE_H_

#include <functional>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"

namespace ccdpsf::fit {

// Threshold above which a direction counts as unconstrained: the sd of a flat prior of unit
// width.
constexpr double kUnconstrainedSdFraction = 0.28867513459481287;  // 1 / sqrt(12)
// A parameter "loads" on a direction when its component there exceeds this (unit vectors in
// prior-scaled coordinates): used to name the parameters of a direction.
constexpr double kLoadingThreshold = 0.1;
// A quantity (parameter or derived) counts as not constrained when the spread the
// unconstrained directions give it - each direction taken across the prior, sd 1/sqrt(12) of
// its width - exceeds this fraction of its Laplace sd on the constrained subspace: the
// Gaussian sd would then understate its uncertainty. (A first-order loading test is not
// enough: e.g. the ellipticity barely moves along the defocus ridge at the MAP, but over
// the ridge's full length it spans 0.05-0.5.)
constexpr double kUnconstrainedSpreadRatio = 0.5;
// Distance from a bound, as a fraction of the prior width, within which a MAP value counts as
// sitting at the bound (where the Gaussian approximation ignores the truncation); capped at
// two Laplace sd where that is finite.
constexpr double kAtBoundFraction = 1e-3;

struct UnconstrainedDirection {
  std::vector<double> direction;  // in parameter units, largest component +1
  double sd_fraction_of_prior = 0.0;  // likelihood sd along it / prior width; inf for null
  std::string description;            // names the parameters that trade against each other
};

struct LaplaceResult {
  int dim = 0;
  std::vector<double> covariance;  // dim x dim, parameter units, constrained subspace only
  std::vector<double> sd;          // per parameter; NaN where the parameter is not constrained
  std::vector<bool> constrained;
  std::vector<UnconstrainedDirection> unconstrained;
  std::vector<int> at_bound;       // parameter indices whose MAP value sits at a prior bound
  // The eigen-decomposition in prior-scaled coordinates (for seeding the sampler).
  std::vector<double> scales;      // w_i
  std::vector<double> eigenvectors;  // dim x dim, column j = eigenvector j
  std::vector<double> eigen_sd;      // sd along eigenvector j (prior widths); inf if <= 0
};

LaplaceResult ComputeLaplace(const FitModel& model, const std::vector<double>& theta_map,
                             const std::vector<double>& fisher);

// The same for any coordinates: names, and the widths (upper - lower) that scale them.
// explain_defocus names the Gaussian-defocus degeneracy when a direction involves it.
LaplaceResult ComputeLaplace(const std::vector<std::string>& names,
                             const std::vector<double>& lower, const std::vector<double>& upper,
                             const std::vector<double>& theta_map,
                             const std::vector<double>& fisher, bool explain_defocus);

// Laplace sd of a derived quantity f(theta) with gradient `gradient` at the MAP (delta
// method). NaN when f is not constrained (kUnconstrainedSpreadRatio).
double DerivedSd(const LaplaceResult& laplace, const std::vector<double>& gradient);

// `count` starting walkers inside the prior with finite log-posterior: MAP + Gaussian draws
// on the constrained subspace + uniform spread over [-1/2, 1/2] prior widths along each
// unconstrained direction. Returns false if no valid walker could be found.
// log_density returns -infinity where a walker may not go.
bool SeedWalkers(const LaplaceResult& laplace, const std::vector<double>& centre, int count,
                 std::mt19937_64& engine,
                 const std::function<double(const double*)>& log_density,
                 std::vector<double>* walkers, std::string* error);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_LAPLACE_H_
