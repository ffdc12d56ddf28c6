// The intensity plot of a joint fit with brighter_fatter or boundary_shift (fit_report.h
// writes it as intensity.png/.pdf/.svg with its gnuplot script and data).
//
// Abscissa: the peak pixel [e-]. Ordinate: the kernel width [px] in x and y, the CCD widths
// where the fit identifies them, else the total widths (sqrt(defocus^2 + sigma^2); at one
// focus with a Gaussian defocus only those are identified). Drawn (intensity_points.h):
//   - the predicted width against signal: the brightest exposure's spot with its flux scaled,
//     its affected widths (affected_widths.h) as the posterior median with the central 68 %
//     band (at the MAP without MCMC);
//   - each exposure fitted alone without the effect: MAP +- Laplace sd;
//   - the intrinsic width (the fit's widths at zero signal, posterior median, else the MAP)
//     as a flat line per axis.
#ifndef CCDPSF_FIT_INTENSITY_PLOT_H_
#define CCDPSF_FIT_INTENSITY_PLOT_H_

#include <string>

#include "ccdpsf/fit/intensity_points.h"
#include "ccdpsf/plot.h"

namespace ccdpsf::fit {

// Writes the plot of `points` into `dir` under `stem`. False with a one-line reason when
// there is nothing to draw (no effect, or no finite curve node) or the files cannot be
// written; a picture gnuplot could not make is reported in *result, as for every plot.
bool WriteIntensityPlot(const std::string& dir, const std::string& stem,
                        const IntensityPoints& points, const PlotOptions& options,
                        PlotResult* result, std::string* error);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_INTENSITY_PLOT_H_
