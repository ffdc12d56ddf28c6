// What the data alone say of the parameters a Gaussian prior names (gaussian_prior.h), from a
// fit made with the prior, without fitting again: for `--ptc`, the spot-derived a_ij to hold
// against the flat-derived ones.
//
// In the Laplace (Gaussian) approximation at the MAP the posterior's precision is H = F + P:
// F the likelihood's Fisher information, P the prior's precision on the named block a. With b
// every other parameter, the likelihood's marginal on a is Gaussian with precision the Schur
// complement
//   S = F_aa - F_ab F_bb^+ F_ba
// (F_bb^+ the pseudo-inverse: F_bb is singular along directions the data do not identify,
// e.g. a Gaussian defocus against the CCD widths at one focus, and since F is positive
// semi-definite F_ba lies in F_bb's range, where the pseudo-inverse is the inverse). The
// posterior's marginal on a is the product of that and the prior, so (S + P) a_post =
// S a_data + P mean, i.e.
//   a_data = a_post + S^-1 P (a_post - mean),      covariance S^-1.
// Computed in prior-scaled coordinates (each parameter over the width of its flat range, as
// laplace.h does), with F_bb's eigenvalues below 1e-12 of F's largest taken as zero.
//
// Not available where S does not constrain every direction of a: an eigenvalue of S (scaled)
// whose sd 1/sqrt(lambda) exceeds kUnconstrainedSdFraction (laplace.h: the data constrain
// the direction less than its flat prior does), or a non-positive one. The flat bounds are
// ignored, as in every Laplace approximation: a MAP at a bound makes it approximate.
#ifndef CCDPSF_FIT_DATA_ALONE_ESTIMATE_H_
#define CCDPSF_FIT_DATA_ALONE_ESTIMATE_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"

namespace ccdpsf::fit {

struct DataAloneEstimate {
  bool available = false;
  std::string why_not;            // one line when not available
  std::vector<int> indices;       // theta indices, the prior's order
  std::vector<double> mean;       // a_data [the parameters' units]
  std::vector<double> covariance;  // S^-1, row-major, indices x indices [units^2]
  std::vector<double> sd;         // sqrt of its diagonal
};

// From the MAP of a model with an active Gaussian prior and the likelihood's Fisher
// information there (dim x dim, row-major, without the prior). Not available (with why_not)
// without an active prior, or where S does not constrain the named block.
DataAloneEstimate EstimateFromDataAlone(const FitModel& model,
                                        const std::vector<double>& theta_map,
                                        const std::vector<double>& fisher);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_DATA_ALONE_ESTIMATE_H_
