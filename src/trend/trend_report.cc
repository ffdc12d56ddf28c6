#include "ccdpsf/trend/trend_report.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/staged_output.h"
#include "ccdpsf/trend/intensity_series.h"
#include "internal/parallel_for.h"

namespace ccdpsf::trend {
namespace {

using nlohmann::json;

json Number(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

json SummaryJson(const fit::Summary& s) {
  return {{"map", Number(s.map)},       {"laplace_sd", Number(s.laplace_sd)},
          {"median", Number(s.median)}, {"lo68", Number(s.lo68)},
          {"hi68", Number(s.hi68)},     {"lo997", Number(s.lo997)},
          {"hi997", Number(s.hi997)}};
}

// `out_dir`: the trend's folder; a group's report folder is recorded relative to it, so the
// record stays right when the folder is moved (or committed from its partial folder).
json GroupJson(const GroupResult& g, const std::string& out_dir) {
  json j = {{"name", g.group.name},
            {"wavelength_nm", Number(g.group.wavelength_nm)},
            {"nominal_peak_e", g.group.nominal_peak_e ? json(*g.group.nominal_peak_e) : json()},
            {"exptime_s", g.group.exptime_s ? json(*g.group.exptime_s) : json()},
            {"focus_series", g.group.focus_series},
            {"files", g.group.files},
            {"ok", g.ok},
            {"failure", g.ok ? json() : json(g.failure)},
            {"warnings", g.warnings},
            {"notes", g.notes},
            {"quality", g.quality.ToJson()},
            {"mcmc_ran", g.mcmc_ran},
            {"mcmc_converged", g.converged},
            {"chi2_per_dof", Number(g.chi2_per_dof)},
            {"seconds", g.seconds},
            {"report",
             g.report_dir.empty()
                 ? json()
                 : json(std::filesystem::path(g.report_dir).lexically_relative(out_dir).string())}};
  j["ccd_widths_identified"] = g.ok ? json(!g.ccd_split_unidentified) : json();
  if (g.group.intensity_series) {
    // intensity_series.h: the member setting of each file.
    j["intensity_series"] = true;
    j["member_settings"] = g.group.member_settings;
  }
  if (g.group.defocus_anchor) {
    const DefocusAnchor& a = *g.group.defocus_anchor;
    j["defocus_anchor"] = {{"series", a.series},
                           {"series_wavelength_nm", Number(a.series_wavelength_nm)},
                           {"focus_position_um", Number(a.focus_position_um)},
                           {"defocus_px", {Number(a.lower_px), Number(a.upper_px)}},
                           {"defocus_median_px", Number(a.median_px)}};
  }
  if (g.ok) {
    j["peak_e"] = SummaryJson(g.peak_e);
    json m = json::object();
    for (const auto& [name, s] : g.summaries) m[name] = SummaryJson(s);
    j["metrics"] = m;
  }
  return j;
}

std::string Fmt(double v, int precision = 4) {
  if (!std::isfinite(v)) return "n/a";
  std::ostringstream out;
  out.precision(precision);
  out << v;
  return out.str();
}

std::string Interval(const Estimate& e, int precision = 4) {
  if (!std::isfinite(e.median)) return "n/a";
  return Fmt(e.median, precision) + " [" + Fmt(e.lo68, precision) + ", " +
         Fmt(e.hi68, precision) + "]";
}

std::string Interval(const fit::Summary& s, int precision = 4) {
  if (std::isfinite(s.median)) {
    return Fmt(s.median, precision) + " [" + Fmt(s.lo68, precision) + ", " +
           Fmt(s.hi68, precision) + "]";
  }
  if (std::isfinite(s.map)) {
    return Fmt(s.map, precision) + " +- " + (std::isfinite(s.laplace_sd) ? Fmt(s.laplace_sd, 2)
                                                                       : std::string("(unconstrained)"));
  }
  return "n/a";
}

// A relation's points as CSV, units in the column names: the group, the abscissa
// (wavelength_nm for a relation with wavelength, peak_e for one with intensity), the metric's
// median, 68 % bounds and sd (named after the metric, e.g. fwhm_um_lo68), the normalised
// residual, used (1: a fitted point; 0: a gap), and a bound-only gap's 95 % upper limit.
std::string RelationCsv(const std::string& relation_name, const RelationFit& fit) {
  const bool wavelength = fit.kind == RelationKind::kPowerLaw;
  const std::string suffix = RelationName("", fit.kind);
  const std::string metric = relation_name.substr(0, relation_name.size() - suffix.size());
  std::ostringstream csv;
  csv.precision(10);
  csv << "group," << (wavelength ? "wavelength_nm" : "peak_e") << "," << metric << "," << metric
      << "_lo68," << metric << "_hi68," << metric << "_sd,normalized_residual,used," << metric
      << "_upper_limit_95\n";
  for (const PointSummary& p : fit.points) {
    csv << p.label << "," << p.abscissa << "," << p.value.median << "," << p.value.lo68 << ","
        << p.value.hi68 << "," << p.value.sd << "," << p.normalized_residual << ",1,\n";
  }
  for (const RelationGap& g : fit.gaps) {
    csv << g.label << "," << g.abscissa << ",,,,,,0,";
    if (std::isfinite(g.upper_limit_95)) csv << g.upper_limit_95;
    csv << "\n";
  }
  return csv.str();
}

// What a plot needs besides its lines: the result, the truth and where the files go.
struct PlotContext {
  const TrendResult* result = nullptr;
  const TrendReportOptions* options = nullptr;
  std::string dir;
  std::vector<std::string>* images = nullptr;       // file names of the pictures made
  std::vector<std::string>* truth_drawn = nullptr;  // what the truth added, for report.md
  std::vector<std::string>* warnings = nullptr;
};

struct PlotLine {
  std::string label;
  std::string relation;  // its name in TrendResult::relations, e.g. "fwhm_um_vs_intensity"
  std::string metric;    // the metric it relates, e.g. "fwhm_um"
};

// The true relation `relation` from a campaign truth's "relations", as a curve over [lo, hi],
// when it holds in the frame the trend plots it in (trend_report.h); else none.
std::optional<Curve> TruthRelationCurve(const PlotContext& ctx, const std::string& relation,
                                        double lo, double hi) {
  if (!ctx.options->truth) return std::nullopt;
  const nlohmann::json& doc = ctx.options->truth->document;
  if (!doc.contains("relations") || !doc["relations"].is_object()) return std::nullopt;
  const nlohmann::json& relations = doc["relations"];
  const bool power =
      relation.size() > 14 && relation.compare(relation.size() - 14, 14, "_vs_wavelength") == 0;
  const std::string suffix = power ? "_vs_wavelength" : "_vs_intensity";
  // The ellipticity is not itself one of the truth's laws: it follows from the x and y FWHM
  // laws, e = |f_x^2 - f_y^2| / (f_x^2 + f_y^2) (e depends on the widths' ratio only).
  const bool ellipticity = relation == "ellipticity" + suffix;
  const std::string law_x = ellipticity ? "fwhm_x_um" + suffix : relation;
  const std::string law_y = ellipticity ? "fwhm_y_um" + suffix : relation;
  for (const std::string& law : {law_x, law_y}) {
    if (!relations.contains(law) || !relations[law].is_object()) return std::nullopt;
  }
  auto number = [](const nlohmann::json& j, const char* key) {
    return j.contains(key) && j[key].is_number() ? j[key].get<double>() : NAN;
  };
  if (power) {
    // Holds at the truth's reference intensity: the trend's wavelength points are corrected
    // to its own I0.
    if (number(relations, "reference_intensity_e") != ctx.options->reference_intensity_e) {
      return std::nullopt;
    }
  } else if (number(relations, "reference_wavelength_nm") != ctx.result->intensity_wavelength_nm) {
    return std::nullopt;  // the truth's intensity relation holds at its reference wavelength
  }
  const nlohmann::json& rx = relations[law_x];
  const nlohmann::json& ry = relations[law_y];
  const double x0 = number(rx, power ? "a" : "intercept"),
               x1 = number(rx, power ? "alpha" : "slope");
  const double y0 = number(ry, power ? "a" : "intercept"),
               y1 = number(ry, power ? "alpha" : "slope");
  for (double v : {x0, x1, y0, y1}) {
    if (!std::isfinite(v)) return std::nullopt;
  }
  if (!(hi > lo)) return std::nullopt;
  auto law = [power](double c0, double c1, double x) {
    return power ? c0 * std::pow(x, c1) : c0 + c1 * x;
  };
  Curve c;
  for (int i = 0; i <= 60; ++i) {
    const double x = lo + (hi - lo) * i / 60.0;
    const double fx = law(x0, x1, x), fy = law(y0, y1, x);
    c.x.push_back(x);
    c.y.push_back(ellipticity ? std::fabs(fx * fx - fy * fy) / (fx * fx + fy * fy) : fx);
  }
  return c;
}

// True values of `metric` of the groups at the intensity relations' wavelength, at their
// nominal peak intensity (the setting the simulation made), from a campaign truth's
// "groups"; empty when there are none.
Curve TruthGroupPoints(const PlotContext& ctx, const std::string& metric) {
  Curve c;
  if (!ctx.options->truth) return c;
  const nlohmann::json& doc = ctx.options->truth->document;
  if (!doc.contains("groups") || !doc["groups"].is_array()) return c;
  for (const nlohmann::json& g : doc["groups"]) {
    // Fields read by type (a truth file is input: json::value() throws on another type).
    if (!g.is_object()) continue;
    auto number = [&g](const char* key) {
      return g.contains(key) && g[key].is_number() ? g[key].get<double>() : NAN;
    };
    if (g.contains("focus_series") && g["focus_series"].is_boolean() &&
        g["focus_series"].get<bool>()) {
      continue;
    }
    const double wavelength = number("wavelength_nm");
    const double peak = number("nominal_peak_e");
    const double value =
        g.contains(metric) && g[metric].is_number() ? g[metric].get<double>() : NAN;
    if (wavelength != ctx.result->intensity_wavelength_nm || !std::isfinite(peak) ||
        !std::isfinite(value)) {
      continue;
    }
    c.x.push_back(peak);
    c.y.push_back(value);
  }
  return c;
}

// Per relation: each setting's point where the fit sees it (fit_centre: the mean of its
// draws in the fitted space, through which the median relation runs) with the central 68 %
// interval of its draws as bars; the relation's pointwise median and 68 % band from its
// resampled draws; requirement lines in red; truths in black.
void PlotFits(const PlotContext& ctx, const std::string& stem, const std::string& title,
              const std::string& x_label, const std::string& y_label,
              const std::vector<PlotLine>& lines, const std::vector<HorizontalLine>& limits,
              bool intensity) {
  XyPlotInput in;
  in.title = title;
  in.x_label = x_label;
  in.y_label = y_label;
  const std::string extension = std::string(".") + PlotFormatName(ctx.options->plot.format);
  double x_lo = NAN, x_hi = NAN;
  for (const PlotLine& line : lines) {
    auto found = ctx.result->relations.find(line.relation);
    const RelationFit* fit = found == ctx.result->relations.end() ? nullptr : &found->second;
    if (fit == nullptr || (fit->points.empty() && fit->gaps.empty())) continue;
    Series s;
    s.label = line.label;
    for (const PointSummary& p : fit->points) {
      const double centre = std::isfinite(p.fit_centre) ? p.fit_centre : p.value.median;
      if (!std::isfinite(centre)) continue;
      s.x.push_back(p.abscissa);
      s.y.push_back(centre);
      s.y_lo.push_back(std::isfinite(p.value.lo68) ? std::min(p.value.lo68, centre) : centre);
      s.y_hi.push_back(std::isfinite(p.value.hi68) ? std::max(p.value.hi68, centre) : centre);
    }
    // Bound-only settings as upper limits (the axes are linear).
    for (const RelationGap& g : fit->gaps) {
      if (!std::isfinite(g.upper_limit_95) || !std::isfinite(g.abscissa)) continue;
      s.limit_x.push_back(g.abscissa);
      s.limit_y.push_back(g.upper_limit_95);
    }
    if (!s.limit_x.empty()) s.limit_label = line.label + ": 95 % upper limit (bound only)";
    Curve c;
    if (fit->fitted) {
      // The relation's shape coefficient in the key, so the plot carries its headline.
      const Coefficient* shape =
          fit->Find(fit->kind == RelationKind::kPowerLaw ? "alpha" : "slope");
      c.label = line.label + " fit";
      if (shape != nullptr && std::isfinite(shape->estimate.median)) {
        c.label += std::string(fit->kind == RelationKind::kPowerLaw ? " (alpha " : " (slope ") +
                   Interval(shape->estimate, 3) + ")";
      }
      c.label += ", 68 % band";
      const double lo = fit->MinAbscissa(), hi = fit->MaxAbscissa();
      for (int i = 0; i <= 40; ++i) {
        const double x = lo + (hi - lo) * i / 40.0;
        const Estimate e = SummarizeDraws(fit->ValueDraws(x));
        if (!std::isfinite(e.median) || !std::isfinite(e.lo68) || !std::isfinite(e.hi68)) continue;
        c.x.push_back(x);
        c.y.push_back(e.median);
        c.y_lo.push_back(std::min(e.lo68, e.median));
        c.y_hi.push_back(std::max(e.hi68, e.median));
      }
    }
    // Series k and curve k share a colour, so they stay paired: a relation that was not
    // fitted gets a one-point curve (which draws nothing) and no key entry.
    if (s.x.empty() && s.limit_x.empty()) continue;
    if (c.x.empty()) {
      c = Curve();
      c.x = {s.x.empty() ? s.limit_x[0] : s.x[0]};
      c.y = {s.x.empty() ? s.limit_y[0] : s.y[0]};
    }
    for (double x : s.x) {
      x_lo = std::isnan(x_lo) ? x : std::min(x_lo, x);
      x_hi = std::isnan(x_hi) ? x : std::max(x_hi, x);
    }
    in.series.push_back(std::move(s));
    in.curves.push_back(std::move(c));
  }
  bool any = false;
  for (const Series& s : in.series) any = any || !s.x.empty() || !s.limit_x.empty();
  if (!any) return;
  in.requirements = limits;
  in.dodge_fraction = in.series.size() > 1 ? 0.012 : 0.0;
  // Truths: the true relation where the truth has it in this frame, else (intensity plots)
  // the groups' true values.
  for (const PlotLine& line : lines) {
    const std::string label = "truth: " + line.label;
    if (auto curve = TruthRelationCurve(ctx, line.relation, x_lo, x_hi)) {
      curve->label = label + " relation";
      in.truth.curves.push_back(std::move(*curve));
      ctx.truth_drawn->push_back(stem + ": " + line.relation + " (true relation)");
    } else if (intensity) {
      Curve points = TruthGroupPoints(ctx, line.metric);
      if (!points.x.empty()) {
        points.label = label + " (at nominal peak)";
        in.truth.points.push_back(std::move(points));
        ctx.truth_drawn->push_back(stem + ": " + line.metric + " of the groups (true values)");
      }
    }
  }
  PlotResult plot;
  std::string error;
  if (!WriteXyPlot(ctx.dir, stem, in, &plot, &error, ctx.options->plot)) {
    ctx.warnings->push_back(stem + extension + " not made: " + error);
  } else if (!plot.image_written) {
    ctx.warnings->push_back(stem + extension + " not made: " + plot.message);
  } else {
    ctx.images->push_back(stem + extension);
  }
}

double LimitOf(const TrendResult& r, const std::string& metric) {
  for (const RequirementResult& q : r.requirements) {
    if (q.requirement.target == Requirement::Target::kMetricAt && q.requirement.metric == metric) {
      return q.requirement.limit;
    }
  }
  return NAN;
}

}  // namespace

json TrendJson(const TrendResult& r, const std::string& out_dir) {
  json j;
  j["relations"] = json::object();
  for (const auto& [name, fit] : r.relations) j["relations"][name] = ToJson(fit);
  j["intensity_relations_wavelength_nm"] = Number(r.intensity_wavelength_nm);
  // With intensity series (intensity_series.h): the intrinsic kernel's relations, and what
  // the CCD-only relations in "relations" are.
  j["relations_intrinsic"] = json::object();
  for (const auto& [name, fit] : r.relations_intrinsic) j["relations_intrinsic"][name] = ToJson(fit);
  if (r.intensity_series_effect.empty()) {
    j["intensity_kernel"] = nullptr;
  } else {
    const bool paper = r.intensity_series_effect == "brighter_fatter";
    j["intensity_kernel"] = {
        {"effect", r.intensity_series_effect},
        {"relations", paper ? "paper" : "boundary_shift_affected"},
        {"description",
         paper ? "relations.<CCD-only metric>_vs_intensity are the paper's relation: the kernel "
                 "sigma_0 + b I (its empirical brighter-fatter law) at each setting's "
                 "intensity; relations_intrinsic.<metric>_vs_intensity the kernel at zero "
                 "signal, sigma_0"
               : "relations.<CCD-only metric>_vs_intensity are the brighter-fatter-affected "
                 "kernel at each setting's intensity (sqrt(sigma^2 + Delta var), Delta var the "
                 "change of the second central moment the boundary shifts make; "
                 "docs/conventions.md); relations_intrinsic.<metric>_vs_intensity the kernel "
                 "at zero signal"}};
  }
  j["intensity_relations_by_wavelength"] = json::object();
  for (const auto& [wavelength, fits] : r.intensity_by_wavelength) {
    json w = json::object();
    for (const auto& [name, fit] : fits) w[name] = ToJson(fit);
    j["intensity_relations_by_wavelength"][Fmt(wavelength, 6)] = w;
  }
  j["wavelength_relation_groups"] = r.wavelength_groups;
  j["requirements"] = json::array();
  for (const RequirementResult& q : r.requirements) j["requirements"].push_back(ToJson(q));
  j["focus_series_requirements"] = json::array();
  for (const TrendResult::FocusRequirement& q : r.focus_requirements) {
    json e = ToJson(q.result);
    e["group"] = q.group;
    j["focus_series_requirements"].push_back(e);
  }
  j["groups"] = json::array();
  int failed = 0;
  for (const GroupResult& g : r.groups) {
    j["groups"].push_back(GroupJson(g, out_dir));
    failed += g.ok ? 0 : 1;
  }
  j["failed_groups"] = failed;
  j["notes"] = r.notes;
  return j;
}

bool WriteTrendReport(const std::string& out_dir, const TrendResult& r, const json& run_record,
                      std::vector<std::string>* warnings, std::string* error,
                      const TrendReportOptions& options) {
  StagedOutput out;
  if (!out.Begin(out_dir, error)) return false;
  const std::string dir = out.staging_dir();

  // CSV tables.
  std::ostringstream groups_csv;
  groups_csv.precision(10);
  groups_csv << "group,wavelength_nm,nominal_peak_e,exposures,focus_series,ok,peak_e";
  const std::vector<std::string>& metrics = TrendMetricNames();
  for (const std::string& m : metrics) groups_csv << "," << m << "," << m << "_lo68," << m << "_hi68";
  groups_csv << ",chi2_per_dof,mcmc_converged,ccd_widths_identified,defocus_anchor_series,"
                "defocus_anchor_lower_px,defocus_anchor_upper_px,failure\n";
  for (const GroupResult& g : r.groups) {
    groups_csv << g.group.name << "," << g.group.wavelength_nm << ","
               << (g.group.nominal_peak_e ? std::to_string(*g.group.nominal_peak_e) : "") << ","
               << g.exposures << "," << (g.group.focus_series ? 1 : 0) << "," << (g.ok ? 1 : 0)
               << "," << g.peak_e.median;
    for (const std::string& m : metrics) {
      auto s = g.summaries.find(m);
      if (s == g.summaries.end()) {
        groups_csv << ",,,";
      } else {
        groups_csv << "," << s->second.median << "," << s->second.lo68 << "," << s->second.hi68;
      }
    }
    std::string failure = g.failure;
    std::replace(failure.begin(), failure.end(), '"', '\'');
    groups_csv << "," << g.chi2_per_dof << "," << (g.converged ? 1 : 0) << ","
               << (g.ok ? (g.ccd_split_unidentified ? "0" : "1") : "");
    if (g.group.defocus_anchor) {
      const DefocusAnchor& a = *g.group.defocus_anchor;
      groups_csv << "," << a.series << "," << a.lower_px << "," << a.upper_px;
    } else {
      groups_csv << ",,,";
    }
    groups_csv << ",\"" << failure << "\"\n";
  }
  if (!WriteTextFileAtomically(out.Path("groups.csv"), groups_csv.str(), error)) return false;
  for (const auto& [name, fit] : r.relations) {
    if (!WriteTextFileAtomically(out.Path(name + ".csv"), RelationCsv(name, fit), error)) {
      return false;
    }
  }

  // Plots like the paper's figures: gnuplot runs options.threads at a time, each plot with
  // its own lists, joined in this order afterwards (the same report for any thread count).
  std::vector<std::function<void(const PlotContext&)>> plots;
  const double fwhm_limit = LimitOf(r, "fwhm_um");
  const double e_limit = LimitOf(r, "ellipticity");
  std::vector<HorizontalLine> fwhm_lines, e_lines;
  if (std::isfinite(fwhm_limit)) {
    fwhm_lines.push_back({"FWHM requirement: <= " + Fmt(fwhm_limit) + " um", fwhm_limit});
  }
  if (std::isfinite(e_limit)) {
    e_lines.push_back({"ellipticity requirement: <= " + Fmt(e_limit), e_limit});
  }
  const std::string at_i = " at " + Fmt(r.intensity_wavelength_nm) + " nm";
  const std::vector<PlotLine> fwhm_wavelength = {{"FWHM_x", "fwhm_x_um_vs_wavelength", "fwhm_x_um"},
                                                 {"FWHM_y", "fwhm_y_um_vs_wavelength", "fwhm_y_um"},
                                                 {"FWHM", "fwhm_um_vs_wavelength", "fwhm_um"}};
  const std::vector<PlotLine> fwhm_intensity = {{"FWHM_x", "fwhm_x_um_vs_intensity", "fwhm_x_um"},
                                                {"FWHM_y", "fwhm_y_um_vs_intensity", "fwhm_y_um"},
                                                {"FWHM", "fwhm_um_vs_intensity", "fwhm_um"}};
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "fwhm_vs_wavelength", "CCD PSF FWHM vs wavelength (at I0)", "wavelength [nm]",
             "FWHM [um]", fwhm_wavelength, fwhm_lines, false);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "fwhm_vs_intensity", "CCD PSF FWHM vs intensity" + at_i, "peak pixel [e-]",
             "FWHM [um]", fwhm_intensity, fwhm_lines, true);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "r2_vs_wavelength", "CCD PSF R^2 vs wavelength (at I0)", "wavelength [nm]",
             "R^2 [px^2]", {{"R^2", "r2_px2_vs_wavelength", "r2_px2"}}, {}, false);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "r2_vs_intensity", "CCD PSF R^2 vs intensity" + at_i, "peak pixel [e-]",
             "R^2 [px^2]", {{"R^2", "r2_px2_vs_intensity", "r2_px2"}}, {}, true);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "ellipticity_vs_wavelength", "CCD PSF ellipticity vs wavelength (at I0)",
             "wavelength [nm]", "e", {{"e", "ellipticity_vs_wavelength", "ellipticity"}}, e_lines,
             false);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "ellipticity_vs_intensity", "CCD PSF ellipticity vs intensity" + at_i,
             "peak pixel [e-]", "e", {{"e", "ellipticity_vs_intensity", "ellipticity"}}, e_lines,
             true);
  });
  // No requirement line on the totals: they include the defocus.
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "total_fwhm_vs_wavelength",
             "identified (total) FWHM, defocus included, vs wavelength (at I0)", "wavelength [nm]",
             "total FWHM [um]", {{"total FWHM", "total_fwhm_um_vs_wavelength", "total_fwhm_um"}},
             {}, false);
  });
  plots.push_back([=](const PlotContext& ctx) {
    PlotFits(ctx, "total_fwhm_vs_intensity", "identified (total) FWHM vs intensity" + at_i,
             "peak pixel [e-]", "total FWHM [um]",
             {{"total FWHM", "total_fwhm_um_vs_intensity", "total_fwhm_um"}}, {}, true);
  });

  const int n_plots = static_cast<int>(plots.size());
  std::vector<std::vector<std::string>> plot_images(n_plots), plot_truths(n_plots),
      plot_warnings(n_plots);
  internal::ParallelFor(n_plots, std::max(1, options.threads), [&](int i, int) {
    const PlotContext ctx{&r, &options, dir, &plot_images[i], &plot_truths[i], &plot_warnings[i]};
    plots[i](ctx);
  });
  std::vector<std::string> pngs;
  std::vector<std::string> truth_drawn;
  for (int i = 0; i < n_plots; ++i) {
    pngs.insert(pngs.end(), plot_images[i].begin(), plot_images[i].end());
    truth_drawn.insert(truth_drawn.end(), plot_truths[i].begin(), plot_truths[i].end());
    warnings->insert(warnings->end(), plot_warnings[i].begin(), plot_warnings[i].end());
  }

  // report.md
  std::ostringstream md;
  int ok = 0;
  for (const GroupResult& g : r.groups) ok += g.ok ? 1 : 0;
  md << "# ccdpsf trend\n\n";
  md << r.groups.size() << " groups, " << ok << " fitted, " << r.groups.size() - ok
     << " failed. Intervals are central 68 % posterior intervals (propagated from each group's "
        "MCMC draws).\n\n";
  md << "## Requirements\n\n```\n"
     << FormatRequirementTable(r.requirements) << "```\n\n"
     << "pass: by the median. P(pass): the share of the propagated draws that pass. verdict: "
        "pass or fail when P(pass) >= "
     << kSettledProbability << " or <= " << 1.0 - kSettledProbability
     << ", else undetermined (the data do not settle it); n/a when an input is missing, with "
        "the reason.\n\n";
  std::map<std::string, std::vector<RequirementResult>> by_series;
  for (const TrendResult::FocusRequirement& q : r.focus_requirements) {
    by_series[q.group].push_back(q.result);
  }
  for (const auto& [group, results] : by_series) {
    md << "On the through-focus series " << group
       << " (its CCD widths are identified; on its own posterior, at its own intensity, not "
          "corrected to I0):\n\n```\n"
       << FormatRequirementTable(results) << "```\n\n";
  }
  md << "## Relations\n\n";
  md << "| relation | coefficients (median [68 %]) | value at pivot | chi2/dof | points | flags |\n";
  md << "|---|---|---|---|---|---|\n";
  for (const auto& [name, fit] : r.relations) {
    std::string coefficients, pivot;
    for (const Coefficient& c : fit.coefficients) {
      if (c.name == "value_at_pivot") {
        pivot = Interval(c.estimate) + " at " + Fmt(fit.pivot, 6);
      } else {
        coefficients += (coefficients.empty() ? "" : "; ") + c.name + " = " + Interval(c.estimate);
      }
    }
    std::string flags;
    for (const RelationFlag& f : fit.flags) flags += (flags.empty() ? "" : ", ") + f.code;
    md << "| " << name << " | " << coefficients << " | " << pivot << " | "
       << (fit.dof > 0 ? Fmt(fit.chi2 / fit.dof, 3) : std::string("n/a")) << " | "
       << fit.points.size() << (fit.gaps.empty() ? "" : " (+" + std::to_string(fit.gaps.size()) + " gaps)")
       << " | " << (flags.empty() ? "-" : flags) << " |\n";
  }
  md << "\nRelation flags and gaps, in words:\n\n";
  for (const auto& [name, fit] : r.relations) {
    for (const RelationFlag& f : fit.flags) md << "- " << name << ": " << f.reason << "\n";
    for (const RelationGap& g : fit.gaps) {
      md << "- " << name << ": gap at " << g.label << " (" << g.reason;
      if (std::isfinite(g.upper_limit_95)) md << "; 95 % upper limit " << Fmt(g.upper_limit_95, 4);
      md << ")\n";
    }
  }
  if (!r.relations_intrinsic.empty()) {
    md << "\nThe CCD-only intensity relations above are the "
       << (r.intensity_series_effect == "brighter_fatter"
               ? "paper's relation (the kernel sigma_0 + b I of its empirical brighter-fatter "
                 "law at each setting's intensity)"
               : "brighter-fatter-affected kernel at each setting's intensity (boundary "
                 "shifts; sqrt(sigma^2 + Delta var), docs/conventions.md)")
       << ". The intrinsic kernel (at zero signal, shared by the series' settings: its slope "
          "is 0 by the model's construction), trend.json's relations_intrinsic:\n\n"
       << "| relation | intercept | slope | value at pivot |\n|---|---|---|---|\n";
    for (const auto& [name, fit] : r.relations_intrinsic) {
      const Coefficient* intercept = fit.Find("intercept");
      const Coefficient* slope = fit.Find("slope");
      const Coefficient* pivot = fit.Find("value_at_pivot");
      md << "| " << name << " | " << (intercept ? Interval(intercept->estimate) : "-") << " | "
         << (slope ? Interval(slope->estimate) : "-") << " | "
         << (pivot ? Interval(pivot->estimate) : "-") << " |\n";
    }
  }
  if (!r.intensity_by_wavelength.empty()) {
    md << "\nIntensity relations at other wavelengths (FWHM):\n\n";
    for (const auto& [wavelength, fits] : r.intensity_by_wavelength) {
      auto it = fits.find("fwhm_um_vs_intensity");
      if (it == fits.end()) continue;
      const Coefficient* slope = it->second.Find("slope");
      const Coefficient* intercept = it->second.Find("intercept");
      md << "- " << Fmt(wavelength) << " nm: FWHM = " << Interval(intercept->estimate)
         << " um + " << Interval(slope->estimate) << " um/e- x I"
         << (it->second.HasFlag(kFlagPoorlyConstrained) ? " (poorly constrained)" : "") << "\n";
    }
  }
  md << "\n## Plots\n\n";
  md << "Points: each setting where the relation's fit sees it (the mean of its posterior "
        "draws; for the wavelength relations, fitted in log space, their geometric mean), with "
        "the central 68 % interval of the draws as bars; with skewed posteriors this differs "
        "from the medians in the tables. Where several series share a setting they are moved "
        "apart along x by about 1 % of the axis (the .dat files keep the true x). Lines: the "
        "relation's pointwise median with its 68 % band from the resampled fits. Dashed red: "
        "requirements.";
  if (options.truth) {
    md << " Black: true values from " << options.truth->path
       << (truth_drawn.empty() ? " (none maps onto these plots)" : "") << ".";
  }
  md << "\n\n";
  if (options.truth && !truth_drawn.empty()) {
    md << "Truth drawn:\n\n";
    for (const std::string& t : truth_drawn) md << "- " << t << "\n";
    md << "\n";
  }
  for (const std::string& png : pngs) md << "![" << png << "](" << png << ")\n\n";
  md << "## Groups\n\n| group | nm | peak e- | exposures | FWHM um | e | total FWHM um | chi2/dof | status |\n";
  md << "|---|---|---|---|---|---|---|---|---|\n";
  for (const GroupResult& g : r.groups) {
    auto metric = [&](const std::string& m) {
      auto s = g.summaries.find(m);
      return s == g.summaries.end() ? std::string("n/a") : Interval(s->second);
    };
    std::string status = g.ok ? "verdict " + g.quality.Verdict() +
                                    (!g.mcmc_ran || g.converged ? "" : ", MCMC not converged")
                              : "FAILED: " + g.failure;
    if (!g.report_dir.empty()) {
      // Linked relative to report.md's folder, so that the link works wherever the folder is
      // opened or moved (report_dir is as given on the command line, e.g. "out/campaign/...").
      const std::string link =
          (std::filesystem::path(g.report_dir).lexically_relative(out_dir) / "report.md")
              .generic_string();
      status += " ([fit](" + link + "))";
    }
    md << "| " << g.group.name
       << (g.group.focus_series ? " (through focus)"
                                : (g.group.defocus_anchor ? " (defocus anchored)" : ""))
       << " | " << Fmt(g.group.wavelength_nm) << " | " << (g.ok ? Interval(g.peak_e, 6) : "n/a")
       << " | " << g.exposures << " | " << (g.ok ? metric("fwhm_um") : "n/a") << " | "
       << (g.ok ? metric("ellipticity") : "n/a") << " | "
       << (g.ok ? metric("total_fwhm_um") : "n/a") << " | " << Fmt(g.chi2_per_dof, 3) << " | "
       << status << " |\n";
  }
  bool any_focus = false;
  for (const GroupResult& g : r.groups) {
    any_focus = any_focus || (g.ok && g.group.focus_series && !g.group.intensity_series);
  }
  if (any_focus) {
    md << "\n## Through-focus series\n\n"
          "At one focus position a Gaussian defocus and the CCD kernel are not separable "
          "(docs/trust.md, single focus): with `integrated` sampling the groups' CCD-only widths "
          "above rest on the priors. A series through focus, fitted with defocus = rate x "
          "|z - z0| and one CCD kernel, identifies them:\n\n"
          "| group | nm | CCD sigma_x px | CCD sigma_y px | FWHM um | e | defocus rate px/um | "
          "best focus um |\n"
          "|---|---|---|---|---|---|---|---|\n";
    for (const GroupResult& g : r.groups) {
      if (!g.ok || !g.group.focus_series || g.group.intensity_series) continue;
      auto metric = [&](const std::string& m) {
        auto it = g.summaries.find(m);
        return it == g.summaries.end() ? std::string("n/a") : Interval(it->second);
      };
      md << "| " << g.group.name << " | " << Fmt(g.group.wavelength_nm) << " | "
         << metric("ccd_sigma_x_px") << " | " << metric("ccd_sigma_y_px") << " | "
         << metric("fwhm_um") << " | " << metric("ellipticity") << " | "
         << metric("defocus_rate_px_per_um") << " | " << metric("best_focus_um") << " |\n";
    }
  }
  bool any_series = false;
  for (const GroupResult& g : r.groups)
    any_series = any_series || (g.ok && g.group.intensity_series);
  if (any_series) {
    const bool shift = r.intensity_series_effect == "boundary_shift";
    md << "\n## Intensity series (brighter-fatter)\n\n"
       << (shift ? "The settings of one wavelength fitted jointly with the boundary shifts "
                   "(a_ij [1/e-]; docs/conventions.md): the CCD kernel at zero signal sigma_0, "
                   "widened at each setting's signal by the charge it collects. The CCD-only "
                   "intensity relations above are its settings' affected kernels at their "
                   "measured peaks:\n\n"
                   "| group | nm | settings | sigma_0 x px | sigma_0 y px | a_10 1/e- | a_01 1/e- | "
                   "chi2/dof | MCMC |\n"
                 : "The settings of one wavelength fitted jointly with the brighter-fatter slope "
                   "(docs/trust.md, the brighter-fatter slope in a campaign): the CCD kernel at "
                   "zero signal, sigma(I) = sigma_0 + b I with I the peak pixel before the "
                   "growth. The CCD-only intensity relations above are its settings' kernels at "
                   "their measured peaks:\n\n"
                   "| group | nm | settings | sigma_0 x px | sigma_0 y px | b_x px/e- | b_y px/e- | "
                   "chi2/dof | MCMC |\n")
       << "|---|---|---|---|---|---|---|---|---|\n";
    for (const GroupResult& g : r.groups) {
      if (!g.ok || !g.group.intensity_series) continue;
      auto metric = [&](const std::string& m) {
        auto it = g.summaries.find(m);
        return it == g.summaries.end() ? std::string("n/a") : Interval(it->second);
      };
      const std::vector<std::string> settings = SeriesMembers(g.group);
      md << "| " << g.group.name << " | " << Fmt(g.group.wavelength_nm) << " | " << settings.size()
         << " | " << metric("ccd_sigma_x_px") << " | " << metric("ccd_sigma_y_px") << " | "
         << metric(shift ? "boundary_shift.a_10" : "brighter_fatter.slope_x_px_per_e") << " | "
         << metric(shift ? "boundary_shift.a_01" : "brighter_fatter.slope_y_px_per_e") << " | "
         << Fmt(g.chi2_per_dof, 3) << " | "
         << (!g.mcmc_ran   ? "not run"
             : g.converged ? "converged"
                           : "NOT converged")
         << " |\n";
    }
  }
  bool any_warning = false;
  for (const GroupResult& g : r.groups) any_warning = any_warning || !g.warnings.empty();
  if (any_warning) {
    md << "\nWarnings:\n\n";
    for (const GroupResult& g : r.groups) {
      for (const std::string& w : g.warnings) md << "- " << g.group.name << ": " << w << "\n";
    }
  }
  if (!r.notes.empty()) {
    md << "\n## Notes\n\n";
    for (const std::string& n : r.notes) md << "- " << n << "\n";
  }
  md << "\nFiles: trend.json (everything), groups.csv, one CSV per relation, the plots with "
        "their gnuplot scripts (.gp) and data (.dat), run.json (options, seed, versions).\n";
  if (!WriteTextFileAtomically(out.Path("report.md"), md.str(), error)) return false;
  if (!WriteTextFileAtomically(out.Path("run.json"), run_record.dump(2) + "\n", error)) return false;
  if (!WriteTextFileAtomically(out.Path("trend.json"), TrendJson(r, out_dir).dump(2) + "\n", error)) {
    return false;
  }
  return out.Commit({"trend.json"}, error);
}

}  // namespace ccdpsf::trend
