// The through-focus plot of a through-focus fit (fit_report.h writes it as focus.png/.pdf/.svg
// with its gnuplot script and data).
//
// Abscissa: the stage position z [um]. Ordinate: the total Gaussian width [px] in x and y,
// sqrt(defocus^2 + ccd_sigma^2). Drawn:
//   - the fitted law sqrt(ccd_sigma_x^2 + rate^2 (z - z0)^2) (likewise y): the posterior
//     median over z with its central 68 % band from the post-burn-in MCMC draws (at most
//     kMaxFocusCurveDraws of them, evenly spaced), or the MAP curve without MCMC;
//   - each exposure fitted alone (focus_points.h): MAP +- Laplace sd, free of the law;
//   - with a truth (simulated data, truth.h) whose exposures give focus_position_um and
//     defocus_px and whose CCD widths apply (no injected effects), the true widths in black.
#ifndef CCDPSF_FIT_FOCUS_PLOT_H_
#define CCDPSF_FIT_FOCUS_PLOT_H_

#include <optional>
#include <string>

#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/truth.h"

namespace ccdpsf::fit {

constexpr int kMaxFocusCurveDraws = 1000;

// Writes the plot for `fit` (a through-focus fit with its focus_points) into `dir` under
// `stem`. *truth_drawn says whether true widths were drawn. False with a one-line reason
// when the fit is not a through-focus fit or the files cannot be written; a picture gnuplot
// could not make is reported in *result, as for every plot.
bool WriteFocusPlot(const std::string& dir, const std::string& stem, const ExposuresFit& fit,
                    const std::optional<TruthFile>& truth, const PlotOptions& options,
                    PlotResult* result, bool* truth_drawn, std::string* error);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FOCUS_PLOT_H_
