#include "ccdpsf/fit/focus_points.h"

#include <cmath>
#include <memory>
#include <utility>

namespace ccdpsf::fit {

namespace {

const Summary* FindDerived(const FitResult& r, const std::string& name) {
  for (const auto& [n, s] : r.derived) {
    if (n == name) return &s;
  }
  return nullptr;
}

}  // namespace

std::vector<FocusPoint> FitEachFocusPosition(const FitModel& model, const MapOptions& map) {
  std::vector<FocusPoint> points;
  if (!model.through_focus()) return points;
  // The joint model's options with the law dropped: a free Gaussian defocus, one flux. Its
  // effects and a Gaussian prior on them stay (gaussian_prior.h): each exposure alone is drawn
  // with the same boundary-shift knowledge as the joint fit.
  FitModelOptions single = SingleExposureOptions(model.options());
  single.through_focus = false;
  single.flux = FluxMode::kShared;
  FitOptions options;
  options.map = map;
  options.run_mcmc = false;
  for (int k = 0; k < model.num_exposures(); ++k) {
    FocusPoint p;
    p.exposure = k;
    p.focus_um = model.FocusPositionUm(k);
    std::string error;
    std::unique_ptr<FitModel> alone = FitModel::Create({model.stamps()[k]}, single, &error);
    FitResult r;
    if (alone == nullptr || !RunFit(*alone, options, &r, &error)) {
      p.failure = error;
    } else {
      const Summary* sx = FindDerived(r, "total_sigma_x_px");
      const Summary* sy = FindDerived(r, "total_sigma_y_px");
      if (sx != nullptr && sy != nullptr) {
        p.total_sigma_x_px = *sx;
        p.total_sigma_y_px = *sy;
      } else {
        p.failure = "no total widths in the fit's summaries";
      }
    }
    points.push_back(std::move(p));
  }
  return points;
}

}  // namespace ccdpsf::fit
