// `--ptc=DIR/ptc.json` (`fit`, `trend`): the flat-field measurement of boundary_shift's
// nearest coefficients as the Gaussian prior of the spot fit's (fit/gaussian_prior.h).
//
// `ccdpsf ptc` writes ptc.json (ptc.h, docs/formats.md) with "a": {"a_10": {"median", "sd",
// ...}, ...} and "a_covariance": {"names": ["a_00", "a_10", ...], "matrix": [[...]]}, the fit's
// covariance of every lag's a_ij [1/e-^2]. Its lags are Astier et al.'s a_ij with i along x
// (columns) and j along y (rows), the convention of model/boundary_shift.h, so ptc's a_10,
// a_01 and a_11 are the parameters boundary_shift.a_10, .a_01 and .a_11 themselves. The prior
// is the normal with the medians as its mean and the 3 x 3 block of a_covariance as its
// covariance (the flats' correlations between the lags kept); boundary_shift.a_far stays
// flat: the far lags' power law is the spot model's own, not a lag ptc measures as such.
#ifndef CCDPSF_PTC_PRIOR_H_
#define CCDPSF_PTC_PRIOR_H_

#include <string>

#include "ccdpsf/fit/gaussian_prior.h"

namespace ccdpsf {

// The lags taken from ptc.json, and the fit parameters they become.
inline constexpr const char* kPtcPriorLags[] = {"a_10", "a_01", "a_11"};

// Reads ptc.json at `path` (the bounded text reader, input_file.h) into *prior, its source
// the path. False with a one-line reason naming the file: unreadable, not JSON, not a ptc.json
// (a field missing or of the wrong type), a median that is not finite, an sd that is not a
// positive finite number, a covariance whose diagonal is not the sds squared (to 1e-6), or one
// that is not positive definite.
bool ReadPtcPrior(const std::string& path, fit::GaussianPrior* prior, std::string* error);

// The same from the file's text; `path` names it in messages and becomes the source.
bool ParsePtcPrior(const std::string& text, const std::string& path, fit::GaussianPrior* prior,
                   std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_PTC_PRIOR_H_
