#include "ccdpsf/fit/focus_plot.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

namespace ccdpsf::fit {

namespace {

// The law's total width at stage position z [um] for one axis [px].
double LawWidth(double ccd_sigma_px, double rate_px_per_um, double z_um, double z0_um) {
  const double defocus = rate_px_per_um * (z_um - z0_um);
  return std::sqrt(ccd_sigma_px * ccd_sigma_px + defocus * defocus);
}

}  // namespace

bool WriteFocusPlot(const std::string& dir, const std::string& stem, const ExposuresFit& fit,
                    const std::optional<TruthFile>& truth, const PlotOptions& options,
                    PlotResult* result, bool* truth_drawn, std::string* error) {
  *truth_drawn = false;
  const FitModel& model = *fit.model;
  const FitResult& r = fit.result;
  if (!model.through_focus() || fit.focus_points.empty()) {
    *error = "the through-focus plot needs a through-focus fit";
    return false;
  }
  const int dim = model.dim();
  const int focus = model.FocusIndex();

  // The z range: the exposures' positions with 10 % of their span either side.
  double z_min = INFINITY, z_max = -INFINITY;
  for (int k = 0; k < model.num_exposures(); ++k) {
    z_min = std::min(z_min, model.FocusPositionUm(k));
    z_max = std::max(z_max, model.FocusPositionUm(k));
  }
  const double margin = 0.1 * std::max(z_max - z_min, 1e-6);
  constexpr int kGrid = 81;
  std::vector<double> z(kGrid);
  for (int i = 0; i < kGrid; ++i)
    z[i] = z_min - margin + (z_max - z_min + 2 * margin) * i / (kGrid - 1);

  XyPlotInput in;
  in.title = "through focus: each exposure alone against the fitted law";
  in.x_label = "stage focus position z [um]";
  in.y_label = "total Gaussian width sqrt(defocus^2 + ccd sigma^2) [px]";
  in.dodge_fraction = 0.01;
  const char* axis_name[2] = {"x", "y"};
  const int ccd_index[2] = {kCcdSigmaXPx, kCcdSigmaYPx};

  for (int a = 0; a < 2; ++a) {
    Curve law;
    law.x = z;
    const SamplerResult& c = r.chain;
    const size_t kept =
        r.have_mcmc ? static_cast<size_t>(std::max(c.num_steps - c.burn_in, 0)) * c.num_walkers : 0;
    if (kept > 0) {
      const size_t draws = std::min<size_t>(kept, kMaxFocusCurveDraws);
      std::vector<std::vector<double>> at(kGrid);
      for (size_t d = 0; d < draws; ++d) {
        const size_t t = draws > 1 ? d * (kept - 1) / (draws - 1) : 0;
        const double* theta = &c.chain[(static_cast<size_t>(c.burn_in) * c.num_walkers + t) * dim];
        for (int i = 0; i < kGrid; ++i) {
          at[i].push_back(LawWidth(theta[ccd_index[a]], theta[kDefocusPx], z[i], theta[focus]));
        }
      }
      for (int i = 0; i < kGrid; ++i) {
        Summary s;
        FillPosterior(std::move(at[i]), &s);
        law.y.push_back(s.median);
        law.y_lo.push_back(s.lo68);
        law.y_hi.push_back(s.hi68);
      }
      law.label = std::string(axis_name[a]) + ": fitted law, posterior median and 68 % band";
    } else {
      const double* theta = r.map.theta.data();
      for (int i = 0; i < kGrid; ++i) {
        law.y.push_back(LawWidth(theta[ccd_index[a]], theta[kDefocusPx], z[i], theta[focus]));
      }
      law.label = std::string(axis_name[a]) + ": fitted law at the MAP";
    }
    in.curves.push_back(std::move(law));

    Series alone;
    alone.label = std::string(axis_name[a]) + ": each exposure fitted alone (MAP +- Laplace sd)";
    for (const FocusPoint& p : fit.focus_points) {
      const Summary& s = a == 0 ? p.total_sigma_x_px : p.total_sigma_y_px;
      if (!p.failure.empty() || !std::isfinite(s.map) || !std::isfinite(p.focus_um)) continue;
      const double sd = std::isfinite(s.laplace_sd) ? s.laplace_sd : 0.0;
      alone.x.push_back(p.focus_um);
      alone.y.push_back(s.map);
      alone.y_lo.push_back(s.map - sd);
      alone.y_hi.push_back(s.map + sd);
    }
    if (!alone.x.empty()) in.series.push_back(std::move(alone));
  }

  // True widths: the simulation's per-exposure defocus with its CCD widths, when they apply.
  if (truth && truth->document.is_object()) {
    const nlohmann::json& t = truth->document;
    const bool effects = t.contains("effects") && !t["effects"].empty();
    // (A damaged truth file's "parameters" of another type reads as none: json::value() would
    // throw.)
    const nlohmann::json params = t.contains("parameters") && t["parameters"].is_object()
                                      ? t["parameters"]
                                      : nlohmann::json::object();
    if (!effects && params.contains("ccd_sigma_x_px") && params.contains("ccd_sigma_y_px") &&
        t.contains("exposures") && t["exposures"].is_array()) {
      Curve points[2];
      for (int a = 0; a < 2; ++a) {
        points[a].label = std::string("true ") + axis_name[a] + " widths";
      }
      for (const nlohmann::json& e : t["exposures"]) {
        if (!e.is_object() || !e.contains("focus_position_um") || !e.contains("defocus_px") ||
            !e["focus_position_um"].is_number() || !e["defocus_px"].is_number()) {
          continue;
        }
        const double zk = e["focus_position_um"].get<double>();
        const double dk = e["defocus_px"].get<double>();
        for (int a = 0; a < 2; ++a) {
          const nlohmann::json& ccd = params[a == 0 ? "ccd_sigma_x_px" : "ccd_sigma_y_px"];
          if (!ccd.is_number()) continue;
          const double w = std::hypot(dk, ccd.get<double>());
          if (std::isfinite(zk) && std::isfinite(w)) {
            points[a].x.push_back(zk);
            points[a].y.push_back(w);
          }
        }
      }
      for (int a = 0; a < 2; ++a) {
        if (!points[a].x.empty()) {
          in.truth.points.push_back(std::move(points[a]));
          *truth_drawn = true;
        }
      }
    }
  }
  return WriteXyPlot(dir, stem, in, result, error, options);
}

}  // namespace ccdpsf::fit
