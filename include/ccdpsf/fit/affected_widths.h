// The brighter-fatter-affected CCD widths of one exposure: the kernel widths that the spot of
// exposure k, at its own collected signal, is drawn with, computed from the model at theta
// (not fitted).
//
// The fitted CCD widths ccd_sigma_x_px / ccd_sigma_y_px of a model with a signal-dependent
// effect are the INTRINSIC kernel, the kernel at zero collected signal. What a lab exposure
// shows is that kernel widened by its own charge:
//
//   brighter_fatter (the paper's empirical law, model/effects.h): the kernel is Gaussian at
//     every signal, with widths sigma_0 + b x I (I the peak pixel of the spot drawn without
//     the growth; FitEvaluator::KernelWidths). The affected widths are exactly those.
//
//   boundary_shift (model/boundary_shift.h): the charge already collected moves the pixel
//     boundaries, which is not a Gaussian kernel at all (the core flattens, the edge
//     neighbours gain more than the diagonals). Its affected widths are DEFINED by the second
//     central moments: with M the image of exposure k at theta drawn without the boundary
//     shift (theta's a_ij set to 0, nothing else changed) and dQ = (the image drawn with it)
//     - M, both noise-free and in electrons, the change of the image's second central moment
//     along x is
//
//       Delta var_x = sum_p dQ_p (x_p - x_k)^2 / F - (sum_p dQ_p (x_p - x_k) / F)^2   [px^2]
//
//     (likewise y), x_p the centre of pixel p, x_k the spot's centre, F its flux [e-] (the
//     total of the continuous image: the moments are per electron of the spot), and
//
//       sigma_eff_x = sqrt(ccd_sigma_x^2 + Delta var_x)                               [px]
//
//     the width of the Gaussian CCD kernel that, in the model without the effect, gives the
//     spot the same second central moment (a Gaussian kernel convolves, and convolution adds
//     variances, so widening the kernel from sigma to sigma_eff adds exactly sigma_eff^2 -
//     sigma^2 to the image's variance; the Airy, defocus and pixel parts cancel in the
//     difference). The formula is exact for the moments of the pixelated image when the
//     effect conserves charge (sum_p dQ_p = 0, which boundary shifts do: a boundary's gain is
//     its neighbour's loss) and the spot without it is centred on x_k (symmetric about its
//     centre: Airy, defocus and Gaussian kernel are).
//
//     Its approximation: it matches the second moment only. The boundary shift flattens the
//     core and moves charge to the wings differently from a wider Gaussian, so a fit of the
//     exposure with the Gaussian kernel alone (the "measured" width, fit/intensity_points.h),
//     which weighs the core by its pixels' inverse variances, need not find exactly
//     sigma_eff: the moment counts charge moved two pixels out four times as much as charge
//     moved one pixel out. To first order in the a_ij, Delta var is linear in the a_ij and in
//     the collected signal (dQ is, at fixed spot shape), and 0 for a_ij = 0. Image effects
//     that act after the kernel (halo, IPC, CTI, nonlinearity; effects.h) act on dQ too: the
//     change is of the image as the model draws it. The window of the redistribution
//     (kBoundaryShiftWindowHalf) bounds where dQ is nonzero, so the sums are not truncated by
//     the stamp.
//
// The total widths add the exposure's defocus in quadrature, as the fit's total_* metrics
// (fit.cc DerivedAt): sqrt(sigma_eff^2 + defocus^2) for a Gaussian defocus, + R^2 / 4 for a
// pillbox of radius R.
#ifndef CCDPSF_FIT_AFFECTED_WIDTHS_H_
#define CCDPSF_FIT_AFFECTED_WIDTHS_H_

#include <cmath>
#include <string>

#include "ccdpsf/fit/fit_model.h"

namespace ccdpsf::fit {

struct AffectedWidths {
  double ccd_sigma_x_px = NAN, ccd_sigma_y_px = NAN;  // sigma_eff [px]
  double total_sigma_x_px = NAN, total_sigma_y_px = NAN;  // with the defocus [px]
  // boundary_shift's Delta var [px^2]; 0 without it (brighter_fatter's growth is a kernel
  // width, not a moment change).
  double delta_var_x_px2 = 0.0, delta_var_y_px2 = 0.0;
  double peak_e = NAN;  // the brightest pixel of exposure k's image at theta [e-]
};

// Exposure k's affected widths at theta (the intrinsic ones when the model has neither
// effect). `evaluator` must be one of `model`'s. False where an image cannot be drawn or
// ccd_sigma^2 + Delta var is not positive.
bool AffectedKernelWidths(const FitModel& model, FitEvaluator* evaluator, const double* theta,
                          int k, AffectedWidths* out);

// Whether the model holds a signal-dependent kernel effect (brighter_fatter or boundary_shift),
// whose name it then returns; "" when not.
std::string SignalDependentEffect(const FitModel& model);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_AFFECTED_WIDTHS_H_
