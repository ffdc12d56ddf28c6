// Model alternatives for `ccdpsf diagnose`: the same spot with one component of another
// shape, tested against the current model like the catalogue's additive effects, so that
// physics the catalogue does not add (a geometric defocus, pixels that collect from less than
// their full area) is named for what it is instead of as the nearest additive effect.
//
//   pillbox_defocus   the defocus kernel a uniform disc of radius R [px] instead of a
//                     Gaussian (ModelOptions::defocus): an out-of-focus spot projector in
//                     geometric optics. Not nested in the Gaussian model (same number of
//                     parameters, R in place of sigma_f): LR = 2 delta log L has no reference
//                     distribution, so it counts as significant only when delta BIC = -LR is
//                     below -10 (very strong evidence on the scale of Kass & Raftery 1995).
//                     Fitted with the analytic-Jacobian fit::FitModel (a pillbox render takes
//                     ~17 ms, 50 times a Gaussian one, too slow for numeric derivatives), from
//                     R = 2 sigma_f (equal second moments, R^2 / 4 = sigma_f^2) and from a
//                     smaller R with the CCD widths taking the rest of the variance, then
//                     scored with the EffectModel likelihood. Only on a model without added
//                     effects (fit::FitModel has none).
//   pixel_response    a collecting window of width w < 1 px centred in each pixel
//                     (ModelOptions::pixel_response_width): charge landing outside it is lost.
//                     Nested (w = 1 is the current model, on the boundary): LR from the
//                     profile likelihood over w = 0.9, 0.8, 0.7, 0.6, 0.5 and a parabola's
//                     maximum between the best grid points, p from the chi-bar-square
//                     mixture with one boundary parameter; sd(w) from the profile's curvature.
//
// An intra-pixel sensitivity that falls towards the pixel edges (rather than a sharp window)
// is not modelled: such data are expected to select pixel_response with a width between the
// two, or to stay unexplained.
#ifndef CCDPSF_DIAGNOSE_ALTERNATIVES_H_
#define CCDPSF_DIAGNOSE_ALTERNATIVES_H_

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "ccdpsf/diagnose/effect_fit.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/map_fit.h"

namespace ccdpsf::diagnose {

enum class AlternativeKind { kPillboxDefocus, kPixelResponse };
std::string ToString(AlternativeKind kind);  // "pillbox_defocus", "pixel_response"
const std::vector<AlternativeKind>& AllAlternatives();

// delta BIC below which a non-nested alternative counts as significant.
constexpr double kNonNestedDeltaBic = -10.0;

// Why `kind` cannot be tried on `current` (empty: it can).
std::string AlternativeNotApplicable(const EffectModel& current, AlternativeKind kind);

struct AlternativeFit {
  AlternativeKind kind;
  // The alternative's model options on the same stamps, and the current spec on them (the
  // model holds a reference to `base`: keep both together).
  std::unique_ptr<fit::FitModel> base;
  std::unique_ptr<EffectModel> model;
  EffectFitResult fit;
  std::string parameter;  // "defocus_radius_px" or "pixel_response.width_px"
  double value = NAN;     // its MAP [px]
  double sd = NAN;        // Laplace (pillbox) or from the profile's curvature (response)
  bool at_bound = false;  // the response width at the grid's narrowest end
  std::vector<std::pair<double, double>> profile;  // (w, log L) for pixel_response
};

// Fits `kind` on the stamps of `current` from its MAP `current_fit`. False with a one-line
// reason when no fit succeeds.
bool FitAlternative(const EffectModel& current, const EffectFitResult& current_fit,
                    AlternativeKind kind, const EffectFitOptions& fit_options,
                    const fit::MapOptions& map_options, AlternativeFit* out, std::string* error);

// "pillbox defocus", "pixel response 0.78 px": what a model's options change from the paper's.
std::string DescribeModelOptions(const model::ModelOptions& options);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_ALTERNATIVES_H_
