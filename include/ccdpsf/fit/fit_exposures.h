// The fit of calibrated lab exposures from start to verdict, shared by `fit`, `trend` and
// `diagnose`:
//
//   1. the flux model of a joint fit, chosen from the data unless given (ChooseFluxMode);
//   2. the MAP, then pixels the model cannot explain masked and the MAP refound (at most
//      three rounds; OutlierOptions says which pixels);
//   3. Laplace and MCMC (fit.h);
//   4. the verdict (quality.h): calibration's and the set checks' findings, the masking's,
//      and the fit's own (fit_quality.h);
//   5. for a through-focus series, each exposure fitted alone (focus_points.h), the points the
//      report's through-focus plot sets beside the fitted law;
//   6. for a joint fit with brighter_fatter or boundary_shift, each exposure's widths as the
//      joint posterior predicts them at its signal and as it alone measures them
//      (intensity_points.h), the points of the report's intensity plot.
//
// Outliers. A pixel is masked when its normalised residual |z| >= threshold_sd (8: a
// Gaussian pixel goes there once in 10^15) and it is a transient or a spike, not part of a
// pattern that a wrong model leaves:
//   joint sets of >= 3 exposures: it also differs from the median z of the same stamp pixel
//     in the other exposures by >= threshold_sd, by >= transient_ratio (1) of that median
//     and by >= transient_spread (4) times the others' own spread there (1.4826 MAD), as a
//     cosmic ray, which hits one exposure only (a wrong model leaves much the same residual
//     in all, up to what sub-pixel phase changes, which the others' spread measures; a large
//     outlier may pull the joint fit off the others too, so they need not fit, only agree);
//   one or two exposures: |z| is at least spike_ratio (2.5) times the largest |z| among the
//     pixels at the same distance from the spot's centre (within 0.5 px) that are not its
//     neighbours (a spike drags the fit, leaving its neighbours off too); at least one such
//     pixel: a wrong width or profile leaves rings of residuals, a cosmic ray or hot pixel a
//     lone spike. The peak pixel has no such ring and is not masked: alone, a clipped peak and
//     a PSF flatter than the model look alike. A peak far below the model is reported
//     instead (finding "peak_deficit").
// At most max_per_exposure pixels per exposure and round, of which one in the core (a bad
// core pixel drags the fit, leaving its neighbours off until the refit). A masked pixel within
// core_radius_px of the centre of a one- or two-exposure fit is a suspect finding (the core
// carries the width, and a lone spike is only the likeliest reading), one outside
// it a note; in a set of >= 3 exposures, where the others show the pixel as it should be, a
// note either way. When pixels were masked, the flux model is chosen again without them.
#ifndef CCDPSF_FIT_FIT_EXPOSURES_H_
#define CCDPSF_FIT_FIT_EXPOSURES_H_

#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_quality.h"
#include "ccdpsf/fit/focus_points.h"
#include "ccdpsf/fit/intensity_points.h"
#include "ccdpsf/quality.h"

namespace ccdpsf::fit {

struct OutlierOptions {
  bool enabled = true;
  double threshold_sd = 8.0;
  double spike_ratio = 2.5;
  double transient_ratio = 1.0;
  double transient_spread = 4.0;
  double core_radius_px = 1.5;
  int max_per_exposure = 3;
  int max_rounds = 3;
};

struct ExposuresFitOptions {
  FitConfig config;         // model, fit and calibration options
  bool flux_given = false;  // config.model.flux was set by the user: no automatic choice
  OutlierOptions outliers;
  FitQualityOptions quality;
};

struct OutlierMask {
  int exposure = 0;
  int x_px = 0, y_px = 0;  // frame coordinates
  double z = 0.0;          // normalised residual when it was masked
  bool core = false;
};

struct ExposuresFit {
  std::unique_ptr<FitModel> model;  // the final model (stamps with every mask applied)
  FitResult result;
  std::vector<CalibrationReport> calibration;
  std::vector<OutlierMask> outliers;
  Quality quality;                  // the verdict
  std::vector<std::string> notes;   // choices made from the data, for the terminal and report
  std::vector<FocusPoint> focus_points;  // step 5; empty unless through-focus
  IntensityPoints intensity_points;      // step 6; effect "" unless it applies
};

// The flux model for a joint set, from the light outside each stamp's 3 x 3 core over the
// pixels measured in every stamp (a clipped, saturated or cosmic-ray-hit core says nothing of
// the flux): exposures at one exposure time (or none known) whose such signals agree within
// 3 % share one flux; exposure times that differ by more than 1 % with signals proportional
// to them within 5 % scale it by exposure time; anything else gets a flux per exposure. When
// that light is too faint to compare (counting noise above 1 %), exposures share one flux at
// one exposure time and get one each otherwise. *why says what the data showed.
FluxMode ChooseFluxMode(const std::vector<Stamp>& stamps, std::string* why);

// Steps 1-6 above. `set_quality` holds the set checks' findings (exposure_set.h). False
// with a one-line reason when the model cannot be built or no MAP is found.
bool FitExposures(const std::vector<Exposure>& exposures, const Quality& set_quality,
                  const ExposuresFitOptions& options, ExposuresFit* out, std::string* error);

// Step 2's test on a fitted model: the pixels to mask at theta.
std::vector<OutlierMask> FindOutliers(const FitModel& model, const std::vector<double>& theta,
                                      const OutlierOptions& options);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_EXPOSURES_H_
