#include "ccdpsf/trend/trend.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <sstream>

#include "ccdpsf/trend/intensity_series.h"

namespace ccdpsf::trend {
namespace {

std::string Format(double v, int precision = 4) {
  std::ostringstream out;
  out.precision(precision);
  out << v;
  return out.str();
}

// The CCD width behind a CCD-only metric that the data do not bound from below (group_fit.h
// unbounded_below), or "".
std::string WidthAtLowerBound(const GroupResult& g, const std::string& metric) {
  std::vector<std::string> axes;
  if (metric == "fwhm_x_um") {
    axes = {"ccd_sigma_x_px"};
  } else if (metric == "fwhm_y_um") {
    axes = {"ccd_sigma_y_px"};
  } else if (metric == "fwhm_um" || metric == "r2_px2" || metric == "ellipticity") {
    axes = {"ccd_sigma_x_px", "ccd_sigma_y_px"};
  }
  for (const std::string& a : axes) {
    if (std::find(g.unbounded_below.begin(), g.unbounded_below.end(), a) !=
        g.unbounded_below.end()) {
      return a;
    }
  }
  return "";
}

// The group's measurement of `metric` as a relation point at `abscissa`: its posterior
// draws, else the Laplace Gaussian, else a gap saying why.
RelationPoint PointOf(const GroupResult& g, const std::string& metric, double abscissa) {
  const std::string& label = g.group.name;
  if (!g.ok) return RelationPoint::Missing(label, abscissa, g.failure);
  if (g.ccd_split_unidentified && IsCcdOnlyMetric(metric)) {
    return RelationPoint::Missing(
        label, abscissa,
        "CCD widths not identified: at one focus a Gaussian defocus and the CCD kernel "
        "convolve to one Gaussian, so only their total widths are measured (docs/trust.md); a "
        "through-focus series at this setting identifies them, and so does one at this "
        "wavelength whose scanned range holds this setting's stage position (FOCUSPOS), which "
        "anchors its defocus");
  }
  // "Bound only" (see trend.h): not a measurement to fit a line through.
  const std::string width = WidthAtLowerBound(g, metric);
  if (!width.empty()) {
    auto s = g.summaries.find(metric);
    std::string posterior;
    if (s != g.summaries.end() && std::isfinite(s->second.median)) {
      posterior = "; posterior median " + Format(s->second.median) + ", 84th percentile " +
                  Format(s->second.hi68);
    }
    const std::string reason =
        "bound only: " + width + " reaches its prior's lower bound (MAP or posterior), so the "
        "data do not bound this metric from below (in pixel_centre sampling a CCD width under "
        "~0.25 px leaves no trace)" + posterior;
    // The draws give the gap its upper limit, unless the chain is not to be trusted.
    auto draws = g.draws.find(metric);
    if (draws == g.draws.end() || !g.converged) {
      return RelationPoint::Missing(label, abscissa, reason);
    }
    return RelationPoint::BoundOnly(label, abscissa, reason, draws->second);
  }
  auto draws = g.draws.find(metric);
  // A chain that did not converge has intervals not to be trusted (often far too narrow: a
  // walker ensemble stuck in one corner), and one such point can dominate a weighted fit.
  if (draws != g.draws.end() && !g.converged) {
    return RelationPoint::Missing(label, abscissa,
                                  "its MCMC did not converge, so its interval is not to be "
                                  "trusted (see the group's fit report)");
  }
  if (draws != g.draws.end() && draws->second.size() >= 2) {
    return RelationPoint::FromDraws(label, abscissa, draws->second);
  }
  auto s = g.summaries.find(metric);
  if (s != g.summaries.end() && std::isfinite(s->second.laplace_sd)) {
    return RelationPoint::FromGaussian(label, abscissa, s->second.map, s->second.laplace_sd);
  }
  return RelationPoint::Missing(label, abscissa,
                                "no posterior draws (MCMC off) and no Laplace sd (the data do "
                                "not constrain " + metric + ")");
}

double NominalOrMeasuredPeak(const GroupResult& g) {
  if (g.ok && std::isfinite(g.peak_e.median)) return g.peak_e.median;
  if (g.ok && std::isfinite(g.peak_e.map)) return g.peak_e.map;
  return g.group.nominal_peak_e.value_or(NAN);
}

// Whether group g measures `metric` for the relations: a through-focus series only the
// CCD-only metrics (its total_* describe the PSF at best focus, a different spot from the
// single-focus settings' defocused one).
bool MeasuresMetric(const GroupResult& g, const std::string& metric) {
  return !g.group.focus_series || IsCcdOnlyMetric(metric);
}

// The group of one wavelength whose point enters the power law: the one nearest I0 within
// the intensity tolerance, a through-focus series first (its CCD widths are identified); a
// failed group only if no successful one qualifies, so that its gap shows. nullptr, with
// the reason in *why_none, when none qualifies.
const GroupResult* NearestReference(const std::vector<const GroupResult*>& list,
                                    const TrendOptions& options, std::string* why_none) {
  const double i0 = options.reference_intensity_e;
  const GroupResult* best = nullptr;
  double best_rank = INFINITY;
  for (const GroupResult* g : list) {
    const double peak = NominalOrMeasuredPeak(*g);
    // (A failed group of unknown intensity might have been the one: it ranks as close.)
    const double distance =
        std::isfinite(peak) ? std::fabs(peak / i0 - 1.0) : (g->ok ? INFINITY : 0.0);
    const bool qualifies = distance <= options.intensity_tolerance;
    // Ranks: a successful series within tolerance, then a successful single-focus setting,
    // then a failed group; by distance within each.
    const double rank = distance + (g->ok ? 0.0 : 20.0) +
                        (qualifies && g->ok && g->group.focus_series ? 0.0 : 10.0);
    if (rank < best_rank) {
      best_rank = rank;
      best = g;
    }
  }
  const double distance =
      best != nullptr ? std::fabs(NominalOrMeasuredPeak(*best) / i0 - 1.0) : INFINITY;
  if (best != nullptr && (distance <= options.intensity_tolerance || !best->ok)) return best;
  *why_none = list.empty() ? "no single-focus setting (a through-focus series measures the "
                             "CCD-only metrics only)"
                           : "no setting within " + Format(100 * options.intensity_tolerance, 3) +
                                 " % of I0 = " + Format(i0, 7) + " e-";
  return nullptr;
}

// Setting `label`'s point in an intensity relation of CCD-only `metric` from the intensity
// series that holds it (intensity_series.h): the series' draws at the setting, at the
// setting's own intensity, resampled jointly with the series' other points.
RelationPoint SeriesPoint(const GroupResult& series, const std::string& label, double abscissa,
                          const std::string& metric, bool intrinsic = false) {
  if (!series.ok) {
    return RelationPoint::Missing(label, abscissa,
                                  "its intensity series failed: " + series.failure);
  }
  if (!series.converged) {
    return RelationPoint::Missing(label, abscissa,
                                  "its intensity series' MCMC did not converge (see "
                                  "the series' fit report)");
  }
  if (series.ccd_split_unidentified) {
    return RelationPoint::Missing(
        label, abscissa,
        "CCD widths not identified: the intensity series is at one focus with a Gaussian "
        "defocus and no through-focus series anchors it (docs/trust.md)");
  }
  auto draws = series.draws.find(intrinsic ? SettingIntrinsicDrawKey(label, metric)
                                           : SettingDrawKey(label, metric));
  if (draws == series.draws.end()) {
    return RelationPoint::Missing(label, abscissa, "no draws of its intensity series (MCMC off)");
  }
  RelationPoint p = RelationPoint::FromDraws(label, abscissa, draws->second);
  p.joint_set = 0;
  return p;
}

}  // namespace

bool ComputeTrend(std::vector<GroupResult> groups, const TrendOptions& options,
                  TrendResult* result, std::string* error) {
  if (!options.relation.IsValid(error)) return false;
  if (!(options.reference_intensity_e > 0) || !(options.reference_wavelength_nm > 0) ||
      !(options.intensity_tolerance > 0)) {
    *error = "trend: the reference intensity, wavelength and intensity tolerance must be > 0";
    return false;
  }
  *result = TrendResult();
  result->groups = std::move(groups);
  const std::vector<GroupResult>& all = result->groups;
  const std::vector<std::string>& metrics = TrendMetricNames();
  const double i0 = options.reference_intensity_e;

  // Groups by wavelength (single-focus settings and through-focus series); groups of unknown
  // wavelength fit nowhere.
  std::map<double, std::vector<const GroupResult*>> by_wavelength;
  // Intensity series (intensity_series.h) by wavelength: not settings, but the source of
  // their settings' CCD-only intensity relations.
  std::map<double, const GroupResult*> series_at;
  for (const GroupResult& g : all) {
    if (g.group.intensity_series) {
      series_at[g.group.wavelength_nm] = &g;
      continue;
    }
    if (!std::isfinite(g.group.wavelength_nm)) {
      result->notes.push_back(g.group.name + " is in no relation: " + g.failure);
      continue;
    }
    by_wavelength[g.group.wavelength_nm].push_back(&g);
  }
  // The groups of `list` that measure `metric` (see the top of trend.h).
  auto measuring = [](const std::vector<const GroupResult*>& list, const std::string& metric) {
    std::vector<const GroupResult*> out;
    for (const GroupResult* g : list) {
      if (MeasuresMetric(*g, metric)) out.push_back(g);
    }
    return out;
  };

  // Intensity relations.
  double main_wavelength = NAN;
  size_t most = 0;
  for (const auto& [wavelength, list] : by_wavelength) {
    if (list.size() > most) {
      most = list.size();
      main_wavelength = wavelength;
    }
  }
  auto ref = by_wavelength.find(options.reference_wavelength_nm);
  if (ref != by_wavelength.end() && ref->second.size() >= 2) {
    main_wavelength = options.reference_wavelength_nm;
  }
  result->intensity_wavelength_nm = main_wavelength;
  result->intensity_series_effect = options.intensity_series_effect;
  for (const auto& [wavelength, all_here] : by_wavelength) {
    const bool main = wavelength == main_wavelength;
    for (const std::string& metric : metrics) {
      const std::vector<const GroupResult*> list = measuring(all_here, metric);
      if (!main && list.size() < 2) continue;
      std::vector<RelationPoint> points;
      auto series = series_at.find(wavelength);
      const std::vector<std::string> members = series != series_at.end() && IsCcdOnlyMetric(metric)
                                                   ? SeriesMembers(series->second->group)
                                                   : std::vector<std::string>();
      for (const GroupResult* g : list) {
        const bool in_series =
            std::find(members.begin(), members.end(), g->group.name) != members.end();
        points.push_back(in_series ? SeriesPoint(*series->second, g->group.name,
                                                 NominalOrMeasuredPeak(*g), metric)
                                   : PointOf(*g, metric, NominalOrMeasuredPeak(*g)));
      }
      auto fit = FitRelation(RelationKind::kLinear, points, options.relation, error);
      if (!fit) return false;
      const std::string name = RelationName(metric, RelationKind::kLinear);
      if (main && !members.empty()) {
        // The intrinsic kernel's relation: the same settings, their points the series' kernel
        // at zero signal (settings outside the series have no intrinsic kernel: gaps).
        std::vector<RelationPoint> intrinsic;
        for (const GroupResult* g : list) {
          const bool in_series =
              std::find(members.begin(), members.end(), g->group.name) != members.end();
          intrinsic.push_back(
              in_series ? SeriesPoint(*series->second, g->group.name, NominalOrMeasuredPeak(*g),
                                      metric, true)
                        : RelationPoint::Missing(g->group.name, NominalOrMeasuredPeak(*g),
                                                 "not in the intensity series: its fit has no "
                                                 "kernel at zero signal"));
        }
        auto zero = FitRelation(RelationKind::kLinear, intrinsic, options.relation, error);
        if (!zero) return false;
        result->relations_intrinsic[name] = std::move(*zero);
      }
      if (main) {
        result->relations[name] = std::move(*fit);
      } else {
        result->intensity_by_wavelength[wavelength][name] = std::move(*fit);
      }
    }
  }
  if (std::isfinite(main_wavelength)) {
    const size_t n = by_wavelength[main_wavelength].size();
    if (n < 2) {
      result->notes.push_back("no wavelength has two or more intensity settings: the intensity "
                              "relations cannot be fitted");
    } else if (main_wavelength != options.reference_wavelength_nm) {
      result->notes.push_back("the intensity relations are measured at " +
                              Format(main_wavelength) + " nm (no " +
                              Format(options.reference_wavelength_nm) +
                              " nm intensity series)");
    }
  }
  for (const auto& [wavelength, list] : by_wavelength) {
    if (list.size() == 1 && wavelength != main_wavelength) {
      result->notes.push_back(Format(wavelength) +
                              " nm has a single intensity setting: no intensity relation there");
    }
  }

  // Wavelength relations: one point per wavelength and metric, nearest I0; for a CCD-only
  // metric a through-focus series within the tolerance comes first (its CCD widths are
  // identified, a single-focus setting's only in sum with the defocus).
  std::vector<std::string> uncorrected;
  std::set<std::string> used_for_wavelength;
  for (const std::string& metric : metrics) {
    auto it = result->relations.find(RelationName(metric, RelationKind::kLinear));
    // A correction from a relation the data barely constrain would inject its spread (its
    // draws can even change sign); such points are used as measured.
    const RelationFit* intensity = it != result->relations.end() && it->second.fitted &&
                                           !it->second.HasFlag(kFlagPoorlyConstrained)
                                       ? &it->second
                                       : nullptr;
    if (options.correct_to_reference_intensity && intensity == nullptr) {
      uncorrected.push_back(metric);
    }
    std::vector<RelationPoint> points;
    for (const auto& [wavelength, all_here] : by_wavelength) {
      std::string why_none;
      const GroupResult* g = NearestReference(measuring(all_here, metric), options, &why_none);
      if (g == nullptr) {
        points.push_back(RelationPoint::Missing(Format(wavelength) + " nm", wavelength, why_none));
        continue;
      }
      used_for_wavelength.insert(g->group.name);
      RelationPoint p = PointOf(*g, metric, wavelength);
      const double peak = NominalOrMeasuredPeak(*g);
      if (options.correct_to_reference_intensity && intensity != nullptr &&
          !p.draws.empty() && std::isfinite(peak)) {
        // (A bound-only point's draws are corrected too: they give its upper limit.)
        const std::vector<double> at_i0 = intensity->ValueDraws(i0);
        const std::vector<double> at_i = intensity->ValueDraws(peak);
        for (size_t j = 0; j < p.draws.size(); ++j) {
          const size_t r = j % at_i0.size();
          p.draws[j] *= at_i0[r] / at_i[r];
        }
      }
      points.push_back(std::move(p));
    }
    auto fit = FitRelation(RelationKind::kPowerLaw, points, options.relation, error);
    if (!fit) return false;
    result->relations[RelationName(metric, RelationKind::kPowerLaw)] = std::move(*fit);
  }
  for (const auto& [wavelength, list] : by_wavelength) {
    for (const GroupResult* g : list) {
      if (used_for_wavelength.count(g->group.name) > 0) {
        result->wavelength_groups.push_back(g->group.name);
      }
    }
  }
  if (options.correct_to_reference_intensity) {
    if (uncorrected.size() < metrics.size()) {
      result->notes.push_back(
          "wavelength points are corrected to I0 = " + Format(i0, 7) + " e- with the " +
          Format(result->intensity_wavelength_nm) +
          " nm intensity relation of each metric, draw by draw (paper section 4.4's assumption "
          "that the intensity dependence does not change with wavelength)");
    }
    if (!uncorrected.empty()) {
      std::string list;
      for (const std::string& m : uncorrected) list += (list.empty() ? "" : ", ") + m;
      result->notes.push_back("used at their measured intensity, not corrected to I0 (no "
                              "well-constrained intensity relation): " + list);
    }
  }
  std::string series, anchored;
  int unidentified = 0;
  for (const GroupResult& g : all) {
    if (g.group.intensity_series) continue;
    if (g.group.focus_series) series += (series.empty() ? "" : ", ") + g.group.name;
    if (g.ok && g.ccd_split_unidentified) ++unidentified;
    if (g.ok && g.group.defocus_anchor) {
      anchored += (anchored.empty() ? "" : ", ") + g.group.name;
    }
  }
  for (const auto& [wavelength, is] : series_at) {
    std::string members;
    for (const std::string& m : SeriesMembers(is->group))
      members += (members.empty() ? "" : ", ") + m;
    result->notes.push_back(
        "at " + Format(wavelength) +
        " nm the CCD-only intensity relations are those of the "
        "intensity series " +
        is->group.name + " (" + members +
        " fitted jointly with the brighter-fatter slope, sharing the CCD kernel and " +
        (is->group.focus_series ? std::string("the focus law rate |z - z0|")
                                : std::string("the defocus")) +
        ": the settings are assumed to share the optics and the focus), resampled "
        "state by state (flag joint_points); each setting is also fitted alone without the "
        "slope, for the total_* relations and the wavelength relations");
  }
  if (!anchored.empty()) {
    result->notes.push_back(
        "single-focus settings with an anchored defocus (" + anchored +
        ") are in the CCD-only relations with the CCD widths their anchored defocus leaves "
        "(docs/trust.md, anchoring the defocus)");
  }
  if (unidentified > 0) {
    result->notes.push_back(
        std::to_string(unidentified) +
        " single-focus setting(s) measure only the total widths (integrated sampling, Gaussian "
        "defocus: the defocus takes any share of them) and are gaps in the CCD-only relations; " +
        (series.empty() ? std::string("with no through-focus series in the campaign those "
                                      "relations have no points. Take a through-focus series at "
                                      "the settings to measure the CCD kernel")
                        : std::string("the through-focus series give those relations their "
                                      "points")));
  }
  if (!series.empty()) {
    result->notes.push_back(
        "through-focus series (" + series +
        ") are in the relations of the CCD-only metrics, "
        "with their identified CCD widths, and not in the total_* ones: a series' total PSF is "
        "the one at best focus, not the defocused spot of the single-focus settings");
  }
  result->requirements = EvaluateRequirements(options.requirements, result->relations, i0);
  for (const GroupResult& g : result->groups) {
    if (!g.group.focus_series || g.group.intensity_series || !g.ok) continue;
    for (const Requirement& req : options.requirements) {
      if (req.target != Requirement::Target::kMetricAt ||
          !(std::fabs(req.wavelength_nm - g.group.wavelength_nm) <= 0.5)) {
        continue;
      }
      const auto draws = g.draws.find(req.metric);
      RequirementResult res;
      if (draws == g.draws.end()) {
        res = EvaluateRequirementOnDraws(req, {});
        res.reason += " (MCMC off)";
      } else if (!g.converged) {
        res.requirement = req;
        res.reason = "its MCMC did not converge (see the group's fit report)";
      } else {
        res = EvaluateRequirementOnDraws(req, draws->second);
      }
      res.notes.push_back("on " + g.group.name + "'s own posterior, at its peak " +
                          Format(g.peak_e.median) + " e-, not corrected to I0 = " + Format(i0) +
                          " e-");
      result->focus_requirements.push_back({g.group.name, std::move(res)});
    }
  }
  return true;
}

}  // namespace ccdpsf::trend
