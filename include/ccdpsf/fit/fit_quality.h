// What a fit's own numbers say about whether to trust it, as findings (quality.h):
//
//   chi2_high / chi2_low  chi^2 outside the central 99.8 % of its distribution for the
//                         degrees of freedom (each tail p < 1e-3: on data the model describes,
//                         2 fits in 1000 are flagged): too high, the model misses something
//                         (`ccdpsf diagnose`); too low, the noise model overstates the noise
//                         (read noise or gain too large, clipped or smoothed data) - suspect
//   gross_misfit          chi^2/dof > 10: the model does not describe the source - invalid
//   at_bound              a parameter at a prior bound, where the Laplace approximation and
//                         the credible interval are cut by the prior - suspect; not the
//                         defocus at zero where the defocus / CCD split is unidentified (that
//                         MAP sits there by construction, fit.cc)
//   width_upper_limit     a CCD width at its prior's lower bound: the spot is narrower than
//                         the model resolves, the width is only an upper limit - suspect
//   width_at_upper_bound  a CCD width at its upper bound: broader than the model allows -
//                         invalid
//   all_at_bounds         every shape parameter (Airy radius, defocus, CCD widths) at a bound
//                         - invalid
//   mcmc_not_converged    the chain did not reach its effective sample size - suspect
//   censored_misfit       a censored pixel (which adds no chi^2) lies > 4 sd on the wrong side
//                         of its level under the fitted model - suspect
#ifndef CCDPSF_FIT_FIT_QUALITY_H_
#define CCDPSF_FIT_FIT_QUALITY_H_

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/quality.h"

namespace ccdpsf::fit {

struct FitQualityOptions {
  double chi2_tail_p = 1e-3;        // each tail of chi^2 below this probability is suspect
  double gross_chi2_per_dof = 10.0;  // above this the fit is invalid
  double censored_sd = 4.0;  // a censored pixel this far on the wrong side of its level
  // Above this share of an exposure's modelled light in one pixel the spot is undersampled
  // (a note): "most of the light".
  double undersampled_peak_fraction = 0.5;
};

// The chi^2 findings alone (chi2_high, chi2_low, gross_misfit), for a chi^2 with dof.
void AssessChi2(double chi2, int dof, const FitQualityOptions& options, Quality* quality);

// Where chi^2 rejects the model (above its range): a note (intervals_assume_model) that the
// intervals assume the model, with the largest sandwich / Laplace sd ratio and where.
void AssessIntervalsUnderMisfit(const FitResult& result, const FitQualityOptions& options,
                                Quality* quality);

// The note `undersampled` where more than options.undersampled_peak_fraction of some
// exposure's modelled light (at the MAP) falls in its brightest pixel.
void AssessSampling(const FitModel& model, const FitResult& result,
                    const FitQualityOptions& options, Quality* quality);

// The prior-bound and convergence findings alone.
void AssessBounds(const FitModel& model, const FitResult& result, Quality* quality);

// Adds the fit's findings to *quality (AssessChi2 and AssessBounds).
void AssessFit(const FitModel& model, const FitResult& result, const FitQualityOptions& options,
               Quality* quality);

// The chi^2 / dof range holding the central 1 - 2 tail_p of its distribution (normal
// approximation of chi^2 / dof, sd sqrt(2 / dof)), for messages.
void ExpectedChi2PerDofRange(int dof, double tail_p, double* low, double* high);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_QUALITY_H_
