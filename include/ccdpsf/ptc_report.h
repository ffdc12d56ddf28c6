// What `ccdpsf ptc` leaves in its output folder besides ptc.json and ptc.csv (ptc.h):
//   ptc_variance.png      C_00 / mu [ADU] against mu [ADU]: the photon transfer curve's
//                         shape, points with their sampling errors, the fitted model, and
//                         the same model without the a_ij (Poisson and read noise alone);
//   ptc_covariances.png   C_ij / mu [ADU] against mu for the nearest lags (10, 01, 11, 20,
//                         02 within the range), points and model;
//                         each with its .gp script and .dat data (plot.h), or .pdf / .svg;
//   report.md             the results, the model and its units, the pairs, and the plots.
#ifndef CCDPSF_PTC_REPORT_H_
#define CCDPSF_PTC_REPORT_H_

#include <string>
#include <vector>

#include "ccdpsf/plot.h"
#include "ccdpsf/ptc.h"

namespace ccdpsf {

// Writes the plots and report.md into `dir`. A plot that cannot be drawn (no gnuplot) is
// not an error: it is said in `warnings` and in report.md. False with a one-line reason when
// a file cannot be written.
bool WritePtcReport(const std::string& dir, const PtcResult& result,
                    const PlotOptions& plot_options, std::vector<std::string>* warnings,
                    std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_PTC_REPORT_H_
