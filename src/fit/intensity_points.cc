#include "ccdpsf/fit/intensity_points.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <utility>

#include "ccdpsf/fit/affected_widths.h"
#include "internal/parallel_for.h"

namespace ccdpsf::fit {

namespace {

const Summary* FindDerived(const FitResult& r, const std::string& name) {
  for (const auto& [n, s] : r.derived) {
    if (n == name) return &s;
  }
  return nullptr;
}

// The four widths of `w` in WidthSummaries' order.
std::array<double, 4> Widths(const AffectedWidths& w) {
  return {w.ccd_sigma_x_px, w.ccd_sigma_y_px, w.total_sigma_x_px, w.total_sigma_y_px};
}
Summary* Slot(WidthSummaries* s, int i) { return &WidthAt(*s, i); }

// Nodes of the plot's curve: the brightest exposure's flux scaled from 0 to this multiple of
// the largest exposure's peak over its own, so that the curve spans every point.
constexpr int kCurveNodes = 13;
constexpr double kCurveReach = 1.1;

}  // namespace

const Summary& WidthAt(const WidthSummaries& s, int i) {
  return i == 0 ? s.ccd_sigma_x_px : i == 1 ? s.ccd_sigma_y_px : i == 2 ? s.total_sigma_x_px
                                                                         : s.total_sigma_y_px;
}
Summary& WidthAt(WidthSummaries& s, int i) {
  return const_cast<Summary&>(WidthAt(static_cast<const WidthSummaries&>(s), i));
}

IntensityPoints MeasureIntensityPoints(const FitModel& model, const FitResult& result,
                                       const MapOptions& map, int draws, int curve_draws) {
  IntensityPoints out;
  const std::string effect = SignalDependentEffect(model);
  if (effect.empty() || model.num_exposures() < 2) return out;
  out.effect = effect;
  out.ccd_identified = !CcdSplitUnidentified(model.options());
  const int dim = model.dim();
  out.intrinsic.ccd_sigma_x_px = result.parameters[kCcdSigmaXPx];
  out.intrinsic.ccd_sigma_y_px = result.parameters[kCcdSigmaYPx];
  if (const Summary* s = FindDerived(result, "total_sigma_x_px")) out.intrinsic.total_sigma_x_px = *s;
  if (const Summary* s = FindDerived(result, "total_sigma_y_px")) out.intrinsic.total_sigma_y_px = *s;

  const int n = model.num_exposures();
  const int threads = std::max(1, map.num_threads);
  std::vector<std::unique_ptr<FitEvaluator>> evaluators;
  for (int t = 0; t < threads; ++t) evaluators.push_back(model.NewEvaluator());
  const double* theta_map = result.map.theta.data();

  // Predicted: at the MAP, then over the thinned chain states.
  out.points.resize(n);
  for (int k = 0; k < n; ++k) {
    IntensityPoint& p = out.points[k];
    p.exposure = k;
    AffectedWidths w;
    if (AffectedKernelWidths(model, evaluators[0].get(), theta_map, k, &w)) {
      p.peak_e = w.peak_e;
      const auto v = Widths(w);
      for (int i = 0; i < 4; ++i) Slot(&p.predicted, i)->map = v[i];
      p.delta_var_x_px2.map = w.delta_var_x_px2;
      p.delta_var_y_px2.map = w.delta_var_y_px2;
    }
  }
  const std::vector<size_t> states =
      result.have_mcmc ? result.chain.ThinnedStates(draws) : std::vector<size_t>();
  if (!states.empty()) {
    // values[k][q][s]: exposure k, quantity q (4 widths, 2 variances), state s.
    std::vector<std::vector<std::vector<double>>> values(
        n, std::vector<std::vector<double>>(6, std::vector<double>(states.size(), NAN)));
    internal::ParallelFor(static_cast<int>(states.size()), threads, [&](int s, int worker) {
      const double* theta = &result.chain.chain[states[s] * dim];
      for (int k = 0; k < n; ++k) {
        AffectedWidths w;
        if (!AffectedKernelWidths(model, evaluators[worker].get(), theta, k, &w)) continue;
        const auto v = Widths(w);
        for (int i = 0; i < 4; ++i) values[k][i][s] = v[i];
        values[k][4][s] = w.delta_var_x_px2;
        values[k][5][s] = w.delta_var_y_px2;
      }
    });
    for (int k = 0; k < n; ++k) {
      IntensityPoint& p = out.points[k];
      for (int i = 0; i < 4; ++i) FillPosterior(std::move(values[k][i]), Slot(&p.predicted, i));
      FillPosterior(std::move(values[k][4]), &p.delta_var_x_px2);
      FillPosterior(std::move(values[k][5]), &p.delta_var_y_px2);
    }
  }

  // The curve: the brightest exposure (at the MAP) with its flux scaled.
  int brightest = 0;
  double top = 0.0;
  for (int k = 0; k < n; ++k) {
    if (out.points[k].peak_e > top) {
      top = out.points[k].peak_e;
      brightest = k;
    }
  }
  if (top > 0.0) {
    const std::vector<size_t> curve_states =
        result.have_mcmc ? result.chain.ThinnedStates(curve_draws) : std::vector<size_t>();
    for (int i = 0; i < 4; ++i) out.curve_widths[i].resize(kCurveNodes);
    out.curve_peak_e.assign(kCurveNodes, NAN);
    internal::ParallelFor(kCurveNodes, threads, [&](int node, int worker) {
      const double scale = kCurveReach * node / (kCurveNodes - 1);
      FitEvaluator* ev = evaluators[worker].get();
      std::vector<double> theta(theta_map, theta_map + dim);
      theta[kFluxE] *= scale;
      AffectedWidths w;
      if (AffectedKernelWidths(model, ev, theta.data(), brightest, &w)) {
        out.curve_peak_e[node] = w.peak_e;
        const auto v = Widths(w);
        for (int i = 0; i < 4; ++i) out.curve_widths[i][node].map = v[i];
      }
      std::vector<double> at[4];
      for (const size_t s : curve_states) {
        theta.assign(&result.chain.chain[s * dim], &result.chain.chain[s * dim] + dim);
        theta[kFluxE] *= scale;
        if (!AffectedKernelWidths(model, ev, theta.data(), brightest, &w)) continue;
        const auto v = Widths(w);
        for (int i = 0; i < 4; ++i) at[i].push_back(v[i]);
      }
      for (int i = 0; i < 4; ++i) {
        if (!at[i].empty()) FillPosterior(std::move(at[i]), &out.curve_widths[i][node]);
      }
    });
  }

  // Measured: each exposure alone, the signal-dependent effects (and jitter) dropped.
  FitModelOptions single = SingleExposureOptions(model.options());
  single.effects.erase(std::remove_if(single.effects.begin(), single.effects.end(),
                                      [](const FitEffect& e) {
                                        return e.kind == model::EffectKind::kBrighterFatter ||
                                               e.kind == model::EffectKind::kBoundaryShift;
                                      }),
                       single.effects.end());
  single.through_focus = false;
  single.flux = FluxMode::kShared;
  FitOptions options;
  options.map = map;
  options.run_mcmc = false;
  for (int k = 0; k < n; ++k) {
    IntensityPoint& p = out.points[k];
    std::string error;
    std::unique_ptr<FitModel> alone = FitModel::Create({model.stamps()[k]}, single, &error);
    FitResult r;
    if (alone == nullptr || !RunFit(*alone, options, &r, &error)) {
      p.failure = error.empty() ? "the exposure's own fit failed" : error;
      continue;
    }
    const Summary* tx = FindDerived(r, "total_sigma_x_px");
    const Summary* ty = FindDerived(r, "total_sigma_y_px");
    p.measured.ccd_sigma_x_px = r.parameters[kCcdSigmaXPx];
    p.measured.ccd_sigma_y_px = r.parameters[kCcdSigmaYPx];
    if (tx != nullptr) p.measured.total_sigma_x_px = *tx;
    if (ty != nullptr) p.measured.total_sigma_y_px = *ty;
  }
  return out;
}

}  // namespace ccdpsf::fit
