#include "ccdpsf/fit/sampling_coordinates.h"

#include <cmath>

namespace ccdpsf::fit {

SamplingCoordinates::SamplingCoordinates(const FitModel& model)
    : dim_(model.dim()),
      pillbox_(model.options().model.defocus == model::DefocusKind::kPillbox),
      identity_(model.through_focus()),
      kernel_weight_(!identity_ && model.options().model.sampling == model::Sampling::kPixelCentre),
      names_(model.names()) {
  if (identity_) return;
  if (kernel_weight_) {
    names_[kCcdSigmaXPx] = "ccd_kernel_weight_x";
    names_[kCcdSigmaYPx] = "ccd_kernel_weight_y";
    return;
  }
  names_[kCcdSigmaXPx] = "total_sigma_x_px";
  names_[kCcdSigmaYPx] = "total_sigma_y_px";
}

double SamplingCoordinates::DefocusVariance(double d) const {
  return pillbox_ ? 0.25 * d * d : d * d;
}

double SamplingCoordinates::DefocusVarianceDerivative(double d) const {
  return pillbox_ ? 0.5 * d : 2.0 * d;
}

namespace {

// pixel_centre coordinates of a CCD width s [px]: u(s) = exp(-1 / (2 s^2)) + c s, with c in
// 1/px. The first term is the sampled kernel's weight on the nearest neighbours, which is
// what the 2015 discretisation's likelihood depends on smoothly; the second keeps u strictly
// increasing and gives the widths below ~0.2 px, where that weight is below 1e-5 and the
// likelihood is flat, a width of c x 0.15 instead of 0.15 px. In s itself that plateau, a
// few per cent of the posterior at 83 ke- and most of it at 7 ke-, joined to a peak ~0.01 px
// wide, is what the stretch move mixes slowly. Measured on Table 1's simulated 82.8 and 7.1
// ke- settings (tau of the slowest parameter, steps): total widths 547 and 285; this map
// with c = 1e-3: 91 and 257; 3e-3: 81 and 160; 1e-2: 104 and 184. Same posterior each time
// (medians and 68 % intervals within 0.001 px).
constexpr double kPlateauSlope = 3e-3;

double KernelWeightCoordinate(double s) { return std::exp(-0.5 / (s * s)) + kPlateauSlope * s; }

double KernelWeightDerivative(double s) {
  return std::exp(-0.5 / (s * s)) / (s * s * s) + kPlateauSlope;
}

// The inverse of KernelWeightCoordinate by bisection (u is increasing; 60 halvings of
// [0, 20] px reach 2e-17 px). NaN when u <= 0 (no preimage).
double WidthOfKernelWeight(double u) {
  if (!(u > 0)) return NAN;
  double lo = 0.0, hi = 20.0;
  if (KernelWeightCoordinate(hi) < u) return NAN;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (KernelWeightCoordinate(mid) < u ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

void SamplingCoordinates::ToSampling(const double* theta, double* phi) const {
  for (int i = 0; i < dim_; ++i) phi[i] = theta[i];
  if (identity_) return;
  if (kernel_weight_) {
    phi[kCcdSigmaXPx] = KernelWeightCoordinate(theta[kCcdSigmaXPx]);
    phi[kCcdSigmaYPx] = KernelWeightCoordinate(theta[kCcdSigmaYPx]);
    return;
  }
  const double v = DefocusVariance(theta[kDefocusPx]);
  phi[kCcdSigmaXPx] = std::sqrt(theta[kCcdSigmaXPx] * theta[kCcdSigmaXPx] + v);
  phi[kCcdSigmaYPx] = std::sqrt(theta[kCcdSigmaYPx] * theta[kCcdSigmaYPx] + v);
}

bool SamplingCoordinates::FromSampling(const double* phi, double* theta) const {
  for (int i = 0; i < dim_; ++i) theta[i] = phi[i];
  if (identity_) return true;
  if (kernel_weight_) {
    theta[kCcdSigmaXPx] = WidthOfKernelWeight(phi[kCcdSigmaXPx]);
    theta[kCcdSigmaYPx] = WidthOfKernelWeight(phi[kCcdSigmaYPx]);
    return std::isfinite(theta[kCcdSigmaXPx]) && std::isfinite(theta[kCcdSigmaYPx]);
  }
  const double v = DefocusVariance(phi[kDefocusPx]);
  const double sx2 = phi[kCcdSigmaXPx] * phi[kCcdSigmaXPx] - v;
  const double sy2 = phi[kCcdSigmaYPx] * phi[kCcdSigmaYPx] - v;
  if (!(sx2 > 0 && sy2 > 0 && phi[kCcdSigmaXPx] > 0 && phi[kCcdSigmaYPx] > 0)) return false;
  theta[kCcdSigmaXPx] = std::sqrt(sx2);
  theta[kCcdSigmaYPx] = std::sqrt(sy2);
  return true;
}

double SamplingCoordinates::LogJacobian(const double* phi) const {
  if (identity_) return 0.0;
  if (kernel_weight_) {
    return -std::log(KernelWeightDerivative(WidthOfKernelWeight(phi[kCcdSigmaXPx]))) -
           std::log(KernelWeightDerivative(WidthOfKernelWeight(phi[kCcdSigmaYPx])));
  }
  const double v = DefocusVariance(phi[kDefocusPx]);
  const double sx2 = phi[kCcdSigmaXPx] * phi[kCcdSigmaXPx] - v;
  const double sy2 = phi[kCcdSigmaYPx] * phi[kCcdSigmaYPx] - v;
  return std::log(phi[kCcdSigmaXPx]) + std::log(phi[kCcdSigmaYPx]) - 0.5 * std::log(sx2) -
         0.5 * std::log(sy2);
}

std::vector<double> SamplingCoordinates::Jacobian(const double* phi) const {
  std::vector<double> j(static_cast<size_t>(dim_) * dim_, 0.0);
  for (int i = 0; i < dim_; ++i) j[i * dim_ + i] = 1.0;
  if (identity_) return j;
  if (kernel_weight_) {
    for (int i : {kCcdSigmaXPx, kCcdSigmaYPx}) {
      j[i * dim_ + i] = 1.0 / KernelWeightDerivative(WidthOfKernelWeight(phi[i]));
    }
    return j;
  }
  std::vector<double> theta(dim_);
  FromSampling(phi, theta.data());
  const double dv = DefocusVarianceDerivative(phi[kDefocusPx]);
  // sigma_x = sqrt(t_x^2 - v(d)): d/dt_x = t_x / sigma_x, d/dd = -v'(d) / (2 sigma_x).
  for (int axis = 0; axis < 2; ++axis) {
    const int i = axis == 0 ? kCcdSigmaXPx : kCcdSigmaYPx;
    j[i * dim_ + i] = phi[i] / theta[i];
    j[i * dim_ + kDefocusPx] = -dv / (2.0 * theta[i]);
  }
  return j;
}

}  // namespace ccdpsf::fit
