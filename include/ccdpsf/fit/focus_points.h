// The through-focus check: each exposure of a focus series fitted on its own.
//
// A through-focus fit (fit_model.h) ties the exposures' defocus to one law,
// sigma_f,k = rate |z_k - z0|, with one CCD kernel. One exposure alone cannot split its
// Gaussian width between the defocus and the CCD kernel, but it does measure their sum in
// quadrature, the total width
//
//   total_sigma_x_px = sqrt(defocus_sigma_px^2 + ccd_sigma_x_px^2)    (likewise y)  [px],
//
// free of the law. Plotted against the stage position z_k [um] beside the law's curve
// sqrt(ccd_sigma_x^2 + rate^2 (z - z0)^2), these show whether the series follows the law
// (the through-focus plot of fit_report.h). Each exposure gets the joint fit's model and
// priors with the Gaussian defocus free, its own flux and position, MAP and Laplace only.
#ifndef CCDPSF_FIT_FOCUS_POINTS_H_
#define CCDPSF_FIT_FOCUS_POINTS_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/map_fit.h"

namespace ccdpsf::fit {

struct FocusPoint {
  int exposure = 0;
  double focus_um = 0.0;  // the stage position z_k [um]
  // MAP and Laplace sd of the exposure's total widths [px] (NaN when its fit failed).
  Summary total_sigma_x_px, total_sigma_y_px;
  std::string failure;  // empty when fitted; else the one-line reason
};

// One FocusPoint per exposure of `model`, which must be in through-focus mode (otherwise
// none). `map` are the MAP options of the joint fit.
std::vector<FocusPoint> FitEachFocusPosition(const FitModel& model, const MapOptions& map);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FOCUS_POINTS_H_
