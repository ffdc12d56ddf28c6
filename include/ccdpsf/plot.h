// The plots of the fit and trend reports, drawn by gnuplot.
//
// Every plot is three kinds of file in one output folder, all written atomically:
//   STEM*.dat   the numbers drawn, as whitespace-separated text; '#' lines name the columns
//               and their units; blocks separated by two blank lines are gnuplot's `index`es;
//               "NaN" marks a missing value;
//   STEM.gp     a self-contained gnuplot script that reads the .dat files by relative path, so
//               `cd DIR && gnuplot STEM.gp` remakes the picture after a user edits the styles
//               (line styles, palettes and sizes are set near its top; `gnuplot -e
//               "plot_format='pdf'" STEM.gp` makes another format);
//   STEM.EXT    the picture, made by running that script, in the format of
//               PlotOptions::format: .png (pngcairo terminal when gnuplot has it, else png),
//               .pdf (pdfcairo) or .svg (svg). Its first bytes are checked against the format
//               (PNG signature, "%PDF", "<svg" or "<?xml") before it is kept.
//
// Failure has two tiers. Bad input (sizes that disagree, empty names, a stem that is not a
// plain file name, a folder that cannot be created or written) returns false with a one-line
// reason in *error and may leave nothing behind. A missing or failing gnuplot is not an error:
// the data and script are still written, the function returns true, and PlotResult says that
// the picture was not made and why, for the caller to pass on as a warning. A picture left by
// an earlier run under the same name is then removed, so that it is never mistaken for a
// picture of the new data.
//
// Text (titles, labels, parameter names) is printed literally: gnuplot's "enhanced" markup is
// off, so x_px_0 shows as typed.
#ifndef CCDPSF_PLOT_H_
#define CCDPSF_PLOT_H_

#include <string>
#include <vector>

#include "ccdpsf/image.h"

namespace ccdpsf {

// The picture's file format.
enum class PlotFormat { kPng, kPdf, kSvg };

// "png", "pdf", "svg": the file extension and the name the --plot_format flag takes.
const char* PlotFormatName(PlotFormat format);

// Reads a --plot_format value (exactly "png", "pdf" or "svg"); false with a one-line reason
// naming the accepted values otherwise.
bool ParsePlotFormat(const std::string& text, PlotFormat* format, std::string* error);

// How gnuplot is run.
struct PlotOptions {
  PlotFormat format = PlotFormat::kPng;
  // The gnuplot program: a name looked up on $PATH, or a path containing '/'. Empty means
  // $CCDPSF_GNUPLOT when that environment variable is set, else "gnuplot". Tests (and users
  // without a working gnuplot) point it at a program that does not exist to exercise the
  // "no PNG" path.
  std::string gnuplot_path;
  // Longest time one gnuplot run may take before it is killed and the picture reported as
  // not made [s].
  double timeout_s = 120.0;
  // False: the data files and the script are written but gnuplot is not run (a picture
  // nobody asked for costs more than the fit it shows: trend's --group_plots). PlotResult's
  // message then says how to make it.
  bool draw = true;
};

// What a plot call produced. Paths are `dir + "/" + file name`.
struct PlotResult {
  bool image_written = false;
  std::string image_path;  // STEM.png / .pdf / .svg; set whether or not it was made
  std::string script_path;
  std::vector<std::string> data_paths;  // the .dat files the script reads
  // When image_written is false: one line saying why (not asked for, gnuplot not found, its
  // exit status and last error lines, a time-out) and how to make the picture by hand, e.g.
  // "gnuplot ('gnuplot') was not found; data and script are in DIR: run 'gnuplot corner.gp'
  // there to make corner.png". When true: empty, or "gnuplot warnings: ..." if it printed any.
  std::string message;
};

// True when the gnuplot chosen as in PlotOptions::gnuplot_path can be found and answers
// `gnuplot --version`. Runs it each time it is called (~10 ms).
bool GnuplotAvailable(const std::string& gnuplot_path = "");

// ---------------------------------------------------------------------------------------------
// Corner plot of posterior samples.
//
// Lower triangle of a dim x dim grid (~200 px per panel; smaller beyond 10 parameters).
// Diagonal: histogram of each parameter (all samples, density-normalised), the MAP as a red
// vertical line, the Laplace approximation N(map_k, cov_kk) as a red curve where its sd is
// finite and positive (clipped at the top when far narrower than the histogram: that is the
// look of a falsely small Laplace uncertainty). Off-diagonal (x = column parameter, y = row
// parameter): the samples as translucent points (thinned to at most 5000 by taking every
// ceil(N/5000)-th), the MAP as a red point, and the Laplace ellipses enclosing 68% and 95% of
// the 2-D Gaussian with the 2x2 sub-covariance, i.e. Mahalanobis radius sqrt(-2 ln(1 - p)) =
// 1.510 and 2.448, drawn only when both sds are finite and the 2x2 block is positive definite.
// True values, when given, are blue lines. The parameters without a Laplace sd are named under
// the title.
struct CornerPlotInput {
  std::vector<std::string> names;  // dim parameter names (units in the names: x_px, flux_e)
  int num_samples = 0;
  std::vector<double> samples;  // num_samples x dim, row-major; all finite
  std::vector<double> map;      // empty, or dim values (NaN: no MAP marker for that one)
  // Empty, or dim x dim row-major; NaN (or a non-positive variance) where undefined.
  std::vector<double> laplace_covariance;
  std::vector<double> truth;  // empty, or dim values (NaN: unknown for that one)
  std::string title;
};

// Writes STEM_samples.dat (the thinned samples), STEM_hist.dat (one histogram per parameter),
// STEM_summary.dat (name, MAP, Laplace sd, truth, axis range per parameter),
// STEM_ellipses.dat (when any ellipse is drawn), STEM.gp and STEM.png into `dir` (created if
// needed). `result` may be null.
bool WriteCornerPlot(const std::string& dir, const std::string& stem, const CornerPlotInput& input,
                     PlotResult* result, std::string* error,
                     const PlotOptions& options = PlotOptions());

// ---------------------------------------------------------------------------------------------
// Data / model / residual / normalised-residual maps, one row of four panels per exposure
// (~250 px per panel), each with its colour box. Axes are pixel coordinates (pixel centres at
// integers, y upwards, as ds9 shows FITS). Data and model share one colour range per exposure
// on an asinh stretch, colour = asinh(value / b) with softening b (linear within a few b of
// zero, logarithmic above, so the faint wings show beside the peak; the colour bar is
// labelled in the image's unit and names the stretch and b). The residual has a symmetric
// range (+- its largest absolute value) and the normalised residual the fixed range -5..5,
// both on a diverging blue-white-red palette with white at zero. Non-finite pixels (masked)
// are drawn grey. Setting `data_stretch = 'linear'` or `'log'` near the top of the script (or
// `data_log = 1`, as before) shows data and model on that scale instead.
struct StampPanels {
  std::string title;  // e.g. "exposure 0: spot_800nm_01.fits"
  Image data;         // all four the same size, in `unit` except `normalised`
  Image model;
  Image residual;           // data - model
  Image normalised;         // (data - model) / sigma, dimensionless
  std::string unit = "e-";  // unit of data, model and residual, for labels and the .dat header
  // Frame coordinates of stamp pixel (0, 0), so that the axes show frame pixels.
  int origin_x = 0;
  int origin_y = 0;
  // The asinh softening b [unit]: the noise sd of an empty pixel is a good choice (noise then
  // spans about one colour step, and everything brighter is on a log-like scale). Not finite
  // or <= 0: 1e-3 of the largest data or model value.
  double asinh_softening = NAN;
};

// Writes STEM_000.dat, STEM_001.dat, ... (one per exposure: x_px, y_px, data, model,
// residual, normalised), STEM.gp and STEM.png into `dir`. `result` may be null.
bool WriteResidualMaps(const std::string& dir, const std::string& stem,
                       const std::vector<StampPanels>& exposures, PlotResult* result,
                       std::string* error, const PlotOptions& options = PlotOptions());

// ---------------------------------------------------------------------------------------------
// A generic x-y plot: point series with optional error bars and upper limits, model curves,
// and horizontal requirement lines (dashed red, labelled at their right end). Series k and
// curve k share colour k (red is kept for requirements), so a series and the model fitted to
// it match. The axis ranges are chosen to show every point, error bar, limit, curve and
// requirement with a 5% margin (in log space on log axes). All values must be finite; on a
// log axis the points, limits, curves and requirement values must be positive, but a lower
// error bound <= 0 is allowed (its bar runs to the bottom of the plot).
struct Series {
  std::string label;  // key entry; empty: none
  std::vector<double> x, y;
  // Empty, or one absolute bound per point with y_lo <= y <= y_hi (not error sizes: for
  // y +- e pass y - e and y + e).
  std::vector<double> y_lo, y_hi;
  // Settings known only to lie below a value: each a downward arrow from (limit_x, limit_y),
  // 4 % of the plot's height long, in the series' colour. A series needs points or limits.
  std::vector<double> limit_x, limit_y;
  std::string limit_label;  // key entry of the arrows; empty: none
};
struct Curve {
  std::string label;  // key entry; empty: none
  std::vector<double> x, y;
  // Empty, or a band per point (y_lo <= y <= y_hi), e.g. the relation's 68 % interval: filled
  // in the curve's colour, translucent, behind the points. It has no key entry of its own;
  // say what it is in the curve's label.
  std::vector<double> y_lo, y_hi;
};
// Known true values (simulated data), drawn in black whatever the series' colours: curves
// dashed, points as open diamonds.
struct TruthOverlay {
  std::vector<Curve> curves;  // bands ignored
  std::vector<Curve> points;  // each one key entry (its label) and its points
};
struct HorizontalLine {
  std::string label;
  double y = 0.0;
};
struct XyPlotInput {
  std::string title, x_label, y_label;
  bool log_x = false, log_y = false;
  std::vector<Series> series;
  std::vector<Curve> curves;
  std::vector<HorizontalLine> requirements;
  TruthOverlay truth;
  // Series that share x values would hide each other's points and bars: with a fraction
  // f > 0, the b-th of the m series with points (and its upper limits) is drawn shifted
  // along x by (b - (m - 1) / 2) f of the x axis' width before the shift (everything's span
  // with the 5 % margins; in log space on a log axis); the axis then widens to show the
  // shifted points. The data file keeps each true x beside the drawn one; say so in the
  // caption. f is at most 0.05.
  double dodge_fraction = 0.0;
};

// Writes STEM_series.dat (when there are series), STEM_limits.dat (when a series has upper
// limits), STEM_curves.dat (when there are curves), STEM_truth.dat (when there are truths),
// STEM.gp and the picture into `dir`. At least one series or curve with points is required.
// `result` may be null.
bool WriteXyPlot(const std::string& dir, const std::string& stem, const XyPlotInput& input,
                 PlotResult* result, std::string* error,
                 const PlotOptions& options = PlotOptions());

// ---------------------------------------------------------------------------------------------
// A quantity across the sensor: each fitted spot a filled circle at its frame position
// (drawn 1-based, as DS9 shows pixels), coloured by its value on a colour bar; spots that
// were not fitted as grey crosses. Writes STEM_spots.dat, STEM_refused.dat, STEM.gp and the
// picture. Non-finite values are left out.
struct SensorMapInput {
  std::string title, value_label;
  int nx = 0, ny = 0;               // the frame's size [px]
  std::vector<double> x, y, value;  // frame coordinates (0-based) [px]
  std::vector<double> refused_x, refused_y;
};
bool WriteSensorMap(const std::string& dir, const std::string& stem, const SensorMapInput& input,
                    PlotResult* result, std::string* error,
                    const PlotOptions& options = PlotOptions());

}  // namespace ccdpsf

#endif  // CCDPSF_PLOT_H_
