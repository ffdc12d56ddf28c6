// What `ccdpsf trend` leaves in its output folder:
//   trend.json        relations (docs/formats.md, trend: <metric>_vs_wavelength with a, alpha;
//                     <metric>_vs_intensity with intercept, slope; each {median, lo68, hi68}),
//                     intensity relations at other wavelengths, the requirement table, every
//                     group's status and metrics, notes. Written last: its presence means the
//                     folder is complete.
//   groups.csv        one row per group: setting, status, intensity, metrics with intervals
//   <relation>.csv    the points of each relation as fitted (for TOPCAT / astropy): group,
//                     wavelength_nm or peak_e, the metric's median, _lo68, _hi68, _sd,
//                     normalized_residual, used, _upper_limit_95 (units in the names)
//   *_vs_wavelength.png, *_vs_intensity.png, or .pdf / .svg (+ .gp scripts and .dat data):
//                     the paper's figures: each setting's point where the relation's fit
//                     sees it (RelationFit point fit_centre) with its 68 % interval, the
//                     median relation with its 68 % band, requirement limits in red, and
//                     with a truth (simulated campaign) the true relation or values in black
//   report.md         a readable report linking all of the above and each group's fit report
#ifndef CCDPSF_TREND_TREND_REPORT_H_
#define CCDPSF_TREND_TREND_REPORT_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/plot.h"
#include "ccdpsf/trend/trend.h"
#include "ccdpsf/truth.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {

// The trend.json of `result`, for a trend folder `out_dir` (group report folders are
// recorded relative to it).
nlohmann::json TrendJson(const TrendResult& result, const std::string& out_dir);

struct TrendReportOptions {
  PlotOptions plot;  // the plots' format (and how gnuplot is run)
  // A campaign truth (truth.h); report.md names the file. Its relations are drawn where they
  // hold at the trend's own frame: the wavelength relations when its reference intensity is
  // reference_intensity_e (the trend's I0), the intensity relations when its reference
  // wavelength is the intensity relations' wavelength.
  std::optional<TruthFile> truth;
  double reference_intensity_e = kReferenceIntensityE;
  // Plots made at a time (each a gnuplot process); the files and report do not depend on it.
  int threads = 1;
};

// Writes the files above into out_dir (staged; trend.json last); run_record goes to
// run.json. Plot failures (no gnuplot) are warnings, not errors.
bool WriteTrendReport(const std::string& out_dir, const TrendResult& result,
                      const nlohmann::json& run_record, std::vector<std::string>* warnings,
                      std::string* error, const TrendReportOptions& options = TrendReportOptions());

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_TREND_REPORT_H_
