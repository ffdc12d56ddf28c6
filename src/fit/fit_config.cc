#include "ccdpsf/fit/fit_config.h"

#include <sstream>

#include "ccdpsf/input_file.h"

#include "internal/json_reader.h"

namespace ccdpsf::fit {
namespace {

using internal::JsonReader;
using nlohmann::json;

// Reads [lower, upper] with lower < upper.
bool Range(JsonReader* r, const std::string& key, double out[2]) {
  if (!r->Has(key)) return true;
  const json& v = r->Get(key);
  if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
      !(v[0].get<double>() < v[1].get<double>())) {
    r->Fail("'" + r->Path(key) + "' must be [lower, upper] with lower < upper");
    return false;
  }
  out[0] = v[0].get<double>();
  out[1] = v[1].get<double>();
  return true;
}

bool NumberList(JsonReader* r, const std::string& key, std::vector<double>* out) {
  if (!r->Has(key)) return true;
  const json& v = r->Get(key);
  if (!v.is_array() || v.empty()) {
    r->Fail("'" + r->Path(key) + "' must be a non-empty list of numbers");
    return false;
  }
  out->clear();
  for (const json& x : v) {
    if (!x.is_number()) {
      r->Fail("'" + r->Path(key) + "' must be a non-empty list of numbers");
      return false;
    }
    out->push_back(x.get<double>());
  }
  return true;
}

}  // namespace

bool ParseFitEffects(const json& effects, std::vector<FitEffect>* out, std::string* error) {
  if (!effects.is_object()) {
    *error = "'effects' must be an object: {\"<effect>\": {\"<parameter>\": [lower, upper]}}";
    return false;
  }
  std::vector<FitEffect> parsed;
  for (const auto& [name, value] : effects.items()) {
    FitEffect e;
    if (!model::ParseEffectKind(name, &e.kind)) {
      *error = "unknown effect 'effects." + name + "' (`ccdpsf effects` lists the catalogue)";
      return false;
    }
    std::string why;
    if (!IsFittableEffect(e.kind, &why)) {
      *error = "'effects." + name + "' cannot be fitted: " + why;
      return false;
    }
    JsonReader r(value, "effects." + name, error);
    if (!value.is_object()) {
      *error = "'effects." + name + "' must be an object of parameter prior ranges";
      return false;
    }
    for (const model::EffectParameterInfo& p : model::DescribeEffect(e.kind).parameters) {
      double range[2] = {p.prior_lower, p.prior_upper};
      Range(&r, p.name, range);
      e.priors.push_back({range[0], range[1]});
    }
    r.RejectUnknownKeys();
    if (!r.ok()) return false;
    for (size_t i = 0; i < e.priors.size(); ++i) {
      for (double v : e.priors[i]) {
        if (!model::CheckEffectParameter(
                e.kind, static_cast<int>(i), v,
                "effects." + name + "." + model::DescribeEffect(e.kind).parameters[i].name,
                error)) {
          return false;
        }
      }
    }
    parsed.push_back(e);
  }
  *out = parsed;
  return true;
}

bool ParseFitEffectList(const std::string& text, std::vector<FitEffect>* out, std::string* error) {
  std::vector<FitEffect> parsed;
  std::stringstream list(text);
  std::string name;
  while (std::getline(list, name, ',')) {
    if (name.empty() || name == "none") continue;
    FitEffect e;
    std::string why;
    if (!model::ParseEffectKind(name, &e.kind)) {
      *error = "--effects: unknown effect '" + name + "' (`ccdpsf effects` lists the catalogue)";
      return false;
    }
    if (!IsFittableEffect(e.kind, &why)) {
      *error = "--effects: '" + name + "' cannot be fitted: " + why;
      return false;
    }
    for (const FitEffect& seen : parsed) {
      if (seen.kind == e.kind) {
        *error = "--effects: '" + name + "' is given twice";
        return false;
      }
    }
    parsed.push_back(e);
  }
  *out = parsed;
  return true;
}

json FitEffectsJson(const std::vector<FitEffect>& effects) {
  json out = json::object();
  for (const FitEffect& e : effects) {
    const model::EffectInfo& info = model::DescribeEffect(e.kind);
    json params = json::object();
    for (size_t p = 0; p < info.parameters.size(); ++p) {
      const double lo = e.priors.empty() ? info.parameters[p].prior_lower : e.priors[p][0];
      const double hi = e.priors.empty() ? info.parameters[p].prior_upper : e.priors[p][1];
      params[info.parameters[p].name] = {lo, hi};
    }
    out[info.name] = params;
  }
  return out;
}

bool ParseFitConfig(const std::string& text, FitConfig* c, std::string* error) {
  json j = json::parse(text, nullptr, false, true);
  if (j.is_discarded()) {
    *error = "fit config is not valid JSON";
    return false;
  }
  JsonReader r(j, "", error);
  std::string s;
  if (r.Has("sampling")) {
    r.String("sampling", &s);
    if (r.ok() && !model::ParseSampling(s, &c->model.model.sampling)) {
      r.Fail("'sampling' must be \"integrated\" or \"pixel_centre\"");
    }
  }
  if (r.Has("defocus")) {
    r.String("defocus", &s);
    if (r.ok() && !model::ParseDefocusKind(s, &c->model.model.defocus)) {
      r.Fail("'defocus' must be \"gaussian\" or \"pillbox\"");
    }
  }
  if (r.Has("pixel_response_width")) {
    double& w = c->model.model.pixel_response_width;
    r.Number("pixel_response_width", &w);
    if (r.ok() && !(w > 0.0 && w <= 1.0)) {
      r.Fail("'pixel_response_width' must be in (0, 1] px (1: the whole pixel collects)");
    }
  }
  if (r.Has("likelihood")) {
    r.String("likelihood", &s);
    if (r.ok() && !ParseLikelihoodKind(s, &c->model.likelihood)) {
      r.Fail("'likelihood' must be \"gaussian\" or \"poisson_normal\"");
    }
  }
  if (r.Has("joint")) {
    const json& v = r.Get("joint");
    if (!v.is_boolean())
      r.Fail("'joint' must be true or false");
    else
      c->joint = v.get<bool>();
  }
  if (r.Has("through_focus")) {
    const json& v = r.Get("through_focus");
    if (!v.is_boolean()) {
      r.Fail("'through_focus' must be true or false");
    } else {
      c->model.through_focus = v.get<bool>();
      c->through_focus_given = true;
    }
  }
  if (r.Has("flux")) {
    r.String("flux", &s);
    if (r.ok() && s == "auto") {
      c->flux_given = false;
    } else if (r.ok() && !ParseFluxMode(s, &c->model.flux)) {
      r.Fail("'flux' must be \"auto\", \"shared\", \"per_exposure\" or \"exptime_scaled\"");
    } else if (r.ok()) {
      c->flux_given = true;
    }
  }
  if (r.ok() && r.Has("effects") && !ParseFitEffects(r.Get("effects"), &c->model.effects, error)) {
    return false;
  }
  if (r.ok() && r.Has("priors")) {
    JsonReader p(r.Get("priors"), "priors", error);
    PriorRanges& pr = c->model.priors;
    Range(&p, "airy_radius_px", pr.airy_radius_px);
    Range(&p, "defocus_px", pr.defocus_px);
    Range(&p, "ccd_sigma_x_px", pr.ccd_sigma_x_px);
    Range(&p, "ccd_sigma_y_px", pr.ccd_sigma_y_px);
    double flux[2] = {pr.flux_lower_fraction, pr.flux_upper_fraction};
    Range(&p, "flux_fraction", flux);
    pr.flux_lower_fraction = flux[0];
    pr.flux_upper_fraction = flux[1];
    p.Number("position_halfwidth_px", &pr.position_halfwidth_px);
    p.RejectUnknownKeys();
    if (!p.ok()) return false;
    if (pr.airy_radius_px[0] < model::kMinAiryRadiusPx || pr.defocus_px[0] < 0 ||
        pr.ccd_sigma_x_px[0] < model::kMinGaussianWidthPx ||
        pr.ccd_sigma_y_px[0] < model::kMinGaussianWidthPx || pr.flux_lower_fraction <= 0 ||
        pr.position_halfwidth_px <= 0) {
      *error =
          "priors: airy radius >= 0.05 px, ccd sigmas >= 0.05 px, defocus >= 0, flux "
          "fraction > 0 and position half-width > 0 are required";
      return false;
    }
  }
  if (r.ok() && r.Has("map")) {
    JsonReader m(r.Get("map"), "map", error);
    NumberList(&m, "start_airy_radii_px", &c->fit.map.start_airy_radii_px);
    NumberList(&m, "start_defocus_shares", &c->fit.map.start_defocus_shares);
    NumberList(&m, "start_ccd_variance_scales", &c->fit.map.start_ccd_variance_scales);
    NumberList(&m, "start_best_focus_fractions", &c->fit.map.start_best_focus_fractions);
    long long it = c->fit.map.max_iterations;
    m.Integer("max_iterations", &it);
    c->fit.map.max_iterations = static_cast<int>(it);
    m.RejectUnknownKeys();
    if (!m.ok()) return false;
    for (double v : c->fit.map.start_ccd_variance_scales) {
      if (!(v > 0 && v <= 1)) {
        *error = "map: start_ccd_variance_scales must lie in (0, 1]";
        return false;
      }
    }
    for (double v : c->fit.map.start_best_focus_fractions) {
      if (!(v >= 0 && v <= 1)) {
        *error = "map: start_best_focus_fractions must lie in [0, 1]";
        return false;
      }
    }
  }
  if (r.ok() && r.Has("mcmc")) {
    JsonReader m(r.Get("mcmc"), "mcmc", error);
    if (m.Has("enabled")) {
      const json& v = m.Get("enabled");
      if (!v.is_boolean())
        m.Fail("'mcmc.enabled' must be true or false");
      else
        c->fit.run_mcmc = v.get<bool>();
    }
    long long walkers = c->fit.num_walkers, steps = c->fit.mcmc.max_steps,
              seed = static_cast<long long>(c->fit.mcmc.seed), threads = c->fit.mcmc.num_threads;
    m.Integer("walkers", &walkers);
    m.Integer("max_steps", &steps);
    m.Integer("seed", &seed);
    m.Integer("threads", &threads);
    m.Number("target_ess", &c->fit.mcmc.target_ess);
    m.Number("min_tau_multiple", &c->fit.mcmc.min_tau_multiple);
    for (const char* key : {"marginal_defocus", "positions_by_conditional"}) {
      if (!m.Has(key)) continue;
      const json& v = m.Get(key);
      bool& field = std::string(key) == "marginal_defocus" ? c->fit.target.marginal_defocus
                                                           : c->fit.target.positions_by_conditional;
      if (!v.is_boolean())
        m.Fail(std::string("'mcmc.") + key + "' must be true or false");
      else
        field = v.get<bool>();
    }
    long long every = c->fit.target.position_update_every;
    m.Integer("position_update_every", &every);
    m.RejectUnknownKeys();
    if (!m.ok()) return false;
    if (!CheckMcmcSettings(walkers, steps, threads, c->fit.mcmc.target_ess, "mcmc.", error)) {
      return false;
    }
    if (seed < 0 || every < 1) {
      *error = "mcmc: seed >= 0 and position_update_every >= 1 are required";
      return false;
    }
    c->fit.target.position_update_every = static_cast<int>(every);
    c->fit.num_walkers = static_cast<int>(walkers);
    c->fit.mcmc.max_steps = static_cast<int>(steps);
    c->fit.mcmc.seed = static_cast<uint64_t>(seed);
    c->fit.mcmc.num_threads = c->fit.map.num_threads = static_cast<int>(threads);
  }
  if (r.ok() && r.Has("calibration")) {
    const json& k = r.Get("calibration");
    if (!k.is_object()) {
      *error = "'calibration' must be a JSON object";
      return false;
    }
    CalibrationOptions& co = c->calibration;
    for (auto it = k.begin(); it != k.end(); ++it) {
      const std::string key = it.key();
      const json& v = it.value();
      if (key == "stamp_size") {
        if (!v.is_number_integer()) {
          *error = "'calibration.stamp_size' must be an integer";
          return false;
        }
        co.stamp_size = v.get<int>();
        continue;
      }
      if (!IsMetadataQuantity(key)) {
        *error = "unknown key 'calibration." + key + "'";
        return false;
      }
      if (v.is_null()) continue;  // as written by run.json for "not given"
      std::string text;
      if (v.is_number()) {
        std::ostringstream out;
        out.precision(17);
        out << v.get<double>();
        text = out.str();
      } else if (v.is_string()) {
        text = v.get<std::string>();
      } else {
        *error = "'calibration." + key + "' must be a number or a string";
        return false;
      }
      std::string why;
      if (!co.given.SetFromText(key, text, "FIT.json", &why)) {
        *error = "calibration: " + why;
        return false;
      }
    }
    if (!co.IsValid(error)) return false;
  }
  if (r.ok() && r.Has("flags")) {
    const json& f = r.Get("flags");
    if (!f.is_object()) {
      *error = "'flags' must be a JSON object of option names and values";
      return false;
    }
    c->flags = f;
  }
  if (r.ok() && r.Has("keywords")) {
    if (!c->calibration.keywords.Overlay(r.Get("keywords"), error)) return false;
  }
  r.RejectUnknownKeys();
  return r.ok();
}

bool LoadFitConfig(const std::string& path, FitConfig* config, std::string* error) {
  std::string text;
  if (!ReadTextInput(path, "fit config", &text, error)) return false;
  if (!ParseFitConfig(text, config, error)) {
    *error = "'" + path + "': " + *error;
    return false;
  }
  return true;
}

json CalibrationJson(const CalibrationOptions& options) {
  json out = json::object();
  for (const auto& [quantity, value] : options.given.values()) {
    if (value.number) out[quantity] = *value.number;
    if (value.text) out[quantity] = *value.text;
  }
  out["stamp_size"] = options.stamp_size;
  return out;
}

json FitConfigJson(const FitConfig& c) {
  const PriorRanges& p = c.model.priors;
  return {{"sampling", model::ToString(c.model.model.sampling)},
          {"defocus", model::ToString(c.model.model.defocus)},
          {"pixel_response_width", c.model.model.pixel_response_width},
          {"likelihood", ToString(c.model.likelihood)},
          {"joint", c.joint},
          {"through_focus", c.model.through_focus},
          {"flux", c.flux_given ? ToString(c.model.flux) : std::string("auto")},
          {"effects", FitEffectsJson(c.model.effects)},
          {"priors",
           {{"airy_radius_px", {p.airy_radius_px[0], p.airy_radius_px[1]}},
            {"defocus_px", {p.defocus_px[0], p.defocus_px[1]}},
            {"ccd_sigma_x_px", {p.ccd_sigma_x_px[0], p.ccd_sigma_x_px[1]}},
            {"ccd_sigma_y_px", {p.ccd_sigma_y_px[0], p.ccd_sigma_y_px[1]}},
            {"flux_fraction", {p.flux_lower_fraction, p.flux_upper_fraction}},
            {"position_halfwidth_px", p.position_halfwidth_px}}},
          {"map",
           {{"start_airy_radii_px", c.fit.map.start_airy_radii_px},
            {"start_defocus_shares", c.fit.map.start_defocus_shares},
            {"start_ccd_variance_scales", c.fit.map.start_ccd_variance_scales},
            {"start_best_focus_fractions", c.fit.map.start_best_focus_fractions},
            {"max_iterations", c.fit.map.max_iterations}}},
          {"mcmc",
           {{"enabled", c.fit.run_mcmc},
            {"walkers", c.fit.num_walkers},
            {"max_steps", c.fit.mcmc.max_steps},
            {"target_ess", c.fit.mcmc.target_ess},
            {"min_tau_multiple", c.fit.mcmc.min_tau_multiple},
            {"marginal_defocus", c.fit.target.marginal_defocus},
            {"positions_by_conditional", c.fit.target.positions_by_conditional},
            {"position_update_every", c.fit.target.position_update_every},
            {"seed", c.fit.mcmc.seed},
            {"threads", c.fit.mcmc.num_threads}}},
          {"calibration", CalibrationJson(c.calibration)},
          {"keywords", c.calibration.keywords.ToJson()}};
}

bool CheckMcmcSettings(long long walkers, long long max_steps, long long threads,
                       double target_ess, const std::string& prefix, std::string* error) {
  auto outside = [&](const char* name, const std::string& value, const std::string& range) {
    *error = prefix + name + " = " + value + " is outside " + range;
    return false;
  };
  if (walkers < 0 || walkers > kMaxWalkers) {
    return outside("walkers", std::to_string(walkers),
                   "0 (automatic) to " + std::to_string(kMaxWalkers));
  }
  if (max_steps < 1 || max_steps > kMaxSteps) {
    return outside("max_steps", std::to_string(max_steps), "1 to " + std::to_string(kMaxSteps));
  }
  if (threads < 1 || threads > kMaxThreads) {
    return outside("threads", std::to_string(threads), "1 to " + std::to_string(kMaxThreads));
  }
  if (!(target_ess >= 0 && target_ess <= static_cast<double>(kMaxSteps))) {
    return outside("target_ess", std::to_string(target_ess), "0 to " + std::to_string(kMaxSteps));
  }
  return true;
}

}  // namespace ccdpsf::fit
