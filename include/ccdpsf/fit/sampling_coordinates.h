// The coordinates the MCMC walks in: the fit parameters with the two CCD widths replaced by
// the total Gaussian widths,
//
//   t_x = sqrt(sigma_x^2 + v),  t_y = sqrt(sigma_y^2 + v),
//   v = defocus_sigma^2 (Gaussian defocus) or R^2 / 4 (pillbox: its second moment per axis).
//
// Why: the data constrain t_x and t_y tightly but say little or nothing about how each splits
// between defocus and CCD kernel (docs/trust.md, single focus). In the fit parameters that leaves a
// thin curved ridge (sigma_f^2 + sigma_x^2 = const), on which the affine-invariant stretch
// move mixes very slowly (measured: tau grew past 1500 steps and acceptance fell to 0.17
// on the paper's values). In these coordinates the ridge is a straight line along the
// defocus axis, which affine moves follow easily.
//
// The priors stay flat in the fit parameters: the density in sampling coordinates carries the
// Jacobian |d(defocus, sigma_x, sigma_y) / d(defocus, t_x, t_y)| = t_x t_y / (sigma_x sigma_y).
// Every other coordinate is unchanged (same index, same meaning).
//
// pixel_centre sampling (the 2015 discretisation) is different: its kernels are sampled at
// integer offsets with unit peak, so a CCD width s acts only through the neighbour weights
// exp(-k^2 / (2 s^2)), and below ~0.2 px not at all. The defocus and the CCD widths are then
// identified separately, but each width's posterior is a peak plus a flat plateau down to
// the prior's edge. Its coordinates are u = exp(-1 / (2 s^2)) + c s per axis (see
// sampling_coordinates.cc), which shrink the plateau; the Jacobian is 1 / u'(s) per axis.
//
// Through-focus fits (fit_model.h) walk the fit parameters themselves (the identity map, no
// Jacobian): there the defocus differs per exposure, so no single total width exists, and
// the series identifies the CCD widths, so there is no ridge to straighten.
#ifndef CCDPSF_FIT_SAMPLING_COORDINATES_H_
#define CCDPSF_FIT_SAMPLING_COORDINATES_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"

namespace ccdpsf::fit {

class SamplingCoordinates {
 public:
  explicit SamplingCoordinates(const FitModel& model);

  // Names of the sampling coordinates (total_sigma_x_px / total_sigma_y_px at the CCD
  // widths' indices).
  const std::vector<std::string>& names() const { return names_; }

  void ToSampling(const double* theta, double* phi) const;
  // False when phi has no preimage (t^2 < v): outside the support.
  bool FromSampling(const double* phi, double* theta) const;
  // log |d theta / d phi| at phi (phi must have a preimage).
  double LogJacobian(const double* phi) const;
  // d theta / d phi at phi, dim x dim row-major (for the Fisher information in phi).
  std::vector<double> Jacobian(const double* phi) const;
  // Whether coordinate p of phi is theta's coordinate p itself (its bounds are theta's).
  bool IsIdentity(int p) const {
    return identity_ || (p != kCcdSigmaXPx && p != kCcdSigmaYPx);
  }

 private:
  double DefocusVariance(double defocus) const;
  double DefocusVarianceDerivative(double defocus) const;
  int dim_;
  bool pillbox_;
  bool identity_;
  bool kernel_weight_;  // pixel_centre sampling: see KernelWeightCoordinate
  std::vector<std::string> names_;
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_SAMPLING_COORDINATES_H_
