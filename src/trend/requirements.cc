#include "ccdpsf/trend/requirements.h"

#include <algorithm>
#include <cstdio>
#include <set>

#include "internal/json_reader.h"

namespace ccdpsf::trend {
namespace {

using nlohmann::json;

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.4g", v);
  return buf;
}

json NullIfNan(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

bool IsTrendMetric(const std::string& metric) {
  const std::vector<std::string>& names = TrendMetricNames();
  return std::find(names.begin(), names.end(), metric) != names.end();
}

// Splits "<metric>_vs_wavelength" / "<metric>_vs_intensity"; false if neither form.
bool ParseRelationName(const std::string& relation, std::string* metric, RelationKind* kind) {
  for (RelationKind k : {RelationKind::kPowerLaw, RelationKind::kLinear}) {
    const std::string suffix = RelationName("", k);
    if (relation.size() > suffix.size() &&
        relation.compare(relation.size() - suffix.size(), suffix.size(), suffix) == 0) {
      *metric = relation.substr(0, relation.size() - suffix.size());
      *kind = k;
      return true;
    }
  }
  return false;
}

bool IsCoefficientOf(RelationKind kind, const std::string& coefficient) {
  if (coefficient == "value_at_pivot") return true;
  return kind == RelationKind::kPowerLaw ? (coefficient == "a" || coefficient == "alpha")
                                         : (coefficient == "intercept" || coefficient == "slope");
}

const char* ComparisonSymbol(Comparison c) { return c == Comparison::kAtMost ? "<=" : ">="; }

// "relation_name: flag: reason" for every flag of the relation.
void AddRelationNotes(const std::string& name, const RelationFit& fit,
                      std::vector<std::string>* notes) {
  for (const RelationFlag& f : fit.flags) notes->push_back(name + ": " + f.code + ": " + f.reason);
}

// Empty when usable; otherwise why not.
std::string RelationProblem(const std::map<std::string, RelationFit>& relations,
                            const std::string& name, const RelationFit** out) {
  const auto it = relations.find(name);
  if (it == relations.end()) return "relation '" + name + "' is absent";
  if (!it->second.fitted) {
    std::string why = "relation '" + name + "' was not fitted";
    for (const RelationFlag& f : it->second.flags) {
      if (f.code == kFlagNotFitted) why += ": " + f.reason;
    }
    return why;
  }
  *out = &it->second;
  return "";
}

}  // namespace

bool Requirement::IsValid(std::string* error) const {
  const std::string where = "requirement '" + name + "': ";
  if (name.empty()) {
    *error = "requirement: empty name";
    return false;
  }
  if (!std::isfinite(limit)) {
    *error = where + "the limit must be a finite number";
    return false;
  }
  if (target == Target::kMetricAt) {
    if (!IsTrendMetric(metric)) {
      *error = where + "unknown metric '" + metric + "'";
      return false;
    }
    if (!(wavelength_nm > 0.0) || !std::isfinite(wavelength_nm)) {
      *error = where + "wavelength_nm must be a finite number > 0";
      return false;
    }
    if (!std::isfinite(intensity_e)) {
      *error = where + "intensity_e must be a finite number";
      return false;
    }
    return true;
  }
  std::string relation_metric;
  RelationKind kind;
  if (!ParseRelationName(relation, &relation_metric, &kind) || !IsTrendMetric(relation_metric)) {
    *error = where + "unknown relation '" + relation +
             "' (expected <metric>_vs_wavelength or <metric>_vs_intensity)";
    return false;
  }
  if (!IsCoefficientOf(kind, coefficient)) {
    *error = where + "relation '" + relation + "' has no coefficient '" + coefficient + "' (" +
             (kind == RelationKind::kPowerLaw ? "a, alpha, value_at_pivot"
                                              : "intercept, slope, value_at_pivot") +
             ")";
    return false;
  }
  return true;
}

std::vector<Requirement> DefaultRequirements() {
  std::vector<Requirement> out;
  Requirement fwhm;
  fwhm.name = "fwhm_800nm";
  fwhm.metric = "fwhm_um";
  fwhm.wavelength_nm = 800.0;
  fwhm.intensity_e = kReferenceIntensityE;
  fwhm.limit = 10.8;
  out.push_back(fwhm);
  Requirement e = fwhm;
  e.name = "ellipticity_800nm";
  e.metric = "ellipticity";
  e.limit = 0.156;
  out.push_back(e);
  Requirement alpha;
  alpha.name = "alpha_fwhm";
  alpha.target = Requirement::Target::kCoefficient;
  alpha.relation = "fwhm_um_vs_wavelength";
  alpha.coefficient = "alpha";
  alpha.limit = -0.2;
  out.push_back(alpha);
  return out;
}

std::optional<std::vector<Requirement>> ParseRequirements(const json& list, std::string* error) {
  if (!list.is_array()) {
    *error = "requirements: must be a JSON list of objects";
    return std::nullopt;
  }
  std::vector<Requirement> out;
  std::set<std::string> names;
  for (size_t k = 0; k < list.size(); ++k) {
    const std::string path = "requirements[" + std::to_string(k) + "]";
    if (!list[k].is_object()) {
      *error = path + ": must be a JSON object";
      return std::nullopt;
    }
    Requirement req;
    internal::JsonReader r(list[k], path, error);
    r.String("name", &req.name, true);
    const bool has_metric = r.Has("metric");
    const bool has_relation = r.Has("relation");
    if (r.ok() && has_metric == has_relation) {
      r.Fail(path + ": give either 'metric' (with 'at') or 'relation' (with 'coefficient')");
    }
    if (r.ok() && has_metric) {
      req.target = Requirement::Target::kMetricAt;
      r.String("metric", &req.metric, true);
      if (r.ok() && r.Has("coefficient")) {
        r.Fail("'" + r.Path("coefficient") + "' goes with 'relation', not 'metric'");
      }
      if (r.ok() && !r.Has("at")) r.Fail("'" + r.Path("at") + "' is required with 'metric'");
      if (r.ok()) {
        const json& at = r.Get("at");
        if (!at.is_object()) {
          r.Fail("'" + r.Path("at") + "' must be a JSON object");
        } else {
          internal::JsonReader a(at, r.Path("at"), error);
          a.Number("wavelength_nm", &req.wavelength_nm, true);
          a.Number("intensity_e", &req.intensity_e);
          a.RejectUnknownKeys();
          if (!a.ok()) return std::nullopt;
        }
      }
    } else if (r.ok()) {
      req.target = Requirement::Target::kCoefficient;
      r.String("relation", &req.relation, true);
      if (r.ok() && r.Has("at")) {
        r.Fail("'" + r.Path("at") + "' goes with 'metric', not 'relation'");
      }
      r.String("coefficient", &req.coefficient, true);
    }
    if (r.ok()) {
      const bool has_max = r.Has("max");
      const bool has_min = r.Has("min");
      if (has_max == has_min) {
        r.Fail(path + ": give exactly one of 'max' (value <= limit) or 'min' (value >= limit)");
      } else {
        req.comparison = has_max ? Comparison::kAtMost : Comparison::kAtLeast;
        r.Number(has_max ? "max" : "min", &req.limit, true);
      }
    }
    r.RejectUnknownKeys();
    if (!r.ok()) return std::nullopt;
    std::string why;
    if (!req.IsValid(&why)) {
      *error = path + ": " + why;
      return std::nullopt;
    }
    if (!names.insert(req.name).second) {
      *error = path + ": duplicate requirement name '" + req.name + "'";
      return std::nullopt;
    }
    out.push_back(std::move(req));
  }
  return out;
}

std::optional<std::vector<Requirement>> ParseRequirementsText(const std::string& json_text,
                                                              std::string* error) {
  const json parsed = json::parse(json_text, nullptr, /*allow_exceptions=*/false,
                                  /*ignore_comments=*/true);
  if (parsed.is_discarded()) {
    *error = "requirements: not valid JSON";
    return std::nullopt;
  }
  return ParseRequirements(parsed, error);
}

json RequirementsToJson(const std::vector<Requirement>& requirements) {
  json list = json::array();
  for (const Requirement& req : requirements) {
    json j;
    j["name"] = req.name;
    if (req.target == Requirement::Target::kMetricAt) {
      j["metric"] = req.metric;
      j["at"] = {{"wavelength_nm", req.wavelength_nm}, {"intensity_e", req.intensity_e}};
    } else {
      j["relation"] = req.relation;
      j["coefficient"] = req.coefficient;
    }
    j[req.comparison == Comparison::kAtMost ? "max" : "min"] = req.limit;
    list.push_back(j);
  }
  return list;
}

namespace {

// The value, margin, pass and P(pass) of res's requirement from the value's draws (a reason
// instead when none is finite).
void Judge(const std::vector<double>& draws, RequirementResult* res) {
  const Requirement& req = res->requirement;
  res->value = SummarizeDraws(draws);
  if (!std::isfinite(res->value.median)) {
    res->reason = "no finite draws of the value";
    res->value = Estimate();
    return;
  }
  const bool at_most = req.comparison == Comparison::kAtMost;
  res->margin = at_most ? req.limit - res->value.median : res->value.median - req.limit;
  res->pass = at_most ? res->value.median <= req.limit : res->value.median >= req.limit;
  size_t finite = 0, passing = 0;
  for (double d : draws) {
    if (!std::isfinite(d)) continue;
    ++finite;
    if (at_most ? d <= req.limit : d >= req.limit) ++passing;
  }
  res->pass_probability = static_cast<double>(passing) / static_cast<double>(finite);
}

// The draws of `metric` at the requirement's (intensity, wavelength) by the combined model
// (relations.h EvaluateCombined), adding the relations' notes to *res. False, with the
// reason in res->reason, when a relation it needs is missing or unusable.
bool CombinedDraws(const std::map<std::string, RelationFit>& relations, const std::string& metric,
                   const Requirement& req, double reference_intensity_e, std::vector<double>* draws,
                   RequirementResult* res) {
  const std::string wl_name = RelationName(metric, RelationKind::kPowerLaw);
  const std::string in_name = RelationName(metric, RelationKind::kLinear);
  const bool at_reference =
      std::fabs(req.intensity_e - reference_intensity_e) <= 1e-9 * std::fabs(reference_intensity_e);
  const RelationFit* wl = nullptr;
  const RelationFit* in = nullptr;
  res->reason = RelationProblem(relations, wl_name, &wl);
  if (res->reason.empty() && !at_reference) {
    res->reason = RelationProblem(relations, in_name, &in);
    if (!res->reason.empty()) {
      res->reason += " (needed at intensity " + Num(req.intensity_e) + " e- != I0 " +
                     Num(reference_intensity_e) + " e-)";
    }
  }
  if (!res->reason.empty()) return false;
  std::string error;
  const std::optional<CombinedValue> v =
      EvaluateCombined(in, *wl, req.intensity_e, req.wavelength_nm, reference_intensity_e, &error);
  if (!v) {
    res->reason = error;
    return false;
  }
  *draws = v->draws;
  AddRelationNotes(wl_name, *wl, &res->notes);
  if (in != nullptr) AddRelationNotes(in_name, *in, &res->notes);
  res->notes.insert(res->notes.end(), v->notes.begin(), v->notes.end());
  return true;
}

}  // namespace

std::vector<RequirementResult> EvaluateRequirements(
    const std::vector<Requirement>& requirements,
    const std::map<std::string, RelationFit>& relations, double reference_intensity_e) {
  std::vector<RequirementResult> results;
  for (const Requirement& req : requirements) {
    RequirementResult res;
    res.requirement = req;
    std::vector<double> draws, fx, fy;
    std::string why;
    if (!req.IsValid(&why)) {
      res.reason = why;
    } else if (req.target == Requirement::Target::kCoefficient) {
      const RelationFit* fit = nullptr;
      res.reason = RelationProblem(relations, req.relation, &fit);
      if (fit != nullptr) {
        const Coefficient* c = fit->Find(req.coefficient);
        if (c == nullptr || c->draws.empty()) {
          res.reason = "relation '" + req.relation + "' has no draws of '" + req.coefficient + "'";
        } else {
          draws = c->draws;
          AddRelationNotes(req.relation, *fit, &res.notes);
        }
      }
    } else if (req.metric == "ellipticity" &&
               CombinedDraws(relations, "fwhm_x_um", req, reference_intensity_e, &fx, &res) &&
               CombinedDraws(relations, "fwhm_y_um", req, reference_intensity_e, &fy, &res)) {
      // e depends on the widths' ratio: from the x and y laws draw by draw (their points
      // are the same settings' same MCMC draws, so the pairing keeps their correlation).
      // Not from a power law of e itself: with different exponents on the two axes e
      // passes through zero at some wavelength, which no power law follows.
      for (size_t r = 0; r < std::min(fx.size(), fy.size()); ++r) {
        const double x2 = fx[r] * fx[r], y2 = fy[r] * fy[r];
        draws.push_back(std::fabs(x2 - y2) / (x2 + y2));
      }
      res.notes.push_back(
          "from the fwhm_x_um and fwhm_y_um relations, draw by draw: e = |fx^2 - fy^2| / (fx^2 "
          "+ fy^2) (a power law of e itself cannot follow e through zero)");
    } else {
      res.notes.clear();
      res.reason.clear();
      CombinedDraws(relations, req.metric, req, reference_intensity_e, &draws, &res);
    }
    if (res.reason.empty()) Judge(draws, &res);
    results.push_back(std::move(res));
  }
  return results;
}

RequirementResult EvaluateRequirementOnDraws(const Requirement& requirement,
                                             const std::vector<double>& draws) {
  RequirementResult res;
  res.requirement = requirement;
  if (!requirement.IsValid(&res.reason)) return res;
  if (requirement.target != Requirement::Target::kMetricAt) {
    res.reason = "a coefficient requirement needs a relation, not one group's draws";
    return res;
  }
  if (draws.empty()) {
    res.reason = "no draws of '" + requirement.metric + "'";
    return res;
  }
  Judge(draws, &res);
  return res;
}

json ToJson(const RequirementResult& result) {
  const Requirement& req = result.requirement;
  json j;
  j["name"] = req.name;
  if (req.target == Requirement::Target::kMetricAt) {
    j["target"] = "metric_at";
    j["metric"] = req.metric;
    j["at"] = {{"wavelength_nm", req.wavelength_nm}, {"intensity_e", req.intensity_e}};
  } else {
    j["target"] = "coefficient";
    j["relation"] = req.relation;
    j["coefficient"] = req.coefficient;
  }
  j["comparison"] = ComparisonSymbol(req.comparison);
  j["limit"] = NullIfNan(req.limit);
  j["value"] = NullIfNan(result.value.median);
  j["lo68"] = NullIfNan(result.value.lo68);
  j["hi68"] = NullIfNan(result.value.hi68);
  j["lo95"] = NullIfNan(result.value.lo95);
  j["hi95"] = NullIfNan(result.value.hi95);
  j["sd"] = NullIfNan(result.value.sd);
  j["margin"] = NullIfNan(result.margin);
  j["pass"] = result.pass ? json(*result.pass) : json(nullptr);
  j["pass_probability"] = NullIfNan(result.pass_probability);
  j["verdict"] = Verdict(result);
  j["reason"] = result.reason.empty() ? json(nullptr) : json(result.reason);
  j["notes"] = result.notes;
  return j;
}

std::string Verdict(const RequirementResult& result) {
  if (!result.pass || !std::isfinite(result.pass_probability)) return "n/a";
  if (result.pass_probability >= kSettledProbability) return "pass";
  if (result.pass_probability <= 1.0 - kSettledProbability) return "fail";
  return "undetermined";
}

std::string FormatRequirementTable(const std::vector<RequirementResult>& results) {
  std::string out;
  char line[512];
  std::snprintf(line, sizeof(line), "%-22s %-30s %-14s %-11s %-5s %-8s %s\n", "requirement",
                "value [68 %]", "limit", "margin", "pass", "P(pass)", "verdict");
  out += line;
  for (const RequirementResult& r : results) {
    const std::string limit =
        std::string(ComparisonSymbol(r.requirement.comparison)) + " " + Num(r.requirement.limit);
    if (!r.pass) {
      std::snprintf(line, sizeof(line), "%-22s %-30s %-14s %-11s %-5s ",
                    r.requirement.name.c_str(), "n/a", limit.c_str(), "n/a", "n/a");
      out += line + ("n/a (" + r.reason + ")\n");
      continue;
    } else {
      const std::string value = Num(r.value.median) + " [" + Num(r.value.lo68) + ", " +
                                Num(r.value.hi68) + "]";
      std::snprintf(line, sizeof(line), "%-22s %-30s %-14s %-11s %-5s %-8.3f %s\n",
                    r.requirement.name.c_str(), value.c_str(), limit.c_str(), Num(r.margin).c_str(),
                    *r.pass ? "yes" : "NO", r.pass_probability, Verdict(r).c_str());
    }
    out += line;
  }
  return out;
}

}  // namespace ccdpsf::trend
