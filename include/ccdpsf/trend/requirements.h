// Requirement checks on the trend relations (docs/metrics.md: the Euclid VIS ones by
// default), evaluated on the propagated draws: value (median), 68 % interval, margin,
// pass / fail and the probability of passing.
//
// A requirement targets either
//   - a metric at (wavelength, intensity), evaluated with the combined model of paper
//     section 4.4 built from the relations "<metric>_vs_intensity" and
//     "<metric>_vs_wavelength" (see EvaluateCombined in relations.h); or
//   - a coefficient of one relation, e.g. alpha of "fwhm_um_vs_wavelength".
//
// Why the combined model rather than the measured setting nearest (800 nm, I0): it uses
// every setting, carries the propagated uncertainty, and is defined at exactly the requested
// place. At I = I0 (the defaults) the intensity factor X(I)/X(I0) is 1 by construction, so
// the value is the wavelength relation at 800 nm and no intensity relation is needed; the
// price is that it trusts the power law (its flags are copied into the requirement's notes,
// so a poorly constrained or over-scattered relation is visible next to the verdict).
//
// `pass` is decided by the median; `pass_probability` is the fraction of draws that pass. A
// requirement whose inputs are missing (relation absent or not fitted, coefficient unknown)
// reports pass = null with a reason, never a made-up value. The verdict (Verdict()) says
// whether the data settle it: "pass" when P(pass) >= 0.95, "fail" when P(pass) <= 0.05,
// "undetermined" between (a prior-dominated CCD-only width passes by its median at P ~ 0.5,
// which is not a measurement), "n/a" when the inputs are missing.
//
// JSON configuration (a list; strict: unknown keys, wrong types, both or neither of max/min
// are errors):
//
//   [{"name": "fwhm_800nm", "metric": "fwhm_um",
//     "at": {"wavelength_nm": 800, "intensity_e": 157800}, "max": 10.8},
//    {"name": "alpha_fwhm", "relation": "fwhm_um_vs_wavelength", "coefficient": "alpha",
//     "max": -0.2}]
//
// "intensity_e" may be omitted (I0 = 157800 e-). Metrics are TrendMetricNames(); relation
// names are "<metric>_vs_wavelength" (coefficients a, alpha, value_at_pivot) or
// "<metric>_vs_intensity" (intercept, slope, value_at_pivot).
#ifndef CCDPSF_TREND_REQUIREMENTS_H_
#define CCDPSF_TREND_REQUIREMENTS_H_

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/trend/relations.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {

enum class Comparison {
  kAtMost,   // value <= limit ("max")
  kAtLeast,  // value >= limit ("min")
};

struct Requirement {
  enum class Target { kMetricAt, kCoefficient };

  std::string name;
  Target target = Target::kMetricAt;
  Comparison comparison = Comparison::kAtMost;
  double limit = NAN;  // in the metric's (or coefficient's) unit

  // kMetricAt: metric (TrendMetricNames()) at (wavelength_nm, intensity_e).
  std::string metric;
  double wavelength_nm = NAN;               // [nm]
  double intensity_e = kReferenceIntensityE;  // peak pixel [e-]

  // kCoefficient: relation name (e.g. "fwhm_um_vs_wavelength") and coefficient name.
  std::string relation;
  std::string coefficient;

  // False with a one-line reason for an empty name, non-finite limit, unknown metric,
  // relation or coefficient, or a wavelength <= 0.
  bool IsValid(std::string* error) const;
};

// Euclid VIS (docs/metrics.md): FWHM <= 10.8 um at 800 nm and I0; ellipticity <= 0.156
// (15.6 %) at 800 nm and I0; alpha of FWHM(lambda) <= -0.2.
std::vector<Requirement> DefaultRequirements();

// Parses the JSON list above. nullopt with a one-line reason (naming the entry and key) on
// any error; duplicate names are errors.
std::optional<std::vector<Requirement>> ParseRequirements(const nlohmann::json& list,
                                                          std::string* error);
std::optional<std::vector<Requirement>> ParseRequirementsText(const std::string& json_text,
                                                              std::string* error);

// The configuration form (ParseRequirements(RequirementsToJson(r)) == r), for run records.
nlohmann::json RequirementsToJson(const std::vector<Requirement>& requirements);

struct RequirementResult {
  Requirement requirement;
  std::optional<bool> pass;       // by the median; nullopt when the inputs are missing
  Estimate value;                 // NaN when missing
  double margin = NAN;            // limit - value for max, value - limit for min: > 0 passes
  double pass_probability = NAN;  // fraction of draws that pass
  std::string reason;             // why pass is null (empty otherwise)
  std::vector<std::string> notes;  // caveats: flags of the relations used, extrapolation
};

// The probability of passing beyond which the data are said to settle a requirement (and
// 1 minus it for failing): a one-sided 95 % credible statement.
constexpr double kSettledProbability = 0.95;

// "pass", "fail", "undetermined" or "n/a", as above.
std::string Verdict(const RequirementResult& result);

// Relations by name (RelationName(metric, kind), as in trend.json). I0 is the intensity
// zero point of the combined model.
std::vector<RequirementResult> EvaluateRequirements(
    const std::vector<Requirement>& requirements,
    const std::map<std::string, RelationFit>& relations,
    double reference_intensity_e = kReferenceIntensityE);

// A metric requirement judged on one group's own posterior draws of that metric, with no
// relation and no intensity correction: for a through-focus series, whose CCD widths are
// identified (trend.h), at the series' wavelength and intensity. The caller adds a note that
// says which. Coefficient requirements and missing or non-finite draws give pass = null with
// a reason.
RequirementResult EvaluateRequirementOnDraws(const Requirement& requirement,
                                             const std::vector<double>& draws);

// trend.json's requirement entry: {"name", "target", "comparison", "limit", "value", "lo68",
// "hi68", "margin", "pass", "pass_probability", "verdict", "reason", "notes"} (+ "metric", "at" or
// "relation", "coefficient"); NaN and a missing pass are null.
nlohmann::json ToJson(const RequirementResult& result);

// A fixed-width text table: name | value [lo68, hi68] | requirement | margin | pass |
// P(pass) | verdict, one line per requirement, "n/a (reason)" for missing inputs. For report.md.
std::string FormatRequirementTable(const std::vector<RequirementResult>& results);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_REQUIREMENTS_H_
