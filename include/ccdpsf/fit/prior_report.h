// What fit.json and report.md say of a Gaussian prior (gaussian_prior.h) and of the data
// against it (data_alone_estimate.h). Nothing is written without an active prior, so a fit
// without `--ptc` reports exactly as before.
//
// fit.json (docs/formats.md):
//   "gaussian_prior": {"source": PATH, "parameters": [names], "mean": [...], "sd": [...],
//                      "covariance": [[...]], "truncated_to": "the flat ranges in priors"}
//   "boundary_shift_vs_flats": {"a_10": {"flat": {"median", "sd"},
//                                        "spot": {"median", "sd"} or null,
//                                        "spot_unavailable_because": "..." (when null),
//                                        "spots_and_flats": {"map", "laplace_sd"},
//                                        "difference_sd": (spot - flat) / sqrt(sd_spot^2 +
//                                                         sd_flat^2) or null}, "a_01": ...}
//   (the prior's only source today is ptc.json, flats; the keys are its lags' names).
#ifndef CCDPSF_FIT_PRIOR_REPORT_H_
#define CCDPSF_FIT_PRIOR_REPORT_H_

#include <string>

#include "ccdpsf/fit/fit.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::fit {

// "gaussian_prior" above; null without an active prior.
nlohmann::json GaussianPriorJson(const FitModel& model);

// "boundary_shift_vs_flats" above; null without an active prior.
nlohmann::json PriorComparisonJson(const FitModel& model, const FitResult& result);

// report.md's section: where the prior came from and a table of the flats', the spots' and
// the joint values with their difference; "" without an active prior.
std::string PriorComparisonMarkdown(const FitModel& model, const FitResult& result);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_PRIOR_REPORT_H_
