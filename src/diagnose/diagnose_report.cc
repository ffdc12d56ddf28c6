#include "ccdpsf/diagnose/diagnose_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/staged_output.h"
#include "ccdpsf/truncated_normal.h"

namespace ccdpsf::diagnose {

using nlohmann::json;

namespace {

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

std::string Fmt(double v, const char* format = "%.4g") {
  if (!std::isfinite(v)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

json WidthTrendJson(const WidthTrend& t) {
  json j = {{"measured", t.measured}};
  if (!t.measured) {
    j["note"] = t.note.empty() ? json("one intensity: not measured") : json(t.note);
    return j;
  }
  j["method"] = "each exposure fitted alone (Airy convolved with one Gaussian: the total "
                "width), widths regressed on the peak signal by weighted least squares; sd "
                "scaled by sqrt(chi2/dof) when above 1";
  j["exposures"] = json::array();
  for (const WidthPoint& w : t.points) {
    j["exposures"].push_back({{"exposure", w.exposure},
                              {"peak_e", Num(w.peak_e)},
                              {"sigma_x_px", Num(w.sigma_px[0])},
                              {"sigma_x_sd", Num(w.sd_px[0])},
                              {"sigma_y_px", Num(w.sigma_px[1])},
                              {"sigma_y_sd", Num(w.sd_px[1])}});
  }
  for (int a = 0; a < 2; ++a) {
    const WidthLine& l = t.axis[a];
    j[a == 0 ? "x" : "y"] = {{"sigma0_px", Num(l.sigma0_px)},
                             {"sigma0_sd", Num(l.sigma0_sd)},
                             {"slope_px_per_e", Num(l.slope_px_per_e)},
                             {"slope_sd", Num(l.slope_sd)},
                             {"percent_per_1e5_e", Num(l.percent_per_1e5_e)},
                             {"percent_sd", Num(l.percent_sd)},
                             {"chi2", Num(l.chi2)},
                             {"dof", l.dof}};
  }
  return j;
}

json Parameters(const std::vector<std::string>& names, const EffectFitResult& fit) {
  json out = json::object();
  for (size_t i = 0; i < names.size(); ++i) {
    const double sd = i < fit.laplace.sd.size() ? fit.laplace.sd[i] : NAN;
    const bool at_bound = std::find(fit.laplace.at_bound.begin(), fit.laplace.at_bound.end(),
                                    static_cast<int>(i)) != fit.laplace.at_bound.end();
    out[names[i]] = {{"map", Num(fit.p[i])}, {"laplace_sd", Num(sd)}, {"at_bound", at_bound}};
  }
  return out;
}

// Laplace estimate with intervals: the normal N(map, sd^2) truncated to the parameter's prior
// range [lower, upper], so that no interval leaves the range (a small ipc's "map - 3 sd" would
// be negative). lo68/hi68 are its 15.87 / 84.13 % quantiles (map -+ sd without bounds),
// lo997/hi997 its 0.135 / 99.865 % quantiles.
json Estimate(double map, double sd, bool at_bound, double lower, double upper) {
  json e = {{"map", Num(map)}, {"laplace_sd", Num(sd)}, {"at_bound", at_bound}};
  if (std::isfinite(sd) && sd > 0 && std::isfinite(map)) {
    e["lo68"] = TruncatedNormalQuantile(map, sd, lower, upper, NormalCdf(-1.0));
    e["hi68"] = TruncatedNormalQuantile(map, sd, lower, upper, NormalCdf(1.0));
    e["lo997"] = TruncatedNormalQuantile(map, sd, lower, upper, NormalCdf(-3.0));
    e["hi997"] = TruncatedNormalQuantile(map, sd, lower, upper, NormalCdf(3.0));
  }
  return e;
}

// A jitter variance's estimate as a sigma: the quantiles map through the square root exactly,
// the sd by the delta method (none at sigma = 0).
json SigmaFromVariance(const json& variance) {
  auto root = [](const json& v) { return Num(std::sqrt(std::max(v.get<double>(), 0.0))); };
  const double var = variance["map"].is_null() ? NAN : variance["map"].get<double>();
  const double var_sd =
      variance["laplace_sd"].is_null() ? NAN : variance["laplace_sd"].get<double>();
  const double s = std::sqrt(std::max(var, 0.0));
  json e = {{"map", Num(s)},
            {"laplace_sd", Num(s > 0 ? var_sd / (2 * s) : NAN)},
            {"at_bound", variance["at_bound"]}};
  for (const char* key : {"lo68", "hi68", "lo997", "hi997"}) {
    if (variance.contains(key)) e[key] = root(variance[key]);
  }
  return e;
}

// The named effects' parameters of the final model, jitter also as sigmas.
json EffectParameters(const DiagnoseResult& result) {
  json out = json::object();
  const RoundResult& last = result.rounds.back();
  const EffectFitResult& fit = last.fit;
  for (model::EffectKind kind : result.named) {
    const std::string name = model::ToString(kind);
    json e = json::object();
    for (size_t i = 0; i < last.names.size(); ++i) {
      const std::string& n = last.names[i];
      // (defocus's parameter has no "defocus." prefix; defocus_offset's must not match it.)
      const bool mine = kind == model::EffectKind::kDefocus
                            ? n == "defocus_sigma_px" || n == "defocus_radius_px"
                            : n.rfind(name + ".", 0) == 0;
      if (!mine) continue;
      const double sd = fit.laplace.sd.empty() ? NAN : fit.laplace.sd[i];
      const bool at_bound = std::find(fit.laplace.at_bound.begin(), fit.laplace.at_bound.end(),
                                      static_cast<int>(i)) != fit.laplace.at_bound.end();
      const std::string key = kind == model::EffectKind::kDefocus ? n : n.substr(name.size() + 1);
      e[key] = Estimate(fit.p[i], sd, at_bound, last.lower[i], last.upper[i]);
      if (kind == model::EffectKind::kJitter) {
        std::string sname = key;
        sname.replace(0, std::string("var_x_px2").size(),
                      key.rfind("var_x", 0) == 0 ? "sigma_x_px" : "sigma_y_px");
        e[sname] = SigmaFromVariance(e[key]);
      }
    }
    if (kind == model::EffectKind::kBrighterFatter && last.spec.defocus) {
      // With a Gaussian defocus only sigma_f^2 + sigma_ccd^2 is identified (docs/trust.md,
      // single focus), and so is the slope of the TOTAL width: d sigma_tot / dI = slope sigma_ccd /
      // sigma_tot at zero signal (sd scaled from the slope's: the split's own uncertainty is
      // not in it). Reported beside the CCD-width slopes.
      auto index = [&](const std::string& n) {
        const auto it = std::find(last.names.begin(), last.names.end(), n);
        return it == last.names.end() ? -1 : static_cast<int>(it - last.names.begin());
      };
      const int f = index("defocus_sigma_px");
      for (const char* axis : {"x", "y"}) {
        const int s = index(std::string("ccd_sigma_") + axis + "_px");
        const int b = index(std::string("brighter_fatter.slope_") + axis + "_px_per_e");
        if (f < 0 || s < 0 || b < 0) continue;
        const double ratio = fit.p[s] / std::hypot(fit.p[s], fit.p[f]);
        const double sd = fit.laplace.sd.empty() ? NAN : fit.laplace.sd[b];
        e[std::string("total_slope_") + axis + "_px_per_e"] = Estimate(
            fit.p[b] * ratio, sd * ratio, false, last.lower[b] * ratio, last.upper[b] * ratio);
      }
    }
    out[name] = e;
  }
  return out;
}

// A stack's four panels (data, model, residual, normalised residual) for WriteResidualMaps.
StampPanels StackPanels(const std::string& title, const ResidualStack& stack) {
  StampPanels p;
  p.title = title;
  p.data = stack.data;
  p.model = stack.model;
  p.residual = stack.residual;
  p.normalised = stack.normalised;
  return p;
}

json Statistics(const ResidualStatistics& st) {
  json list = json::array();
  const auto& desc = StatisticDescriptions();
  for (size_t i = 0; i < st.values.size(); ++i) {
    const NamedStatistic& s = st.values[i];
    list.push_back({{"name", s.name},
                    {"value", Num(s.value)},
                    {"tail", s.tail == Tail::kUpper ? "upper" : "two_sided"},
                    {"p_value", Num(s.p_value)},
                    {"p_method", s.p_method},
                    {"predictive_mean", Num(s.predictive_mean)},
                    {"predictive_sd", Num(s.predictive_sd)},
                    {"description", i < desc.size() ? desc[i].second : ""}});
  }
  return list;
}

// The statistic with the smallest predictive p-value (ties: the largest deviation in
// predictive sds); -1 if none has a p-value.
int FlaggingStatistic(const ResidualStatistics& st) {
  // A targeted statistic says more than chi^2: it wins ties with it.
  int best = -1;
  double chi2_p = INFINITY;
  if (const NamedStatistic* c = st.Find("chi2_per_dof"); c != nullptr && std::isfinite(c->p_value)) {
    chi2_p = c->p_value;
  }
  double best_p = INFINITY, best_dev = -INFINITY;
  for (size_t i = 0; i < st.values.size(); ++i) {
    const NamedStatistic& s = st.values[i];
    if (!std::isfinite(s.p_value) || s.name == "chi2_per_dof") continue;
    const double dev = std::isfinite(s.predictive_sd) && s.predictive_sd > 0
                           ? std::fabs(s.value - s.predictive_mean) / s.predictive_sd
                           : 0.0;
    if (s.p_value < best_p || (s.p_value == best_p && dev > best_dev)) {
      best = static_cast<int>(i);
      best_p = s.p_value;
      best_dev = dev;
    }
  }
  if (best < 0 || best_p > chi2_p) {
    for (size_t i = 0; i < st.values.size(); ++i) {
      if (st.values[i].name == "chi2_per_dof" && std::isfinite(chi2_p)) return static_cast<int>(i);
    }
  }
  return best;
}

}  // namespace

// For every catalogue effect not named: its realistic strength, whether it was tested in the
// last round of testing (and why not), and the weakest strength that would have been
// detected: simulated for these data (--thresholds) or, failing that, the reference value for
// paper-like data (ReferenceThresholds).
json NotNamed(const fit::FitModel& base, const DiagnoseResult& result) {
  const RoundResult* tested = nullptr;
  for (const RoundResult& r : result.rounds) {
    if (r.tested) tested = &r;
  }
  const model::Sampling sampling = base.options().model.sampling;
  json out = json::array();
  for (model::EffectKind kind : model::AllEffectKinds()) {
    if (std::find(result.named.begin(), result.named.end(), kind) != result.named.end()) continue;
    const model::EffectInfo& info = model::DescribeEffect(kind);
    json e = {{"name", info.name},
              {"parameter", info.name + "." + info.parameters[0].name},
              {"realistic", info.parameters[0].default_value}};
    std::string status = "not_a_candidate", reason;
    if (tested != nullptr) {
      for (const CandidateResult& c : tested->candidates) {
        if (c.alternative || c.kind != kind) continue;
        status = ToString(c.status);
        reason = c.reason;
      }
    }
    e["status"] = status;
    e["reason"] = reason.empty() ? json(nullptr) : json(reason);
    e["threshold"] = nullptr;
    e["threshold_source"] = nullptr;
    for (const DetectionThreshold& t : result.thresholds) {
      if (t.kind != kind) continue;
      e["threshold"] = Num(t.threshold);
      e["threshold_source"] = "simulated for these data";
      e["weakest_tried"] = !t.strengths.empty() && t.threshold == t.strengths.front();
    }
    if (e["threshold_source"].is_null()) {
      for (const ReferenceThreshold& r : ReferenceThresholds()) {
        if (r.kind != kind || r.sampling != sampling ||
            r.baseline_defocus != result.rounds.front().spec.defocus) {
          continue;
        }
        e["threshold"] = Num(r.threshold);
        e["threshold_source"] = "reference: " + r.conditions;
        e["weakest_tried"] = r.weakest_tried;
      }
    }
    out.push_back(e);
  }
  return out;
}

json DiagnoseJson(const fit::FitModel& base, const DiagnoseResult& result,
                  const DiagnoseOptions& options) {
  json j;
  j["quality"] = result.quality.ToJson();
  // Only what explains the data is named; what helped without explaining is partial.
  j["named_effects"] = ExplainingNames(result);
  j["explained"] = result.explained;
  j["verdict"] = DiagnosisVerdict(result);
  j["partial"] = json::array();
  j["ambiguous"] = json::array();
  j["attributions"] = json::array();
  for (const Attribution& a : result.attributions) {
    json ja = {{"name", a.name}, {"round", a.round}, {"status", ToString(a.status)},
               {"reason", a.reason.empty() ? json(nullptr) : json(a.reason)}};
    if (!a.parameters.empty()) {
      json ps = json::object();
      for (const ParameterEstimate& p : a.parameters) {
        ps[p.name] = {{"map", Num(p.map)}, {"sd", Num(p.sd)}, {"at_bound", p.at_bound}};
      }
      ja["parameters"] = ps;
    }
    if (a.status == Attribution::Status::kPartial) {
      j["partial"].push_back({{"name", a.name}, {"reason", a.reason}});
    }
    if (a.status == Attribution::Status::kAmbiguous) {
      ja["rivals"] = a.rivals;
      ja["separate_by"] = a.separate_by;
      j["ambiguous"].push_back(
          {{"name", a.name}, {"rivals", a.rivals}, {"separate_by", a.separate_by}});
    }
    j["attributions"].push_back(ja);
  }
  j["unexplained"] = result.unexplained;
  j["width_trend"] = WidthTrendJson(result.width_trend);
  j["round_limit_reached"] = result.round_limit_reached;
  j["flux_mode"] = ToString(result.flux);
  j["multi_intensity"] = result.multi_intensity;
  j["peak_e"] = result.peak_e;
  j["jitter_reference_exposure"] = result.jitter_reference;
  j["exposures"] = json::array();
  for (const Stamp& s : base.stamps()) j["exposures"].push_back(s.info.source);
  j["decision"] = {{"alpha", options.alpha},
                   {"rule", "p < alpha / tested (Bonferroni) and delta BIC < 0 (a non-nested "
                            "alternative: delta BIC < -10); the lowest delta BIC is adopted, "
                            "and named if it explains what it was chosen for"},
                   {"flagged_p", kFlaggedP},
                   {"within_noise_p", kWithinNoiseP},
                   {"ambiguous_delta_bic", kAmbiguousDeltaBic},
                   {"max_rounds", options.max_rounds},
                   {"predictive_simulations", options.predictive.num_simulations},
                   {"predictive_refit", options.predictive.refit}};
  j["rounds"] = json::array();
  for (const RoundResult& r : result.rounds) {
    json jr;
    json effects = json::array();
    for (model::EffectKind k : r.spec.effects) effects.push_back(model::ToString(k));
    jr["model"] = {{"description", r.model_description},
                   {"defocus", r.spec.defocus},
                   {"effects", effects},
                   {"flux", ToString(r.spec.flux)}};
    jr["fit"] = {{"chi2", r.fit.chi2},
                 {"dof", r.fit.dof},
                 {"chi2_per_dof", r.statistics.chi2_per_dof},
                 {"chi2_per_dof_expected_sd", r.statistics.chi2_per_dof_sd},
                 {"loglike", r.fit.log_likelihood},
                 {"seconds", r.fit.seconds},
                 {"parameters", Parameters(r.names, r.fit)}};
    jr["chi2_per_dof"] = r.statistics.chi2_per_dof;
    jr["statistics"] = Statistics(r.statistics);
    jr["intensity_classes"] = json::array();
    for (const IntensityStack& c : r.statistics.by_intensity) {
      jr["intensity_classes"].push_back(
          {{"peak_min_e", c.peak_min_e}, {"peak_max_e", c.peak_max_e}, {"exposures", c.exposures}});
    }
    jr["radial_profile"] = {{"annulus_inner_px", json::array()},
                            {"mean_normalised_residual", json::array()},
                            {"count", json::array()}};
    for (size_t b = 0; b < r.statistics.radial_mean.size(); ++b) {
      jr["radial_profile"]["annulus_inner_px"].push_back(b);
      jr["radial_profile"]["mean_normalised_residual"].push_back(Num(r.statistics.radial_mean[b]));
      jr["radial_profile"]["count"].push_back(r.statistics.radial_count[b]);
    }
    jr["tested"] = r.tested;
    jr["num_tested"] = r.num_tested;
    jr["p_threshold"] = Num(r.p_threshold);
    jr["candidates"] = json::array();
    for (const CandidateResult& c : r.candidates) {
      json jc = {{"name", c.name},
                 {"kind", c.alternative ? "alternative" : "effect"},
                 {"status", ToString(c.status)}};
      if (c.status != CandidateResult::Status::kTested) {
        jc["reason"] = c.reason;
      } else {
        if (!c.reason.empty()) jc["reason"] = c.reason;  // e.g. a contradicted nonlinearity
        jc["nested"] = c.nested;
        jc["num_parameters"] = c.num_parameters;
        jc["boundary_parameters"] = c.boundary_parameters;
        jc["delta_loglike"] = Num(c.delta_log_likelihood);
        jc["lr"] = Num(c.lr);
        jc["p_value"] = Num(c.p_value);
        jc["delta_bic"] = Num(c.delta_bic);
        jc["log_bayes_factor"] = Num(c.log_bayes_factor);
        jc["significant"] = c.significant;
        jc["chi2_per_dof_with"] = Num(c.chi2_per_dof);
        json ps = json::object();
        for (const ParameterEstimate& p : c.parameters) {
          ps[p.name] = {{"map", Num(p.map)}, {"laplace_sd", Num(p.sd)}, {"at_bound", p.at_bound}};
        }
        jc["parameters"] = ps;
      }
      jr["candidates"].push_back(jc);
    }
    jr["adopted"] = r.adopted.empty() ? json(nullptr) : json(r.adopted);
    jr["rivals"] = r.rivals;
    jr["verdict"] = r.verdict;
    j["rounds"].push_back(jr);
  }
  const RoundResult& last = result.rounds.back();
  j["final_fit"] = {{"model", last.model_description},
                    {"chi2", last.fit.chi2},
                    {"dof", last.fit.dof},
                    {"chi2_per_dof", last.statistics.chi2_per_dof},
                    {"chi2_per_dof_expected_sd", last.statistics.chi2_per_dof_sd},
                    {"loglike", last.fit.log_likelihood},
                    {"parameters", Parameters(last.names, last.fit)},
                    {"effects", EffectParameters(result)}};
  json th = {{"computed", result.thresholds_computed}};
  if (!result.thresholds_computed) {
    th["note"] = "not simulated for these data (run with --thresholds); not_named gives "
                 "reference thresholds measured on paper-like five-exposure sets";
  } else {
    th["detection_rate"] = options.thresholds.detection_rate;
    th["effects"] = json::array();
    for (const DetectionThreshold& t : result.thresholds) {
      th["effects"].push_back({{"name", model::ToString(t.kind)},
                               {"parameter", t.parameter},
                               {"strengths", t.strengths},
                               {"rates", t.rates},
                               {"failed_fits", t.failed_fits},
                               {"threshold", Num(t.threshold)},
                               {"simulations_per_strength", t.num_simulations}});
    }
  }
  th["not_named"] = NotNamed(base, result);
  j["detection_thresholds"] = th;
  j["notes"] = result.notes;
  j["seconds"] = result.seconds;
  return j;
}

namespace {

std::string Markdown(const DiagnoseResult& result, const json& doc, const std::string& ext,
                     const std::vector<std::string>& plot_notes) {
  std::ostringstream md;
  md << "# ccdpsf diagnose\n\n";
  md << "**Verdict on the data: " << result.quality.Verdict() << "**\n\n";
  for (const Finding& f : result.quality.findings) {
    if (f.severity != Severity::kNote) md << "- " << ToString(f.severity) << ": " << f.message << "\n";
  }
  if (result.quality.Worst() != Severity::kNote) md << "\n";
  md << "**Diagnosis: " << doc["verdict"].get<std::string>() << "**";
  if (result.round_limit_reached) md << " (round limit reached: more may remain)";
  md << "\n\n";
  for (const Attribution& a : result.attributions) {
    md << "- " << a.name << " (round " << a.round << "): " << ToString(a.status);
    if (!a.reason.empty()) md << " - " << a.reason;
    if (!a.separate_by.empty()) md << ". To separate them: " << a.separate_by;
    md << "\n";
  }
  if (!result.unexplained.empty()) {
    md << "\nWhere the final model still misfits (p < " << kFlaggedP << "):\n\n";
    for (const std::string& u : result.unexplained) md << "- " << u << "\n";
  }
  if (!result.attributions.empty() || !result.unexplained.empty()) md << "\n";
  if (result.width_trend.measured) {
    md << "Width against signal, exposure by exposure (total Gaussian width of a fit of each "
          "exposure alone, regressed on its peak signal):\n\n"
          "| axis | width at 0 e- [px] | slope [px per e-] | per 1e5 e- peak [%] | chi2/dof |\n"
          "|---|---|---|---|---|\n";
    for (int a = 0; a < 2; ++a) {
      const WidthLine& l = result.width_trend.axis[a];
      md << "| " << (a == 0 ? "x" : "y") << " | " << Fmt(l.sigma0_px) << " +- "
         << Fmt(l.sigma0_sd, "%.2g") << " | " << Fmt(l.slope_px_per_e, "%.3g") << " +- "
         << Fmt(l.slope_sd, "%.2g") << " | " << Fmt(l.percent_per_1e5_e, "%.2f") << " +- "
         << Fmt(l.percent_sd, "%.2f") << " | " << Fmt(l.chi2 / std::max(1, l.dof), "%.2f")
         << " |\n";
    }
    md << "\n";
  }
  md << "Exposures: " << result.peak_e.size() << ", flux " << ToString(result.flux)
     << (result.multi_intensity ? " (several intensities)" : " (one intensity)")
     << ". Decision: p < alpha / tested and delta BIC < 0, alpha = "
     << doc["decision"]["alpha"].get<double>() << "; predictive p-values from "
     << doc["decision"]["predictive_simulations"].get<int>() << " simulations of each fitted model.\n\n";
  for (size_t i = 0; i < result.rounds.size(); ++i) {
    const RoundResult& r = result.rounds[i];
    md << "## Round " << i << ": " << r.model_description << "\n\n";
    md << "chi2/dof = " << Fmt(r.statistics.chi2_per_dof) << " (expected 1 +- "
       << Fmt(r.statistics.chi2_per_dof_sd, "%.3f") << ", dof " << r.statistics.dof << ")\n\n";
    md << "| statistic | value | predictive mean +- sd | p |\n|---|---|---|---|\n";
    for (const NamedStatistic& s : r.statistics.values) {
      md << "| " << s.name << " | " << Fmt(s.value) << " | " << Fmt(s.predictive_mean) << " +- "
         << Fmt(s.predictive_sd) << " | " << Fmt(s.p_value, "%.3f") << " |\n";
    }
    md << "\n";
    if (r.tested) {
      md << "| candidate | status | delta logL | p (chi-bar^2) | delta BIC | log BF | parameters |\n"
            "|---|---|---|---|---|---|---|\n";
      for (const CandidateResult& c : r.candidates) {
        md << "| " << c.name << (c.alternative ? " (alternative)" : "")
           << (c.significant ? " **(significant)**" : "")
           << " | " << ToString(c.status) << " | ";
        if (c.status == CandidateResult::Status::kTested) {
          md << Fmt(c.delta_log_likelihood, "%.2f") << " | " << Fmt(c.p_value, "%.3g") << " | "
             << Fmt(c.delta_bic, "%.1f") << " | " << Fmt(c.log_bayes_factor, "%.1f") << " | ";
          for (const ParameterEstimate& p : c.parameters) {
            md << p.name << " = " << Fmt(p.map) << " +- " << Fmt(p.sd, "%.2g")
               << (p.at_bound ? " (at bound)" : "") << "; ";
          }
          if (!c.reason.empty()) md << c.reason;
          md << " |\n";
        } else {
          md << " | | | | " << c.reason << " |\n";
        }
      }
      md << "\np threshold: " << Fmt(r.p_threshold, "%.3g") << " (" << r.num_tested
         << " tested).\n\n";
    }
    md << "**" << r.verdict << "**\n\n";
  }
  md << "## Final model\n\n" << result.rounds.back().model_description << ", chi2/dof "
     << Fmt(result.rounds.back().statistics.chi2_per_dof) << "\n\n";
  for (auto it = doc["final_fit"]["effects"].begin(); it != doc["final_fit"]["effects"].end(); ++it) {
    for (auto p = it.value().begin(); p != it.value().end(); ++p) {
      md << "- " << it.key() << "." << p.key() << " = "
         << Fmt(p.value()["map"].is_null() ? NAN : p.value()["map"].get<double>()) << " +- "
         << Fmt(p.value()["laplace_sd"].is_null() ? NAN : p.value()["laplace_sd"].get<double>(),
                "%.2g");
      if (p.value().contains("lo68")) {
        md << " (68 %: " << Fmt(p.value()["lo68"].get<double>()) << " .. "
           << Fmt(p.value()["hi68"].get<double>()) << ")";
      }
      md << "\n";
    }
  }
  md << "\n## Detection thresholds\n\n";
  md << (result.thresholds_computed
             ? "Simulated for these data (named in >= 80 % of the simulations at that strength)."
             : "Not simulated for these data (run with --thresholds); the values are reference "
               "thresholds for paper-like data, measured by bench/diagnose_benchmark.cc.")
     << " For each effect not named: its realistic strength, and the weakest strength that "
        "would have been detected.\n\n";
  for (const json& e : doc["detection_thresholds"]["not_named"]) {
    md << "- " << e["parameter"].get<std::string>() << " (realistic "
       << Fmt(e["realistic"].get<double>()) << "): ";
    if (e["threshold_source"].is_null()) {
      md << "no threshold";
    } else if (e["threshold"].is_null()) {
      md << "not detected at any strength tried (" << e["threshold_source"].get<std::string>()
         << ")";
    } else {
      md << "detected from " << (e.value("weakest_tried", false) ? "<= " : "")
         << Fmt(e["threshold"].get<double>()) << " ("
         << e["threshold_source"].get<std::string>() << ")";
    }
    if (!e["reason"].is_null()) md << "; here " << e["status"].get<std::string>() << ": "
                                   << e["reason"].get<std::string>();
    md << "\n";
  }
  if (!result.notes.empty() || !plot_notes.empty()) {
    md << "\n## Notes\n\n";
    for (const std::string& n : result.notes) md << "- " << n << "\n";
    for (const std::string& n : plot_notes) md << "- " << n << "\n";
  }
  md << "\nPlots: stacked_residuals" << ext << " (one row per round)"
     << (result.rounds.front().statistics.by_intensity.size() > 1
             ? ", stacked_residuals_by_intensity" + ext +
                   " (one row per round and intensity class: "
                   "a signal-dependent effect leaves residuals of opposite sign at low and high "
                   "intensity, which cancel in the stack of all exposures)"
             : "")
     << ", radial_profile" << ext << ", flag_<effect>" << ext << ".\n";
  return md.str();
}

}  // namespace

bool WriteDiagnoseReport(const std::string& out_dir, const fit::FitModel& base,
                         const DiagnoseResult& result, const DiagnoseOptions& options,
                         const json& run_record, std::vector<std::string>* warnings,
                         std::string* error, const PlotOptions& plot) {
  if (result.rounds.empty()) {
    *error = "no diagnosis to write";
    return false;
  }
  StagedOutput out;
  if (!out.Begin(out_dir, error)) return false;
  const std::string dir = out.staging_dir();
  std::vector<std::string> plot_notes;
  auto note_plot = [&](const PlotResult& pr) {
    if (!pr.image_written && !pr.message.empty()) {
      warnings->push_back(pr.message);
      plot_notes.push_back(pr.message);
    }
  };
  // Stacked residuals, one row per round.
  {
    std::vector<StampPanels> rows;
    for (size_t i = 0; i < result.rounds.size(); ++i) {
      rows.push_back(StackPanels("round " + std::to_string(i) + ": " +
                                     result.rounds[i].spec.Describe() + " (stacked over " +
                                     std::to_string(result.peak_e.size()) + " exposures)",
                                 result.rounds[i].statistics.stack));
    }
    PlotResult pr;
    if (!WriteResidualMaps(dir, "stacked_residuals", rows, &pr, error, plot)) return false;
    note_plot(pr);
  }
  // Split by intensity (statistics.h), one row per round and intensity class.
  if (result.rounds.front().statistics.by_intensity.size() > 1) {
    std::vector<StampPanels> rows;
    for (size_t i = 0; i < result.rounds.size(); ++i) {
      for (const IntensityStack& c : result.rounds[i].statistics.by_intensity) {
        char peaks[96];
        std::snprintf(peaks, sizeof(peaks), "peak %.3g-%.3g e- (%d exposure%s)", c.peak_min_e,
                      c.peak_max_e, c.exposures, c.exposures == 1 ? "" : "s");
        rows.push_back(StackPanels(
            "round " + std::to_string(i) + ": " + result.rounds[i].spec.Describe() + ", " + peaks,
            c.stack));
      }
    }
    PlotResult pr;
    if (!WriteResidualMaps(dir, "stacked_residuals_by_intensity", rows, &pr, error, plot))
      return false;
    note_plot(pr);
  }
  // Radial profile per round.
  {
    XyPlotInput in;
    in.title = "radial profile of the normalised residual";
    in.x_label = "distance from the fitted centre [px] (annulus centre)";
    in.y_label = "mean normalised residual";
    for (size_t i = 0; i < result.rounds.size(); ++i) {
      const ResidualStatistics& st = result.rounds[i].statistics;
      Series s;
      s.label = "round " + std::to_string(i) + ": " + result.rounds[i].spec.Describe();
      for (size_t b = 0; b < st.radial_mean.size(); ++b) {
        if (!std::isfinite(st.radial_mean[b]) || st.radial_count[b] <= 0) continue;
        s.x.push_back(b + 0.5 + 0.05 * i);
        s.y.push_back(st.radial_mean[b]);
        const double e = 1.0 / std::sqrt(st.radial_count[b]);
        s.y_lo.push_back(st.radial_mean[b] - e);
        s.y_hi.push_back(st.radial_mean[b] + e);
      }
      if (!s.x.empty()) in.series.push_back(std::move(s));
    }
    in.requirements.push_back({"0", 0.0});
    if (!in.series.empty()) {
      PlotResult pr;
      if (!WriteXyPlot(dir, "radial_profile", in, &pr, error, plot)) return false;
      note_plot(pr);
    }
  }
  // The flagging statistic of each named effect: before (its round) and after (the next).
  for (size_t i = 0; i + 1 < result.rounds.size(); ++i) {
    const RoundResult& before = result.rounds[i];
    const RoundResult& after = result.rounds[i + 1];
    if (before.adopted.empty()) continue;
    const int s = FlaggingStatistic(before.statistics);
    if (s < 0 || before.predictive_draws.empty()) continue;
    XyPlotInput in;
    const std::string name = before.statistics.values[s].name;
    in.title = before.adopted + ": " + name + " before and after";
    in.x_label = "quantile of the predictive simulations";
    in.y_label = name;
    for (const RoundResult* r : {&before, &after}) {
      if (r->predictive_draws.size() <= static_cast<size_t>(s)) continue;
      std::vector<double> v;
      for (double x : r->predictive_draws[s]) {
        if (std::isfinite(x)) v.push_back(x);
      }
      std::sort(v.begin(), v.end());
      Series ser;
      ser.label = std::string(r == &before ? "before" : "after") + ": simulations of the fitted model";
      for (size_t q = 0; q < v.size(); ++q) {
        ser.x.push_back((q + 0.5) / v.size());
        ser.y.push_back(v[q]);
      }
      if (!ser.x.empty()) in.series.push_back(std::move(ser));
      const double obs = r->statistics.values[s].value;
      if (std::isfinite(obs)) {
        in.requirements.push_back(
            {std::string(r == &before ? "observed before" : "observed after"), obs});
      }
    }
    if (in.series.empty()) continue;
    PlotResult pr;
    if (!WriteXyPlot(dir, "flag_" + before.adopted, in, &pr, error, plot)) return false;
    note_plot(pr);
  }
  const json doc = DiagnoseJson(base, result, options);
  if (!WriteTextFileAtomically(
          out.Path("report.md"),
          Markdown(result, doc, std::string(".") + PlotFormatName(plot.format), plot_notes),
          error) ||
      !WriteTextFileAtomically(out.Path("run.json"), run_record.dump(2) + "\n", error) ||
      !WriteTextFileAtomically(out.Path("diagnose.json"), doc.dump(2) + "\n", error)) {
    return false;
  }
  return out.Commit({"diagnose.json"}, error);
}

}  // namespace ccdpsf::diagnose
