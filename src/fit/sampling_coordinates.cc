#include "ccdpsf/fit/sampling_coordinates.h"

#include <cmath>

namespace ccdpsf::fit {

SamplingCoordinates::SamplingCoordinates(const FitModel& model)
    : dim_(model.dim()),
      pillbox_(model.options().model.defocus == model::DefocusKind::kPillbox),
      identity_(model.through_focus()),
      names_(model.names()) {
  if (identity_) return;
  names_[kCcdSigmaXPx] = "total_sigma_x_px";
  names_[kCcdSigmaYPx] = "total_sigma_y_px";
}

double SamplingCoordinates::DefocusVariance(double d) const {
  return pillbox_ ? 0.25 * d * d : d * d;
}

double SamplingCoordinates::DefocusVarianceDerivative(double d) const {
  return pillbox_ ? 0.5 * d : 2.0 * d;
}

void SamplingCoordinates::ToSampling(const double* theta, double* phi) const {
  for (int i = 0; i < dim_; ++i) phi[i] = theta[i];
  if (identity_) return;
  const double v = DefocusVariance(theta[kDefocusPx]);
  phi[kCcdSigmaXPx] = std::sqrt(theta[kCcdSigmaXPx] * theta[kCcdSigmaXPx] + v);
  phi[kCcdSigmaYPx] = std::sqrt(theta[kCcdSigmaYPx] * theta[kCcdSigmaYPx] + v);
}

bool SamplingCoordinates::FromSampling(const double* phi, double* theta) const {
  for (int i = 0; i < dim_; ++i) theta[i] = phi[i];
  if (identity_) return true;
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
