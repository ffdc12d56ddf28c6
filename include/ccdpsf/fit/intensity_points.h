// The intensity check of a joint fit with a signal-dependent kernel effect (brighter_fatter
// or boundary_shift): the CCD widths each exposure's own charge gives it, predicted by the
// joint posterior, beside what each exposure alone says.
//
// For every exposure k of the joint fit:
//   predicted   its affected widths (fit/affected_widths.h) at theta: at the MAP, and over
//               the MCMC states as SamplerResult::ThinnedStates(draws) thins them (median and
//               central 68 % interval); theta as fitted (the exposure as it was taken: its
//               position and flux), so the check compares like with like;
//   measured    exposure k fitted alone with the joint fit's model minus the signal-dependent
//               effect (and minus jitter, which needs two exposures; one flux, no focus law:
//               a free Gaussian defocus), MAP and Laplace sd only, as the through-focus check
//               (focus_points.h) does: the Gaussian kernel that one exposure shows, its
//               widening by its own charge included;
//   peak_e      the brightest pixel of its image at the joint MAP [e-], the abscissa.
// and once for the fit, `intrinsic`: the widths at zero signal, the fitted ccd_sigma_* (and
// total_sigma_*, the derived totals at zero signal), as fit.json's parameters give them.
//
// At one focus with a Gaussian defocus the CCD widths are not identified (docs/trust.md,
// single focus), neither jointly nor alone, but their sum in quadrature with the defocus is:
// the total widths are the check there (`ccd_identified` false).
#ifndef CCDPSF_FIT_INTENSITY_POINTS_H_
#define CCDPSF_FIT_INTENSITY_POINTS_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/map_fit.h"

namespace ccdpsf::fit {

// Widths on the two axes, CCD-only and total [px].
struct WidthSummaries {
  Summary ccd_sigma_x_px, ccd_sigma_y_px, total_sigma_x_px, total_sigma_y_px;
};

// Slot i of `s`: 0 ccd_sigma_x_px, 1 ccd_sigma_y_px, 2 total_sigma_x_px, 3 total_sigma_y_px.
const Summary& WidthAt(const WidthSummaries& s, int i);
Summary& WidthAt(WidthSummaries& s, int i);

struct IntensityPoint {
  int exposure = 0;
  double peak_e = NAN;        // at the joint MAP [e-]
  WidthSummaries predicted;   // map, median, lo68, hi68 (the last three NaN without MCMC)
  Summary delta_var_x_px2, delta_var_y_px2;  // boundary_shift's moment change, likewise
  WidthSummaries measured;    // map and laplace_sd of the exposure's own fit
  std::string failure;        // why the exposure's own fit failed; empty when it did not
};

struct IntensityPoints {
  std::string effect;         // "brighter_fatter" or "boundary_shift"; "" when not applicable
  bool ccd_identified = true;  // false: compare the total widths (see the top)
  WidthSummaries intrinsic;   // the fit's own summaries at zero signal
  std::vector<IntensityPoint> points;  // one per exposure
  // The predicted widths of the brightest exposure with its flux scaled, for the plot's
  // curve: peak_e [e-] and per axis the median and 68 % band (the MAP without MCMC), CCD-only
  // and total (curve_widths[0..3] in WidthSummaries' order).
  std::vector<double> curve_peak_e;
  std::vector<Summary> curve_widths[4];
};

// The check for `model` fitted as `result`; empty (effect "") unless the model holds
// brighter_fatter or boundary_shift and two or more exposures. `map` are the joint fit's MAP
// options; `draws` bounds the chain states used per exposure, `curve_draws` per curve node.
IntensityPoints MeasureIntensityPoints(const FitModel& model, const FitResult& result,
                                       const MapOptions& map, int draws = 200,
                                       int curve_draws = 100);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_INTENSITY_POINTS_H_
