// What `ccdpsf fit` leaves in its output folder:
//   fit.json        "quality" (the verdict and its reasons, quality.h), parameters, derived
//                   metrics, identifiability, "covariance" (the Laplace covariance of the
//                   constrained parameters: names, matrix), MCMC diagnostics, fit statistics, the
//                   MAP-vs-MCMC comparison, the choices made from the data ("notes"), masked
//                   outliers, and the exposures with every metadata value and its source,
//                   the spot candidates, masks and censoring (written last: its presence
//                   means the folder is complete)
//   residuals.fits  per exposure four image extensions DATA_K, MODEL_K, RESID_K, NRESID_K
//                   [e-, e-, e-, sigma]; masked pixels are NaN
//   chain.fits      binary table CHAIN: walker, step, log_prob, one column per parameter,
//                   then the derived metrics of each draw but peak_e; units in TUNITn;
//                   keywords BURNIN (steps to discard), WALKERS, NSTEPS, NPARAM, NDERIVED,
//                   CONVERGD in the table's header (and the primary's)
//   corner.png / residuals.png, or .pdf / .svg (FitReportOptions::plot.format), with their
//                   .gp scripts and .dat data, for restyling; with a truth (simulated data)
//                   the corner plot marks the true values that map onto fitted parameters
//   report.md       a readable summary linking the plots
#ifndef CCDPSF_FIT_FIT_REPORT_H_
#define CCDPSF_FIT_FIT_REPORT_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/quality.h"
#include "ccdpsf/truth.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::fit {

// Which fit reports get their pictures drawn (fit --plots, trend --group_plots). A single
// exposure's corner and residual pictures take ~0.3 s of gnuplot, several times its fit
// (~0.1 s): most of a batch of separate fits, or of a campaign's groups. Their data and
// gnuplot scripts are written in every case, and report.md says how to draw them.
enum class Pictures {
  kAll,
  kFlagged,  // reports whose verdict is not ok (suspect or invalid), where people look
  kNone,
};
// "all", "flagged", "none"; false for anything else.
bool ParsePictures(const std::string& text, Pictures* pictures);
const char* ToString(Pictures pictures);
// Whether a report with this verdict gets its pictures drawn.
bool DrawsPictures(Pictures pictures, const Quality& quality);

struct FitReportOptions {
  PlotOptions plot;  // the plots' format (and how gnuplot is run, or whether: plot.draw)
  // Why the pictures are not drawn when plot.draw is false, for report.md's sentence.
  std::string plot_reason = "not asked for";
  // Known true values (truth.h), drawn on the corner plot where they map; report.md names
  // the file.
  std::optional<TruthFile> truth;
};

// The fit.json document.
nlohmann::json FitJson(const ExposuresFit& fit);

// Writes everything above into out_dir atomically (staged, fit.json last). `run_record` is
// stored as run.json (resolved options, seed, software versions). Plot failures (no
// gnuplot) are not errors: they are listed in `warnings` and in report.md.
bool WriteFitReport(const std::string& out_dir, const ExposuresFit& fit,
                    const nlohmann::json& run_record, std::vector<std::string>* warnings,
                    std::string* error, const FitReportOptions& options = FitReportOptions());

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_REPORT_H_
