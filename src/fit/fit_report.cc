#include "ccdpsf/fit/fit_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <future>
#include <optional>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/chi_square.h"
#include "ccdpsf/column_units.h"
#include "ccdpsf/fit/fit_quality.h"
#include "ccdpsf/fit/focus_plot.h"
#include "ccdpsf/fit/intensity_plot.h"
#include "ccdpsf/fit/prior_report.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/staged_output.h"
#include "internal/text.h"

namespace ccdpsf::fit {
namespace {

using nlohmann::json;

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

json SummaryJson(const Summary& s) {
  return {{"map", Num(s.map)},       {"laplace_sd", Num(s.laplace_sd)},
          {"sandwich_sd", Num(s.sandwich_sd)},
          {"median", Num(s.median)}, {"lo68", Num(s.lo68)},
          {"hi68", Num(s.hi68)},     {"lo997", Num(s.lo997)},
          {"hi997", Num(s.hi997)}};
}

// The intensity check's block (intensity_points.h): what the joint posterior predicts for
// each exposure's widths at its signal, what the exposure alone measures, and the intrinsic
// (zero-signal) widths.
json IntensityWidthsJson(const IntensityPoints& ip) {
  const char* names[4] = {"ccd_sigma_x_px", "ccd_sigma_y_px", "total_sigma_x_px",
                          "total_sigma_y_px"};
  auto predicted = [](const Summary& s) {
    return json{{"map", Num(s.map)},
                {"median", Num(s.median)},
                {"lo68", Num(s.lo68)},
                {"hi68", Num(s.hi68)}};
  };
  json intrinsic = json::object();
  for (int i = 0; i < 4; ++i) intrinsic[names[i]] = SummaryJson(WidthAt(ip.intrinsic, i));
  json exposures = json::array();
  for (const IntensityPoint& p : ip.points) {
    json e = {{"exposure", p.exposure}, {"peak_e", Num(p.peak_e)}};
    json pr = json::object(), me = json::object();
    for (int i = 0; i < 4; ++i) {
      pr[names[i]] = predicted(WidthAt(p.predicted, i));
      const Summary& m = WidthAt(p.measured, i);
      me[names[i]] = {{"map", Num(m.map)}, {"laplace_sd", Num(m.laplace_sd)}};
    }
    if (ip.effect == "boundary_shift") {
      pr["delta_var_x_px2"] = predicted(p.delta_var_x_px2);
      pr["delta_var_y_px2"] = predicted(p.delta_var_y_px2);
    }
    e["predicted"] = pr;
    e["measured"] = p.failure.empty() ? me : json{{"failure", p.failure}};
    exposures.push_back(e);
  }
  return {{"effect", ip.effect},
          {"compare", ip.ccd_identified ? "ccd" : "total"},
          {"intrinsic", intrinsic},
          {"exposures", exposures}};
}

// MAP/Laplace against MCMC: centres, widths (Laplace sd vs half the 68 % interval) and their
// ratio; the shift of the centre in units of the MCMC width.
json ComparisonRow(const std::string& name, const Summary& s) {
  const double width = 0.5 * (s.hi68 - s.lo68);
  return {{"name", name},
          {"map", Num(s.map)},
          {"median", Num(s.median)},
          {"shift_in_mcmc_sd", Num((s.map - s.median) / width)},
          {"laplace_sd", Num(s.laplace_sd)},
          {"mcmc_half_width68", Num(width)},
          {"width_ratio_laplace_over_mcmc", Num(s.laplace_sd / width)}};
}

std::string Fmt(double v, int digits = 5) {
  if (!std::isfinite(v)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*g", digits, v);
  return buf;
}

// How well one focus identifies the CCD widths under a pillbox defocus (docs/trust.md): a
// disc's edge is not Gaussian, so the profile separates it from the CCD kernel when the disc
// is large enough. Judged on the wider of the two widths' MCMC 68 % half-widths relative to
// their medians: identified up to 10 %, weakly up to 50 %, else not. None for other fits
// (a Gaussian defocus at one focus is a null direction, named as such; a through-focus
// series identifies the widths through the stage).
struct WidthIdentification {
  std::string verdict;         // "identified", "weakly identified" or "not identified"
  double relative_half_width;  // the wider of the two
  std::string sentence;        // for report.md
};
std::optional<WidthIdentification> PillboxWidthIdentification(const FitModel& model,
                                                              const FitResult& r) {
  if (model.options().model.defocus != model::DefocusKind::kPillbox || model.through_focus() ||
      !r.have_mcmc) {
    return std::nullopt;
  }
  double worst = 0.0;
  std::string widths;
  for (const char* name : {"ccd_sigma_x_px", "ccd_sigma_y_px"}) {
    const auto at = std::find(r.names.begin(), r.names.end(), name);
    if (at == r.names.end()) return std::nullopt;
    const Summary& s = r.parameters[at - r.names.begin()];
    const double relative = 0.5 * (s.hi68 - s.lo68) / std::fabs(s.median);
    worst = std::max(worst, std::isfinite(relative) ? relative : INFINITY);
    widths += std::string(widths.empty() ? "" : ", ") + name + " " + Fmt(s.median, 3) + " +- " +
              Fmt(0.5 * (s.hi68 - s.lo68), 2) + " px";
  }
  WidthIdentification out;
  out.relative_half_width = worst;
  out.verdict = worst <= 0.1 ? "identified" : worst <= 0.5 ? "weakly identified" : "not identified";
  out.sentence = "At one focus with a pillbox defocus the CCD widths are **" + out.verdict +
                 "** by these data (" + widths + ", 68 %; the wider is " + Fmt(100.0 * worst, 2) +
                 " % of its value; identified up to 10 %, weakly up to 50 %). The disc's edge "
                 "is what separates the defocus from the CCD kernel, so this holds only if the "
                 "projector's defocus is a disc; if it is closer to a Gaussian, the split is the "
                 "model's assumption.";
  return out;
}

}  // namespace

json FitJson(const ExposuresFit& fit) {
  const FitModel& model = *fit.model;
  const FitResult& r = fit.result;
  const std::vector<CalibrationReport>& calibration = fit.calibration;
  json j;
  j["quality"] = fit.quality.ToJson();
  j["model"] = {{"sampling", model::ToString(model.options().model.sampling)},
                {"defocus", model::ToString(model.options().model.defocus)},
                {"pixel_response_width", model.options().model.pixel_response_width},
                {"likelihood", ToString(model.options().likelihood)},
                {"joint", model.num_exposures() > 1},
                {"through_focus", model.through_focus()},
                {"flux", ToString(model.options().flux)}};
  // The fitted effects in catalogue order (their parameters are in "parameters").
  json effects = json::array();
  for (model::EffectKind kind : model::AllEffectKinds()) {
    if (model.EffectIndex(kind) >= 0) effects.push_back(model::ToString(kind));
  }
  j["model"]["effects"] = effects;
  j["notes"] = fit.notes;
  json outliers = json::array();
  for (const OutlierMask& m : fit.outliers) {
    outliers.push_back({{"exposure", m.exposure},
                        {"pixel_px", {m.x_px, m.y_px}},
                        {"z", m.z},
                        {"core", m.core}});
  }
  j["masked_outliers"] = outliers;
  json params = json::object();
  json priors = json::object();
  for (int i = 0; i < model.dim(); ++i) {
    params[r.names[i]] = SummaryJson(r.parameters[i]);
    priors[r.names[i]] = {{"kind", "flat"}, {"lower", model.lower()[i]},
                          {"upper", model.upper()[i]}};
  }
  // A Gaussian prior's parameters: the normal truncated to their flat ranges.
  const GaussianPriorTerm& gaussian = model.gaussian_prior();
  for (int a = 0; a < gaussian.size(); ++a) {
    const int i = gaussian.indices()[a];
    json& p = priors[r.names[i]];
    p["kind"] = "truncated_gaussian";
    p["mean"] = gaussian.prior().mean[a];
    p["sd"] = std::sqrt(gaussian.prior().covariance[static_cast<size_t>(a) * gaussian.size() + a]);
  }
  j["parameters"] = params;
  j["priors"] = priors;
  if (gaussian.active()) {
    j["gaussian_prior"] = GaussianPriorJson(model);
    j["boundary_shift_vs_flats"] = PriorComparisonJson(model, r);
  }
  json derived = json::object();
  for (const auto& [name, s] : r.derived) derived[name] = SummaryJson(s);
  j["derived"] = derived;
  json nulls = json::array();
  for (const UnconstrainedDirection& d : r.laplace.unconstrained) {
    json dir = json::object();
    for (int i = 0; i < model.dim(); ++i) {
      if (std::fabs(d.direction[i]) > 1e-9) dir[r.names[i]] = d.direction[i];
    }
    nulls.push_back({{"direction", dir},
                     {"likelihood_sd_over_prior_width", Num(d.sd_fraction_of_prior)},
                     {"description", d.description}});
  }
  json at_bound = json::array();
  for (int i : r.laplace.at_bound) {
    at_bound.push_back({{"name", r.names[i]},
                        {"map", r.map.theta[i]},
                        {"lower", model.lower()[i]},
                        {"upper", model.upper()[i]}});
  }
  j["identifiability"] = {{"null_directions", nulls}, {"at_bound", at_bound}};
  if (const auto widths = PillboxWidthIdentification(model, r)) {
    j["identifiability"]["ccd_widths"] = {{"verdict", widths->verdict},
                                          {"relative_half_width", Num(widths->relative_half_width)},
                                          {"basis", "pillbox defocus at one focus"}};
  }
  // The Laplace covariance of the parameters the data constrain (theta units, the names'
  // units; the others lie along identifiability.null_directions and have no entry).
  {
    json names = json::array();
    std::vector<int> kept;
    for (int i = 0; i < model.dim(); ++i) {
      if (r.laplace.constrained[i]) kept.push_back(i);
    }
    for (int a : kept) names.push_back(r.names[a]);
    // The mean of the two triangles: the inverses are symmetric only to rounding.
    auto matrix_of = [&](const std::vector<double>& c) {
      const int n = model.dim();
      const bool have = c.size() == static_cast<size_t>(n) * n;
      json matrix = json::array();
      for (int a : kept) {
        json row = json::array();
        for (int b : kept) row.push_back(have ? Num(0.5 * (c[a * n + b] + c[b * n + a])) : json(nullptr));
        matrix.push_back(row);
      }
      return matrix;
    };
    // Which intervals the file gives, and what they assume (docs/trust.md, Honest uncertainty
    // under misfit).
    j["intervals"] = {
        {"from", r.have_mcmc ? "mcmc" : "laplace"},
        {"assume_model", true},
        {"model_rejected_by_chi2",
         r.map.dof >= 1 && std::isfinite(r.map.chi2) &&
             ChiSquareUpperTail(r.map.chi2, r.map.dof) < FitQualityOptions().chi2_tail_p},
        {"robust_sd", "sandwich_sd"}};
    j["covariance"] = {{"names", names},
                       {"matrix", matrix_of(r.laplace.covariance)},
                       {"sandwich", matrix_of(r.sandwich_covariance)}};
  }
  if (r.have_mcmc) {
    const SamplerResult& c = r.chain;
    json tau = json::object(), ess = json::object();
    for (int i = 0; i < model.dim(); ++i) {
      tau[r.names[i]] = Num(c.tau[i]);
      ess[r.names[i]] = Num(c.ess[i]);
    }
    j["mcmc"] = {{"walkers", c.num_walkers},
                 {"steps", c.num_steps},
                 {"burn_in", c.burn_in},
                 {"acceptance_fraction", Num(c.mean_acceptance)},
                 {"tau", tau},
                 {"ess", ess},
                 {"converged", c.converged},
                 {"stop_reason", c.stop_reason},
                 {"threads", c.num_threads_used},
                 {"seconds", c.seconds},
                 // Joint fits: acceptance of the positions' conditional moves (null if none).
                 {"position_acceptance", Num(c.conditional_acceptance)},
                 // The Laplace-informed independence move: its acceptance (null when it was
                 // off) and how many it proposed; acceptance_fraction counts stretch moves.
                 {"laplace_move_acceptance", Num(c.independence_acceptance)},
                 {"laplace_moves", c.independence_proposed}};
  } else {
    j["mcmc"] = nullptr;
  }
  j["fit"] = {{"chi2", r.map.chi2},
              {"dof", r.map.dof},
              {"chi2_per_dof", r.map.dof > 0 ? json(r.map.chi2 / r.map.dof) : json(nullptr)},
              {"loglike", r.map.log_likelihood},
              {"pixels", r.map.num_pixels},
              {"starts", r.map.num_starts},
              {"usable_starts", r.map.num_usable_starts},
              {"map_seconds", r.map.seconds},
              {"seconds", r.seconds}};
  // The Gaussian prior's log density at the MAP (loglike stays the likelihood's).
  if (gaussian.active()) j["fit"]["log_prior"] = r.map.log_prior;
  json comparison = json::array();
  for (int i = 0; i < model.dim(); ++i) comparison.push_back(ComparisonRow(r.names[i], r.parameters[i]));
  for (const auto& [name, s] : r.derived) comparison.push_back(ComparisonRow(name, s));
  j["map_vs_mcmc"] = comparison;
  json exposures = json::array();
  for (int k = 0; k < model.num_exposures(); ++k) {
    const Stamp& s = model.stamps()[k];
    json e = {{"index", k},
              {"file", s.info.source},
              {"stamp_origin_px", {s.origin_x, s.origin_y}},
              {"stamp_size_px", {s.nx(), s.ny()}},
              {"gain_e_per_adu", s.gain_e_per_adu},
              {"read_noise_e", s.read_noise_e},
              {"bias_adu", s.bias_adu},
              {"wavelength_nm", Num(s.info.wavelength_nm)},
              {"exptime_s", Num(s.info.exptime_s)},
              {"pixel_um", Num(s.info.pixel_um)},
              {"focus_position_um", Num(s.info.focus_position_um)},
              {"masked_pixels", s.nx() * s.ny() - s.NumValid()},
              {"censored_pixels", s.NumCensored()}};
    if (model.RatioIndex(k) >= 0 || model.FixedFluxScale(k) != 1.0) {
      e["flux_scale"] = model.FluxScale(r.map.theta.data(), k);
    }
    // Through-focus fits: this exposure's defocus at the MAP, rate |z_k - z0| [px].
    if (model.through_focus()) e["map_defocus_sigma_px"] = model.DefocusFor(r.map.theta.data(), k);
    // The exposure fitted alone (focus_points.h): its total widths, free of the focus law.
    for (const FocusPoint& p : fit.focus_points) {
      if (p.exposure != static_cast<int>(k)) continue;
      if (!p.failure.empty()) {
        e["alone"] = {{"failure", p.failure}};
      } else {
        e["alone"] = {{"total_sigma_x_px",
                       {{"map", Num(p.total_sigma_x_px.map)},
                        {"laplace_sd", Num(p.total_sigma_x_px.laplace_sd)}}},
                      {"total_sigma_y_px",
                       {{"map", Num(p.total_sigma_y_px.map)},
                        {"laplace_sd", Num(p.total_sigma_y_px.laplace_sd)}}}};
      }
    }
    if (k < static_cast<int>(calibration.size())) {
      const CalibrationReport& c = calibration[k];
      e["calibration"] = CalibrationReportJson(c);
    }
    exposures.push_back(e);
  }
  j["exposures"] = exposures;
  if (!fit.intensity_points.effect.empty()) {
    j["intensity_widths"] = IntensityWidthsJson(fit.intensity_points);
  }
  return j;
}

bool WriteFitReport(const std::string& out_dir, const ExposuresFit& fit, const json& run_record,
                    std::vector<std::string>* warnings, std::string* error,
                    const FitReportOptions& options) {
  const std::string extension = std::string(".") + PlotFormatName(options.plot.format);
  const FitModel& model = *fit.model;
  const FitResult& r = fit.result;
  StagedOutput out;
  if (!out.Begin(out_dir, error)) return false;
  const int dim = model.dim();

  // residuals.fits and the residual maps.
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  std::vector<FitsImageHdu> hdus;
  std::vector<StampPanels> panels;
  std::vector<double> m;
  for (int k = 0; k < model.num_exposures(); ++k) {
    const Stamp& s = model.stamps()[k];
    ev->ModelImage(r.map.theta.data(), k, &m, nullptr);
    const PixelNoise noise = StampNoise(s);
    PixelValue v;
    StampPanels p;
    p.title = "exposure " + std::to_string(k) + ": " + s.info.source;
    p.data = Image(s.nx(), s.ny());
    p.model = Image(s.nx(), s.ny());
    p.residual = Image(s.nx(), s.ny());
    p.normalised = Image(s.nx(), s.ny());
    p.origin_x = s.origin_x;
    p.origin_y = s.origin_y;
    // The asinh stretch is linear within about the noise of an empty pixel [e-].
    p.asinh_softening = std::sqrt(noise.var0);
    for (size_t q = 0; q < m.size(); ++q) {
      const bool ok = s.valid[q];
      p.data.data[q] = ok ? s.electrons.data[q] : NAN;
      p.model.data[q] = m[q];
      p.residual.data[q] = ok ? s.electrons.data[q] - m[q] : NAN;
      if (ok) {
        // Censored pixels: the signed square root of their deviance (pixel_likelihood.h).
        EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, s.electrons.data[q], s.CensorAt(q),
                                  m[q], model.PedestalAt(r.map.theta.data()), noise, false, &v);
        p.normalised.data[q] = v.normalised;
      } else {
        p.normalised.data[q] = NAN;
      }
    }
    const std::string kk = std::to_string(k);
    FitsHeader h = {{"EXPOSURE", static_cast<long long>(k), "exposure index"},
                    {"SOURCE", internal::PercentEncoded(s.info.source),
                     "input file (bytes outside ASCII as %XX)"},
                    {"LTV1", static_cast<double>(-s.origin_x), "stamp to frame: x = i - LTV1"},
                    {"LTV2", static_cast<double>(-s.origin_y), "stamp to frame: y = j - LTV2"}};
    hdus.push_back({"DATA_" + kk, p.data, h});
    hdus.back().header.push_back({"BUNIT", std::string("electron"), "bias-subtracted data"});
    hdus.push_back({"MODEL_" + kk, p.model, h});
    hdus.back().header.push_back({"BUNIT", std::string("electron"), "MAP model"});
    hdus.push_back({"RESID_" + kk, p.residual, h});
    hdus.back().header.push_back({"BUNIT", std::string("electron"), "data - model"});
    hdus.push_back({"NRESID_" + kk, p.normalised, h});
    hdus.back().header.push_back({"BUNIT", std::string(""), "(data - model) / sigma"});
    panels.push_back(std::move(p));
  }
  FitsHeader primary = {{"ORIGIN", std::string("ccdpsf"), "software"},
                        {"CHI2", r.map.chi2, "sum of squared normalised residuals"},
                        {"DOF", static_cast<long long>(r.map.dof), "pixels - parameters"}};
  if (!WriteFitsImagesF64(out.Path("residuals.fits"), primary, hdus, error)) return false;
  // gnuplot draws the residual maps on their own thread while the chain is written and the
  // corner drawn (each writes its own files; RunSubprocess may be called from several
  // threads). On an early return below, the future's destructor waits for it.
  PlotResult plot;
  std::string residuals_error;
  const size_t residuals_warning_at = warnings->size();
  std::future<bool> residuals_done = std::async(std::launch::async, [&] {
    return WriteResidualMaps(out.staging_dir(), "residuals", panels, &plot, &residuals_error,
                             options.plot);
  });
  std::vector<std::string> truth_names;  // the parameters whose true value the corner shows

  // chain.fits and the corner plot.
  if (r.have_mcmc) {
    const SamplerResult& c = r.chain;
    // The corner plot shows the shared parameters (best_focus_um included in a through-focus
    // fit) and the first exposure's position: in a joint fit of many exposures a panel for
    // every pair of positions would bury the PSF.
    std::vector<int> picked = model.SharedIndices();
    picked.push_back(FitModel::XIndex(0));
    picked.push_back(FitModel::YIndex(0));
    const int shown = static_cast<int>(picked.size());
    CornerPlotInput corner;
    for (int i : picked) {
      corner.names.push_back(r.names[i]);
      corner.map.push_back(r.map.theta[i]);
    }
    corner.laplace_covariance.assign(static_cast<size_t>(shown) * shown, NAN);
    for (int a = 0; a < shown; ++a) {
      for (int b = 0; b < shown; ++b) {
        const int pa = picked[a], pb = picked[b];
        if (r.laplace.constrained[pa] && r.laplace.constrained[pb]) {
          corner.laplace_covariance[a * shown + b] = r.laplace.covariance[pa * dim + pb];
        }
      }
    }
    // Every post-burn-in state: the quantiles drawn on the histograms are then those of
    // fit.json (the plot thins its scatter panels itself).
    const size_t kept = static_cast<size_t>(c.num_steps - c.burn_in) * c.num_walkers;
    for (size_t t = 0; t < kept; ++t) {
      const size_t s = static_cast<size_t>(c.burn_in) * c.num_walkers + t;
      for (int i : picked) corner.samples.push_back(c.chain[s * dim + i]);
    }
    corner.num_samples = static_cast<int>(kept);
    corner.title = "posterior (MCMC), MAP and Laplace 68/95 % ellipses";
    if (options.truth) {
      std::vector<std::string> sources;
      for (const Stamp& s : model.stamps()) sources.push_back(s.info.source);
      const std::vector<double> truth = FitParameterTruths(
          options.truth->document, r.names, sources, model.options().flux == FluxMode::kShared);
      bool any = false;
      for (int i : picked) {
        corner.truth.push_back(truth[i]);
        if (std::isfinite(truth[i])) {
          any = true;
          truth_names.push_back(r.names[i]);
        }
      }
      if (!any) corner.truth.clear();
    }
    // gnuplot draws the corner (the slowest plot) on its own thread while chain.fits is
    // written; RunSubprocess may be called from several threads, and the two write different
    // files.
    PlotResult corner_plot;
    std::string corner_error;
    std::future<bool> corner_done = std::async(std::launch::async, [&] {
      return WriteCornerPlot(out.staging_dir(), "corner", corner, &corner_plot, &corner_error,
                             options.plot);
    });
    const size_t states = static_cast<size_t>(c.num_steps) * c.num_walkers;
    // Every state of the chain (burn-in included, flagged by BURNIN), with the derived
    // quantities of each draw beside the parameters: FWHM, e, R^2 ... need no propagation by
    // the reader. peak_e needs a render per draw and is left out (fit.json summarises it).
    const std::vector<std::string>& derived_names = DerivedNames();
    std::vector<size_t> derived_kept;
    for (size_t j = 0; j < derived_names.size(); ++j) {
      if (derived_names[j] != "peak_e") derived_kept.push_back(j);
    }
    std::vector<FitsColumn> cols = {
        {"walker", "", {}, true, {}}, {"step", "", {}, true, {}}, {"log_prob", "", {}, false, {}}};
    for (int i = 0; i < dim; ++i) {
      cols.push_back({FitsColumnName(r.names[i]), UnitOfName(r.names[i]), {}, false, {}});
    }
    for (size_t j : derived_kept) {
      cols.push_back(
          {FitsColumnName(derived_names[j]), UnitOfName(derived_names[j]), {}, false, {}});
    }
    for (auto& col : cols) col.values.reserve(states);
    for (int step = 0; step < c.num_steps; ++step) {
      for (int w = 0; w < c.num_walkers; ++w) {
        const size_t s = static_cast<size_t>(step) * c.num_walkers + w;
        cols[0].values.push_back(w);
        cols[1].values.push_back(step);
        cols[2].values.push_back(c.log_prob[s]);
        const double* theta = &c.chain[s * dim];
        for (int i = 0; i < dim; ++i) cols[3 + i].values.push_back(theta[i]);
        const std::vector<double> d = DerivedAt(model, theta);
        for (size_t k = 0; k < derived_kept.size(); ++k) {
          cols[3 + dim + k].values.push_back(d[derived_kept[k]]);
        }
      }
    }
    // In the table's own header, where astropy's Table.read and TOPCAT look; also in the
    // primary header for readers that look there.
    FitsHeader ch = {
        {"BURNIN", static_cast<long long>(c.burn_in), "steps to discard"},
        {"WALKERS", static_cast<long long>(c.num_walkers), "ensemble size"},
        {"NSTEPS", static_cast<long long>(c.num_steps), "steps per walker"},
        {"NPARAM", static_cast<long long>(dim), "fitted parameters: the columns after log_prob"},
        {"NDERIVED", static_cast<long long>(derived_kept.size()),
         "derived quantities: the columns after them"},
        {"CONVERGD", c.converged, "sampler convergence criteria met"}};
    const bool chain_written = WriteFitsTable(out.Path("chain.fits"), ch, "CHAIN", cols, ch, error);
    if (!corner_done.get()) {
      if (chain_written) *error = corner_error;
      return false;
    }
    if (!chain_written) return false;
    if (!corner_plot.image_written && options.plot.draw) {
      warnings->push_back("corner" + extension + " not made: " + corner_plot.message);
    }
  }

  if (!residuals_done.get()) {
    *error = residuals_error;
    return false;
  }
  if (!plot.image_written && options.plot.draw) {
    warnings->insert(warnings->begin() + residuals_warning_at,
                     "residuals" + extension + " not made: " + plot.message);
  }

  // report.md: the numbers people come for, and the plots.
  std::ostringstream md;
  md << "# ccdpsf fit\n\n";
  md << "**Verdict: " << fit.quality.Verdict() << "**";
  {
    const json q = fit.quality.ToJson();
    if (q["reasons"].empty()) {
      md << " (nothing found that would make these numbers untrustworthy)\n\n";
    } else {
      md << "\n\n";
      for (const json& reason : q["reasons"]) {
        md << "- " << reason["severity"].get<std::string>() << ": "
           << reason["message"].get<std::string>() << "\n";
      }
      md << "\n";
    }
    if (!q["notes"].empty()) {
      md << "Notes:\n\n";
      for (const json& note : q["notes"]) md << "- " << note["message"].get<std::string>() << "\n";
      md << "\n";
    }
  }
  for (const std::string& note : fit.notes) md << "Choice made from the data: " << note << ".\n\n";
  md << "Model: " << model::ToString(model.options().model.sampling) << " sampling, "
     << model::ToString(model.options().model.defocus) << " defocus, "
     << ToString(model.options().likelihood) << " likelihood; " << model.num_exposures()
     << (model.num_exposures() > 1 ? " exposures (joint fit)" : " exposure")
     << (model.through_focus()
             ? "; through-focus series: defocus sigma = defocus_rate_px_per_um x |FOCUSPOS - "
               "best_focus_um|, CCD kernel fixed (total widths are those at best focus)"
             : "")
     << ".\n\n";
  md << "chi2 / dof = " << Fmt(r.map.chi2) << " / " << r.map.dof << " = "
     << Fmt(r.map.chi2 / std::max(1, r.map.dof), 4) << "; MAP from " << r.map.num_usable_starts
     << " of " << r.map.num_starts << " starts in " << Fmt(r.map.seconds, 3) << " s.\n\n";
  if (r.have_mcmc) {
    md << "MCMC: " << r.chain.num_walkers << " walkers x " << r.chain.num_steps
       << " steps (burn-in " << r.chain.burn_in << "), acceptance "
       << Fmt(r.chain.mean_acceptance, 3)
       << (r.chain.independence_proposed > 0
               ? " (stretch), " + Fmt(r.chain.independence_acceptance, 3) + " (Laplace move)"
               : std::string())
       << ", " << (r.chain.converged ? "converged" : "NOT converged") << ": " << r.chain.stop_reason
       << ".\n\n";
  }
  md << PriorComparisonMarkdown(model, r);
  if (!r.laplace.unconstrained.empty()) {
    md << "## Not constrained by the data\n\n";
    for (const auto& d : r.laplace.unconstrained) md << "- " << d.description << "\n";
    md << "\nLaplace widths are not given for parameters along these directions; their "
          "intervals come from the MCMC and reflect the priors.\n\n";
  }
  if (const auto widths = PillboxWidthIdentification(model, r)) {
    md << "## The CCD kernel at one focus\n\n" << widths->sentence << "\n\n";
  }
  if (!r.laplace.at_bound.empty()) {
    md << "## At a prior bound\n\n";
    for (int i : r.laplace.at_bound) md << "- " << r.names[i] << " = " << Fmt(r.map.theta[i]) << "\n";
    md << "\nThe Laplace approximation ignores the bound there.\n\n";
  }
  md << "## MAP / Laplace against MCMC\n\n"
     << "| quantity | MAP | Laplace sd | sandwich sd | MCMC median | MCMC 68 % | MCMC 99.7 % | sd "
        "ratio |\n"
     << "|---|---|---|---|---|---|---|---|\n";
  auto row = [&](const std::string& name, const Summary& s) {
    md << "| " << name << " | " << Fmt(s.map) << " | " << Fmt(s.laplace_sd, 3) << " | "
       << Fmt(s.sandwich_sd, 3) << " | " << Fmt(s.median) << " | " << Fmt(s.lo68) << " .. " << Fmt(s.hi68) << " | "
       << Fmt(s.lo997) << " .. " << Fmt(s.hi997) << " | "
       << Fmt(s.laplace_sd / (0.5 * (s.hi68 - s.lo68)), 3) << " |\n";
  };
  for (int i = 0; i < dim; ++i) row(r.names[i], r.parameters[i]);
  for (const auto& [name, s] : r.derived) row(name, s);
  md << "\nsd ratio = Laplace sd / half the MCMC 68 % interval (1 for a Gaussian posterior). "
        "sandwich sd: the misspecification-robust sd at the MAP (docs/trust.md, Honest "
        "uncertainty under misfit); the intervals assume the model, the sandwich sd does "
        "not.\n\n";
  // The through-focus plot: each exposure alone against the fitted defocus law.
  bool focus_plot = false, focus_truth = false;
  if (model.through_focus() && !fit.focus_points.empty()) {
    PlotResult focus;
    if (!WriteFocusPlot(out.staging_dir(), "focus", fit, options.truth, options.plot, &focus,
                        &focus_truth, error)) {
      return false;
    }
    focus_plot = true;
    if (!focus.image_written && options.plot.draw) {
      warnings->push_back("focus" + extension + " not made: " + focus.message);
    }
  }

  // The intensity plot and section: predicted widths against each exposure alone.
  bool intensity_plot = false;
  if (!fit.intensity_points.effect.empty()) {
    PlotResult intensity;
    std::string why;
    if (WriteIntensityPlot(out.staging_dir(), "intensity", fit.intensity_points, options.plot,
                           &intensity, &why)) {
      intensity_plot = true;
      if (!intensity.image_written && options.plot.draw) {
        warnings->push_back("intensity" + extension + " not made: " + intensity.message);
      }
    } else {
      warnings->push_back("intensity" + extension + " not made: " + why);
    }
    const IntensityPoints& ip = fit.intensity_points;
    const bool ccd = ip.ccd_identified;
    const int first = ccd ? 0 : 2;
    md << "## Widths against signal (" << ip.effect << ")\n\n"
       << "The fitted CCD widths are the intrinsic kernel, the one at zero collected signal. Each "
          "exposure's own charge widens it: "
       << (ip.effect == "boundary_shift"
               ? "predicted here as sqrt(sigma^2 + Delta var), Delta var the change of the "
                 "exposure's second central moment that the boundary shifts make (the image "
                 "drawn with and without them at the fitted parameters; docs/conventions.md, "
                 "boundary shifts)"
               : "predicted here as sigma_0 + b x the exposure's peak pixel (the paper's "
                 "empirical law)")
       << ", and measured by fitting the exposure alone without the effect (MAP +- Laplace sd). "
       << (ccd ? "CCD widths"
               : "Total widths sqrt(defocus^2 + sigma^2) (at one focus with a Gaussian defocus "
                 "only these are identified)")
       << " [px]; predicted as posterior median [68 %] ("
       << (r.have_mcmc ? "MCMC" : "no MCMC: the MAP") << ").\n\n";
    const Summary& ix = WidthAt(ip.intrinsic, first);
    const Summary& iy = WidthAt(ip.intrinsic, first + 1);
    auto centre = [](const Summary& s) { return std::isfinite(s.median) ? s.median : s.map; };
    md << "Intrinsic (zero signal): x " << Fmt(centre(ix), 4) << " [" << Fmt(ix.lo68, 4) << ", "
       << Fmt(ix.hi68, 4) << "], y " << Fmt(centre(iy), 4) << " [" << Fmt(iy.lo68, 4) << ", "
       << Fmt(iy.hi68, 4) << "] px.\n\n"
       << "| exposure | peak [e-] | predicted x | measured x | predicted y | measured y |\n"
       << "|---|---|---|---|---|---|\n";
    for (const IntensityPoint& p : ip.points) {
      md << "| " << p.exposure << " | " << Fmt(p.peak_e, 4);
      for (int a = 0; a < 2; ++a) {
        const Summary& pr = WidthAt(p.predicted, first + a);
        const Summary& me = WidthAt(p.measured, first + a);
        md << " | " << Fmt(centre(pr), 4);
        if (std::isfinite(pr.lo68)) md << " [" << Fmt(pr.lo68, 4) << ", " << Fmt(pr.hi68, 4) << "]";
        md << " | " << (p.failure.empty() ? Fmt(me.map, 4) + " +- " + Fmt(me.laplace_sd, 2)
                                          : std::string("failed"));
      }
      md << " |\n";
    }
    md << "\n";
  }

  md << "## Plots\n\n";
  if (!options.plot.draw) {
    md << "The pictures were not drawn (" << options.plot_reason
       << "). Their data and gnuplot scripts are in this folder: `gnuplot residuals.gp`"
       << (r.have_mcmc ? ", `gnuplot corner.gp`" : "") << (focus_plot ? ", `gnuplot focus.gp`" : "")
       << (intensity_plot ? ", `gnuplot intensity.gp`" : "")
       << " there make them"
       << (options.plot.format == PlotFormat::kPng
               ? ""
               : std::string(" (add `-e \"plot_format='") + PlotFormatName(options.plot.format) +
                     "'\"` for " + PlotFormatName(options.plot.format) + ")")
       << ".\n\n";
  }
  // A picture's link, or where it is not drawn the file its script would make (a link to a
  // file that does not exist shows as broken in every Markdown viewer).
  const auto picture = [&](const std::string& stem) {
    const std::string file = stem + extension;
    return options.plot.draw ? "![" + stem + "](" + file + ")"
                             : "(not drawn: `gnuplot " + stem + ".gp` makes " + file + ")";
  };
  md << "Residual maps: data and model on an asinh stretch (linear within about the noise of an "
        "empty pixel, logarithmic above, so the wings show), residuals and normalised "
        "residuals on a diverging scale with white at zero.\n\n";
  md << picture("residuals") << "\n\n";
  if (r.have_mcmc) {
    md << "Corner plot: histograms with the median and the central 68 % interval (dashed; the "
          "numbers above each column), the MAP and the Laplace approximation in red";
    if (!truth_names.empty()) md << ", true values in blue";
    md << ".\n\n" << picture("corner") << "\n\n";
  }
  if (focus_plot) {
    md << "Through focus: the total Gaussian width sqrt(defocus^2 + ccd sigma^2) [px] against "
          "the stage position, the fitted law "
       << (r.have_mcmc ? "(posterior median and 68 % band)" : "(at the MAP)")
       << " beside each exposure fitted alone (MAP +- Laplace sd; free of the law)"
       << (focus_truth ? ", true widths in black" : "") << ".\n\n" << picture("focus")
       << "\n\n";
  }
  if (intensity_plot) {
    md << "Widths against signal: the predicted width (the brightest exposure's spot with its "
          "flux scaled; "
       << (r.have_mcmc ? "posterior median and 68 % band" : "at the MAP")
       << "), each exposure fitted alone without the effect (MAP +- Laplace sd) and the "
          "intrinsic width at zero signal.\n\n"
       << picture("intensity") << "\n\n";
  }
  if (options.truth) {
    md << "Truth file: " << options.truth->path << " ("
       << (truth_names.empty() ? std::string("none of its values maps onto a plotted parameter")
                               : "true values drawn for " +
                                     [&] {
                                       std::string list;
                                       for (const std::string& n : truth_names) {
                                         list += (list.empty() ? "" : ", ") + n;
                                       }
                                       return list;
                                     }())
       << ").\n\n";
  }
  if (!warnings->empty()) {
    md << "## Warnings\n\n";
    for (const auto& w : *warnings) md << "- " << w << "\n";
  }
  if (!WriteTextFileAtomically(out.Path("report.md"), md.str(), error)) return false;
  if (!WriteTextFileAtomically(out.Path("run.json"), run_record.dump(2) + "\n", error)) {
    return false;
  }
  const json fit_json = FitJson(fit);
  if (!WriteTextFileAtomically(out.Path("fit.json"), fit_json.dump(2) + "\n", error)) return false;
  return out.Commit({"fit.json"}, error);
}

bool ParsePictures(const std::string& text, Pictures* pictures) {
  for (const Pictures p : {Pictures::kAll, Pictures::kFlagged, Pictures::kNone}) {
    if (text == ToString(p)) {
      *pictures = p;
      return true;
    }
  }
  return false;
}

const char* ToString(Pictures pictures) {
  switch (pictures) {
    case Pictures::kAll:
      return "all";
    case Pictures::kFlagged:
      return "flagged";
    case Pictures::kNone:
      return "none";
  }
  return "?";
}

bool DrawsPictures(Pictures pictures, const Quality& quality) {
  switch (pictures) {
    case Pictures::kAll:
      return true;
    case Pictures::kFlagged:
      return quality.Worst() != Severity::kNote;
    case Pictures::kNone:
      return false;
  }
  return true;
}

}  // namespace ccdpsf::fit
