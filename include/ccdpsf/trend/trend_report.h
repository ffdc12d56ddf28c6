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
//   *_vs_wavelength.png, *_vs_intensity.png (+ .gp scripts and .dat data): the paper's
//                     figures, requirement limits in red
//   report.md         a readable report linking all of the above and each group's fit report
#ifndef CCDPSF_TREND_TREND_REPORT_H_
#define CCDPSF_TREND_TREND_REPORT_H_

#include <string>
#include <vector>

#include "ccdpsf/trend/trend.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {

// The trend.json of `result`, for a trend folder `out_dir` (group report folders are
// recorded relative to it).
nlohmann::json TrendJson(const TrendResult& result, const std::string& out_dir);

// Writes the files above into out_dir (staged; trend.json last); run_record goes to
// run.json. Plot failures (no gnuplot) are warnings, not errors.
bool WriteTrendReport(const std::string& out_dir, const TrendResult& result,
                      const nlohmann::json& run_record, std::vector<std::string>* warnings,
                      std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_TREND_REPORT_H_
