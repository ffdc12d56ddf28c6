// The grid's tables, regions and maps (psf_map.h).
#include "ccdpsf/grid/psf_map.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <map>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/column_units.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/model/effects.h"

namespace ccdpsf::grid {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string CsvNumber(double v) {
  if (!std::isfinite(v)) return "";
  char text[64];
  const auto end = std::to_chars(text, text + sizeof(text), v).ptr;
  return std::string(text, end);
}

// A CSV cell: quoted when it holds a comma, quote or line break.
std::string CsvText(const std::string& text) {
  if (text.find_first_of(",\"\n") == std::string::npos) return text;
  std::string out = "\"";
  for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

// Centre and 68 % bounds of a summary: the posterior's with MCMC, else the Laplace interval
// (fit::LaplaceInterval68; for a quantity that cannot be negative, that of its logarithm:
// MAP - sd gave e.g. 0.80 [-0.69, 2.30] um).
void Interval(const fit::Summary& s, bool have_mcmc, bool positive, double* centre, double* lo,
              double* hi) {
  if (have_mcmc && std::isfinite(s.median)) {
    *centre = s.median;
    *lo = s.lo68;
    *hi = s.hi68;
    return;
  }
  *centre = s.map;
  fit::LaplaceInterval68(s.map, s.laplace_sd, positive, lo, hi);
}

// A table as columns, written as FITS and CSV from the same values.
struct Table {
  std::vector<FitsColumn> columns;
  FitsColumn& Number(const std::string& name, bool integer = false) {
    for (FitsColumn& c : columns) {
      if (c.name == name) return c;
    }
    columns.push_back({name, UnitOfName(name), {}, integer, {}});
    return columns.back();
  }
  FitsColumn& Text(const std::string& name) { return Number(name); }
  void Add(const std::string& name, double v, bool integer = false) {
    Number(name, integer).values.push_back(v);
  }
  // FITS text is printable ASCII: anything else (a file name in UTF-8) becomes '?', so that a
  // long run never fails at its last step on a name.
  void AddText(const std::string& name, std::string v) {
    for (char& c : v) {
      if (c < 0x20 || c > 0x7e) c = '?';
    }
    Text(name).texts.push_back(std::move(v));
  }

  std::string Csv() const {
    std::string out;
    for (size_t i = 0; i < columns.size(); ++i) out += (i ? "," : "") + columns[i].name;
    out += "\n";
    const size_t rows = columns.empty() ? 0 : columns[0].Rows();
    for (size_t r = 0; r < rows; ++r) {
      for (size_t i = 0; i < columns.size(); ++i) {
        const FitsColumn& c = columns[i];
        if (i) out += ",";
        if (!c.texts.empty()) {
          out += CsvText(c.texts[r]);
        } else if (c.is_integer) {
          out += std::to_string(std::llround(c.values[r]));
        } else {
          out += CsvNumber(c.values[r]);
        }
      }
      out += "\n";
    }
    return out;
  }
};

std::string Verdict(const SpotEntry& e) {
  if (!e.fitted) return "refused";
  if (!e.fit.ok) return e.fit.quality.Worst() == Severity::kInvalid ? "invalid" : "failed";
  return e.fit.quality.Verdict();
}

std::string Reason(const SpotEntry& e) {
  if (!e.fitted) return e.where.refused + ": " + e.where.reason;
  if (!e.fit.ok) return e.fit.failure;
  std::string why;
  for (const Finding& f : e.fit.quality.findings) {
    if (f.severity == Severity::kNote) continue;
    why += (why.empty() ? "" : "; ") + f.message;
  }
  return why;
}

// A table with no rows still needs one column of the right length (0) per name: FITS
// tables of zero rows are valid, and the reader sees the columns.
bool WriteTable(const std::string& dir, const std::string& stem, const std::string& extname,
                Table& table, const FitsHeader& header, PsfMapOutputs* outputs,
                std::string* error) {
  for (FitsColumn& c : table.columns) {
    // A text column with no rows is written as an empty number column.
    (void)c;
  }
  if (!WriteFitsTable(dir + "/" + stem + ".fits", {}, extname, table.columns, header, error) ||
      !WriteTextFileAtomically(dir + "/" + stem + ".csv", table.Csv(), error)) {
    return false;
  }
  outputs->files.push_back(stem + ".fits");
  outputs->files.push_back(stem + ".csv");
  return true;
}

double Median(std::vector<double> v) {
  v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }), v.end());
  if (v.empty()) return kNaN;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

const std::vector<std::string>& PsfMapMetrics() {
  static const std::vector<std::string> names = {
      "total_fwhm_um",    "total_ellipticity", "total_sigma_x_px",
      "total_sigma_y_px", "fwhm_um",           "ellipticity",
      "r2_px2",           "ccd_sigma_x_px",    "ccd_sigma_y_px"};
  return names;
}

std::vector<std::string> EffectParameterNames(const std::vector<fit::FitEffect>& effects) {
  std::vector<std::string> names;
  for (const model::EffectInfo& info : model::EffectCatalogue()) {
    const bool fitted = std::any_of(effects.begin(), effects.end(),
                                    [&](const fit::FitEffect& e) { return e.kind == info.kind; });
    if (!fitted) continue;
    for (const model::EffectParameterInfo& q : info.parameters) {
      names.push_back(info.name + "." + q.name);
    }
  }
  return names;
}

bool WritePsfMap(const std::string& dir, const GridResult& result,
                 const std::vector<SpotRelation>& relations,
                 const std::vector<fit::FitEffect>& effects, bool have_mcmc,
                 const PlotOptions& plot, PsfMapOutputs* outputs, std::string* error) {
  const std::vector<std::string> effect_names = EffectParameterNames(effects);
  const std::string interval =
      have_mcmc ? "posterior median, central 68 % (MCMC)" : "MAP +- Laplace sd (--nomcmc)";
  // psf_map: one row per spot.
  Table map;
  for (const SpotEntry& e : result.spots) {
    const trend::CampaignGroup& setting = result.settings[e.setting];
    map.AddText("setting", setting.name);
    map.Add("spot", e.spot, true);
    map.AddText("segment", e.segment.empty() ? "0" : e.segment);
    map.Add("x_px", e.where.x_px);
    map.Add("y_px", e.where.y_px);
    map.Add("wavelength_nm", setting.wavelength_nm);
    map.Add("focus_series", setting.focus_series ? 1 : 0, true);
    map.Add("exposures", static_cast<double>(setting.files.size()), true);
    const bool ok = e.fitted && e.fit.ok;
    for (const std::string& m : PsfMapMetrics()) {
      double c = kNaN, lo = kNaN, hi = kNaN;
      if (ok) {
        const auto it = e.fit.summaries.find(m);
        if (it != e.fit.summaries.end()) Interval(it->second, have_mcmc, true, &c, &lo, &hi);
      }
      map.Add(m, c);
      map.Add(m + "_lo68", lo);
      map.Add(m + "_hi68", hi);
    }
    for (const std::string& name : effect_names) {
      double c = kNaN, lo = kNaN, hi = kNaN;
      if (ok) {
        const auto it = e.fit.summaries.find(name);
        if (it != e.fit.summaries.end()) Interval(it->second, have_mcmc, false, &c, &lo, &hi);
      }
      const std::string column = FitsColumnName(name);
      map.Add(column, c);
      map.Add(column + "_lo68", lo);
      map.Add(column + "_hi68", hi);
    }
    map.Add("chi2_per_dof", ok ? e.fit.chi2_per_dof : kNaN);
    map.AddText("verdict", Verdict(e));
    map.AddText("reason", Reason(e));
  }
  FitsHeader header = {{"INTERVAL", interval, "what _lo68 / _hi68 bound"},
                       {"NSPOTS", static_cast<long long>(result.spots.size()), "spots"}};
  if (!WriteTable(dir, "psf_map", "PSF_MAP", map, header, outputs, error)) return false;

  // catalogue: one row per source per frame.
  Table cat;
  std::vector<std::vector<std::vector<int>>> spot_of(result.frames.size());
  for (size_t s = 0; s < result.frames.size(); ++s) {
    spot_of[s].resize(result.frames[s].size());
    for (size_t e = 0; e < result.frames[s].size(); ++e) {
      spot_of[s][e].assign(result.frames[s][e].sources.size(), -1);
    }
  }
  for (const SpotEntry& e : result.spots) {
    for (size_t k = 0; k < e.where.source.size(); ++k) {
      if (e.where.source[k] >= 0) spot_of[e.setting][k][e.where.source[k]] = e.spot;
    }
  }
  for (size_t s = 0; s < result.frames.size(); ++s) {
    for (size_t e = 0; e < result.frames[s].size(); ++e) {
      const ScannedFrame& f = result.frames[s][e];
      for (size_t k = 0; k < f.sources.size(); ++k) {
        const FrameSource& src = f.sources[k];
        cat.AddText("setting", result.settings[s].name);
        cat.AddText("file", std::filesystem::path(f.path).filename().string());
        cat.Add("exposure", static_cast<double>(e), true);
        cat.Add("spot", spot_of[s][e][k], true);
        cat.Add("x_px", src.x_px);
        cat.Add("y_px", src.y_px);
        cat.Add("peak_x_px", src.shape.peak_x, true);
        cat.Add("peak_y_px", src.shape.peak_y, true);
        cat.Add("peak_adu", src.shape.peak_adu);
        cat.Add("background_adu", src.background_adu);
        cat.Add("significance", src.shape.significance);
        cat.Add("size_px", src.shape.size_px);
        cat.Add("elongation", src.shape.elongation);
        cat.Add("core_fraction", src.shape.core_fraction);
        cat.Add("surround_fraction",
                std::isfinite(src.shape.surround_fraction) ? src.shape.surround_fraction : kNaN);
        cat.Add("single_pixel_fraction", src.single_pixel_fraction);
        cat.AddText("status", src.refused.empty() ? "fittable" : src.refused);
        cat.AddText("reason", src.reason);
      }
    }
  }
  if (cat.columns.empty()) {
    // No source at all: the columns still exist, with no rows.
    for (const char* n : {"exposure", "spot"}) cat.Number(n, true);
    for (const char* n : {"x_px", "y_px"}) cat.Number(n);
  }
  if (!WriteTable(dir, "catalogue", "CATALOGUE", cat, {}, outputs, error)) return false;

  // DS9 regions of the spots, 1-based image coordinates.
  std::string reg =
      "# Region file format: DS9 version 4.1\n"
      "# ccdpsf grid: green = fitted (label: spot number), red = not fitted "
      "(label: why). Positions of the first exposure of each setting.\n"
      "global font=\"helvetica 10 normal\"\nimage\n";
  for (const SpotEntry& e : result.spots) {
    char line[256];
    const std::string label =
        e.fitted ? std::to_string(e.spot) : std::to_string(e.spot) + " " + e.where.refused;
    std::snprintf(line, sizeof(line), "circle(%.3f,%.3f,6) # color=%s text={%s}\n",
                  e.where.x_px + 1.0, e.where.y_px + 1.0, e.fitted && e.fit.ok ? "green" : "red",
                  label.c_str());
    reg += line;
  }
  if (!WriteTextFileAtomically(dir + "/spots.reg", reg, error)) return false;
  outputs->files.push_back("spots.reg");

  // Per setting and segment: how many spots were fitted and their median metrics.
  Table seg;
  std::map<std::pair<int, std::string>, std::vector<const SpotEntry*>> by_segment;
  for (const SpotEntry& e : result.spots) by_segment[{e.setting, e.segment}].push_back(&e);
  for (const auto& [key, entries] : by_segment) {
    seg.AddText("setting", result.settings[key.first].name);
    seg.AddText("segment", key.second.empty() ? "0" : key.second);
    int fitted = 0, refused = 0, usable = 0;
    std::map<std::string, std::vector<double>> values;
    for (const SpotEntry* e : entries) {
      fitted += e->fitted;
      refused += !e->fitted;
      if (!e->fitted || !e->fit.ok) continue;
      ++usable;
      for (const std::string& m : PsfMapMetrics()) {
        const auto it = e->fit.summaries.find(m);
        double c = kNaN, lo, hi;
        if (it != e->fit.summaries.end()) Interval(it->second, have_mcmc, true, &c, &lo, &hi);
        values[m].push_back(c);
      }
    }
    seg.Add("spots", static_cast<double>(entries.size()), true);
    seg.Add("fitted", fitted, true);
    seg.Add("usable", usable, true);
    seg.Add("refused", refused, true);
    for (const std::string& m : PsfMapMetrics()) seg.Add("median_" + m, Median(values[m]));
  }
  if (!by_segment.empty()) {
    if (!WriteTextFileAtomically(dir + "/segments.csv", seg.Csv(), error)) return false;
    outputs->files.push_back("segments.csv");
  }

  // Maps of the identified metrics across the sensor, per setting.
  for (size_t s = 0; s < result.settings.size(); ++s) {
    if (result.frames[s].empty()) continue;
    const ScannedFrame& f0 = result.frames[s][0];
    std::vector<std::pair<std::string, std::string>> maps = {
        {"total_fwhm_um", "identified FWHM [um]"}, {"total_ellipticity", "identified ellipticity"}};
    if (result.settings[s].focus_series) {
      maps.push_back({"ccd_sigma_x_px", "CCD sigma_x [px]"});
      maps.push_back({"ccd_sigma_y_px", "CCD sigma_y [px]"});
    }
    for (const std::string& name : effect_names) {
      const std::string unit = UnitOfName(name);
      maps.push_back({name, name + (unit.empty() ? "" : " [" + unit + "]")});
    }
    for (const auto& [metric, label] : maps) {
      SensorMapInput in;
      in.nx = f0.nx;
      in.ny = f0.ny;
      in.value_label = label;
      in.title = result.settings[s].name + ": " + label + " per spot (" + interval + " centre)";
      for (const SpotEntry& e : result.spots) {
        if (e.setting != static_cast<int>(s)) continue;
        const auto it = e.fitted && e.fit.ok ? e.fit.summaries.find(metric) : e.fit.summaries.end();
        if (it == e.fit.summaries.end()) {
          in.refused_x.push_back(e.where.x_px);
          in.refused_y.push_back(e.where.y_px);
          continue;
        }
        double c, lo, hi;
        Interval(it->second, have_mcmc, false, &c, &lo, &hi);  // the centre only
        in.x.push_back(e.where.x_px);
        in.y.push_back(e.where.y_px);
        in.value.push_back(c);
      }
      const std::string stem =
          "map_" + FitsColumnName(metric) +
          (result.settings.size() > 1 ? "_" + std::to_string(s) : std::string());
      PlotResult made;
      if (!WriteSensorMap(dir + "/plots", stem, in, &made, error, plot)) return false;
      if (!made.image_written) outputs->warnings.push_back(made.message);
    }
  }
  if (relations.empty()) return true;

  // Relations per spot across the settings.
  Table rel;
  SensorMapInput alpha_map;
  alpha_map.nx = result.frames[0].empty() ? 0 : result.frames[0][0].nx;
  alpha_map.ny = result.frames[0].empty() ? 0 : result.frames[0][0].ny;
  alpha_map.value_label = "alpha of the identified FWHM";
  alpha_map.title = "alpha of total_fwhm_um = a lambda^alpha per spot (median)";
  for (const SpotRelation& r : relations) {
    rel.Add("track", r.track, true);
    rel.Add("x_px", r.x_px);
    rel.Add("y_px", r.y_px);
    rel.AddText("metric", r.metric);
    rel.AddText("relation", trend::RelationName(r.metric, r.kind));
    rel.Add("wavelength_nm", r.wavelength_nm);
    std::string spots;
    for (int s : r.spots) spots += (spots.empty() ? "" : " ") + std::to_string(s);
    rel.AddText("spots", spots);
    rel.Add("n_points", static_cast<double>(r.fit.points.size()), true);
    rel.Add("n_gaps", static_cast<double>(r.fit.gaps.size()), true);
    const bool power = r.kind == trend::RelationKind::kPowerLaw;
    for (const char* name : {"alpha", "slope_per_e", "value_at_pivot"}) {
      const std::string key = std::string(name) == "slope_per_e" ? "slope" : name;
      const trend::Coefficient* c = r.fit.Find(key);
      const bool here = c != nullptr && (key == "value_at_pivot" || (key == "alpha") == power);
      rel.Add(name, here ? c->estimate.median : kNaN);
      rel.Add(std::string(name) + "_lo68", here ? c->estimate.lo68 : kNaN);
      rel.Add(std::string(name) + "_hi68", here ? c->estimate.hi68 : kNaN);
    }
    rel.Add("pivot", r.fit.pivot);
    rel.Add("chi2_per_dof", r.fit.dof > 0 ? r.fit.chi2 / r.fit.dof : kNaN);
    std::string flags;
    for (const trend::RelationFlag& f : r.fit.flags) flags += (flags.empty() ? "" : " ") + f.code;
    rel.AddText("flags", flags);
    if (power && r.metric == "total_fwhm_um") {
      const trend::Coefficient* alpha = r.fit.Find("alpha");
      if (r.fit.fitted && alpha != nullptr && std::isfinite(alpha->estimate.median)) {
        alpha_map.x.push_back(r.x_px);
        alpha_map.y.push_back(r.y_px);
        alpha_map.value.push_back(alpha->estimate.median);
      } else {
        alpha_map.refused_x.push_back(r.x_px);
        alpha_map.refused_y.push_back(r.y_px);
      }
    }
  }
  if (!WriteTable(dir, "spot_relations", "SPOT_RELATIONS", rel,
                  {{"PIVOTWL", trend::kReferenceWavelengthNm, "power-law pivot [nm]"},
                   {"PIVOTI", trend::kReferenceIntensityE, "linear pivot [e-]"}},
                  outputs, error)) {
    return false;
  }
  if (!alpha_map.x.empty() && alpha_map.nx > 0) {
    PlotResult made;
    if (!WriteSensorMap(dir + "/plots", "map_alpha_total_fwhm_um", alpha_map, &made, error, plot)) {
      return false;
    }
    if (!made.image_written) outputs->warnings.push_back(made.message);
  }
  return true;
}

}  // namespace ccdpsf::grid
