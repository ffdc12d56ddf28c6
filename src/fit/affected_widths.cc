#include "ccdpsf/fit/affected_widths.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace ccdpsf::fit {

std::string SignalDependentEffect(const FitModel& model) {
  for (const model::EffectKind kind :
       {model::EffectKind::kBoundaryShift, model::EffectKind::kBrighterFatter}) {
    if (model.EffectIndex(kind) >= 0) return model::ToString(kind);
  }
  return "";
}

bool AffectedKernelWidths(const FitModel& model, FitEvaluator* evaluator, const double* theta,
                          int k, AffectedWidths* out) {
  *out = AffectedWidths();
  double sx = NAN, sy = NAN;
  // brighter_fatter's sigma_0 + b I; theta's own widths otherwise.
  if (!evaluator->KernelWidths(theta, k, &sx, &sy)) return false;
  std::vector<double> with;
  if (!evaluator->ModelImage(theta, k, &with, nullptr)) return false;
  out->peak_e = *std::max_element(with.begin(), with.end());

  const int shift = model.EffectIndex(model::EffectKind::kBoundaryShift);
  if (shift >= 0) {
    std::vector<double> plain_theta(theta, theta + model.dim());
    std::fill(plain_theta.begin() + shift,
              plain_theta.begin() + shift + model.EffectSize(model::EffectKind::kBoundaryShift),
              0.0);
    std::vector<double> without;
    if (!evaluator->ModelImage(plain_theta.data(), k, &without, nullptr)) return false;
    const model::SpotParams spot = model.SpotFor(theta, k);
    const double flux = spot[model::kFlux];
    const double cx = theta[FitModel::XIndex(k)], cy = theta[FitModel::YIndex(k)];
    const model::PixelGrid grid = model.GridFor(k);
    // Moments of the change about the spot's centre, in frame coordinates (pixel centres at
    // integers; integrated sampling, the only one boundary_shift exists in).
    double d1x = 0.0, d1y = 0.0, d2x = 0.0, d2y = 0.0;
    for (int j = 0; j < grid.ny; ++j) {
      const double y = grid.y0 + j - cy;
      for (int i = 0; i < grid.nx; ++i) {
        const size_t q = static_cast<size_t>(j) * grid.nx + i;
        const double dq = with[q] - without[q];
        if (dq == 0.0) continue;
        const double x = grid.x0 + i - cx;
        d1x += dq * x;
        d1y += dq * y;
        d2x += dq * x * x;
        d2y += dq * y * y;
      }
    }
    // No light, no charge to move the boundaries: the limit of Delta var at F -> 0 is 0.
    if (flux > 0.0) {
      out->delta_var_x_px2 = d2x / flux - (d1x / flux) * (d1x / flux);
      out->delta_var_y_px2 = d2y / flux - (d1y / flux) * (d1y / flux);
    }
  }
  const double vx = sx * sx + out->delta_var_x_px2, vy = sy * sy + out->delta_var_y_px2;
  if (!(vx > 0.0) || !(vy > 0.0)) return false;
  out->ccd_sigma_x_px = std::sqrt(vx);
  out->ccd_sigma_y_px = std::sqrt(vy);
  const double d = model.DefocusFor(theta, k);
  const double d2 = model.options().model.defocus == model::DefocusKind::kGaussian ? d * d : d * d / 4;
  out->total_sigma_x_px = std::sqrt(vx + d2);
  out->total_sigma_y_px = std::sqrt(vy + d2);
  return true;
}

}  // namespace ccdpsf::fit
