#include "ccdpsf/plot.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "ccdpsf/atomic_file.h"
#include "internal/subprocess.h"

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---------------------------------------------------------------------------------------------
// Text helpers.

// Shortest text that reads back as exactly `v` (std::to_chars), "NaN" for NaN and +-Inf for
// infinities, which both gnuplot and strtod read.
std::string Num(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "Inf" : "-Inf";
  char buffer[64];
  const auto end = std::to_chars(buffer, buffer + sizeof(buffer), v).ptr;
  return std::string(buffer, end);
}

// `text` on one line: control characters (newlines, tabs) become spaces.
std::string OneLine(const std::string& text) {
  std::string out = text;
  for (char& ch : out) {
    if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) ch = ' ';
  }
  return out;
}

// A gnuplot string literal printing `text` as given. Single-quoted strings process no
// backslash escapes and no macros; a quote inside is written twice.
std::string GpString(const std::string& text) {
  std::string out = "'";
  for (char ch : OneLine(text)) {
    out += ch;
    if (ch == '\'') out += '\'';
  }
  out += "'";
  return out;
}

std::string JoinPath(const std::string& dir, const std::string& name) {
  if (!dir.empty() && dir.back() == '/') return dir + name;
  return dir + "/" + name;
}

// Plot names become file names and appear inside gnuplot strings and on gnuplot's command
// line, so they are kept to a portable, quote-free set.
bool ValidateStem(const std::string& stem, std::string* error) {
  if (stem.empty()) {
    *error = "the plot name (stem) is empty";
    return false;
  }
  if (stem.find('/') != std::string::npos) {
    *error =
        "the plot name '" + OneLine(stem) + "' contains '/': give a file name stem, not a path";
    return false;
  }
  for (char ch : stem) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                    (ch >= '0' && ch <= '9') || ch == '_' || ch == '-' || ch == '.' || ch == '+';
    if (!ok) {
      *error = "the plot name '" + OneLine(stem) +
               "' has a character other than letters, digits, '_', '-', '+' and '.'";
      return false;
    }
  }
  if (stem[0] == '.' || stem[0] == '-') {
    *error = "the plot name '" + stem + "' must not start with '.' or '-'";
    return false;
  }
  if (stem.size() > 200) {
    *error = "the plot name is longer than 200 characters";
    return false;
  }
  return true;
}

// Position (in [0, 1] screen units) of a pixel offset within a canvas of `size` pixels.
std::string Screen(double px, double size) { return Num(std::round(px) / size); }

// Sets the four margins of a multiplot panel whose plot area is the pixel rectangle
// [left, right] x [top, bottom] (pixels from the canvas' top-left corner).
std::string PanelMargins(double left, double right, double top, double bottom, double width,
                         double height) {
  return "set lmargin at screen " + Screen(left, width) + "; set rmargin at screen " +
         Screen(right, width) + "\nset tmargin at screen " + Num(1.0 - std::round(top) / height) +
         "; set bmargin at screen " + Num(1.0 - std::round(bottom) / height) + "\n";
}

// ---------------------------------------------------------------------------------------------
// Axis helpers.

// The smallest round step (1, 2 or 5 times a power of ten) that splits `span` into at most
// target + 1 intervals.
double NiceStep(double span, int target) {
  const double min_step = span / (std::max(1, target) + 1);
  const double magnitude = std::pow(10.0, std::floor(std::log10(min_step)));
  for (double factor : {1.0, 2.0, 5.0}) {
    if (factor * magnitude >= min_step * (1 - 1e-9)) return factor * magnitude;
  }
  return 10.0 * magnitude;
}

// Label of tick `value` on an axis with tick spacing `step` whose largest magnitude is
// `scale`: just enough digits to tell neighbouring ticks apart.
std::string FormatTick(double value, double step, double scale) {
  if (std::fabs(value) < 1e-9 * step) return "0";
  const int step_exponent = static_cast<int>(std::floor(std::log10(step) + 1e-9));
  char buffer[64];
  if (scale >= 1e7 || scale < 1e-3) {
    const int value_exponent = static_cast<int>(std::floor(std::log10(std::fabs(value))));
    std::snprintf(buffer, sizeof(buffer), "%.*e", std::max(0, value_exponent - step_exponent),
                  value);
  } else {
    std::snprintf(buffer, sizeof(buffer), "%.*f", std::max(0, -step_exponent), value);
  }
  return buffer;
}

// A gnuplot tic list "('a' 1, 'b' 2)" of round values inside [lo, hi], leaving out ticks
// within `edge_fraction` of either end (their labels would run into the next panel's). With
// labels false the tick marks are kept and the labels left empty.
std::string TickList(double lo, double hi, int target, double edge_fraction, bool labels) {
  const double span = hi - lo;
  const double step = NiceStep(span, target);
  const double scale = std::max(std::fabs(lo), std::fabs(hi));
  std::string out = "(";
  bool first = true;
  for (double k = std::ceil(lo / step); k * step <= hi; k += 1.0) {
    const double v = k * step;
    if (v < lo + edge_fraction * span || v > hi - edge_fraction * span) continue;
    if (!first) out += ", ";
    first = false;
    out += (labels ? GpString(FormatTick(v, step, scale)) : std::string("''")) + " " + Num(v);
  }
  return out + ")";
}

// Extends [lo, hi] by `fraction` of its span on each side; a zero span becomes a small
// interval around the value.
void PadRange(double fraction, double* lo, double* hi) {
  double span = *hi - *lo;
  if (!(span > 0)) {
    const double half = *lo != 0 ? std::fabs(*lo) * 1e-3 : 1.0;
    *lo -= half;
    *hi += half;
    span = *hi - *lo;
  }
  *lo -= fraction * span;
  *hi += fraction * span;
}

// ---------------------------------------------------------------------------------------------
// Running gnuplot.

std::string ResolveGnuplotName(const std::string& gnuplot_path) {
  if (!gnuplot_path.empty()) return gnuplot_path;
  const char* env = std::getenv("CCDPSF_GNUPLOT");
  if (env != nullptr && env[0] != '\0') return env;
  return "gnuplot";
}

// The last two meaningful lines of gnuplot's output on one line (its error context lines
// holding only '^' markers are dropped), at most ~300 characters.
std::string SummariseOutput(const std::string& output) {
  std::vector<std::string> lines;
  size_t begin = 0;
  while (begin < output.size()) {
    size_t end = output.find('\n', begin);
    if (end == std::string::npos) end = output.size();
    std::string line = OneLine(output.substr(begin, end - begin));
    const size_t first = line.find_first_not_of(" ^");
    if (first != std::string::npos) {
      const size_t last = line.find_last_not_of(' ');
      lines.push_back(line.substr(first, last - first + 1));
    }
    begin = end + 1;
  }
  std::string out;
  for (size_t i = lines.size() > 2 ? lines.size() - 2 : 0; i < lines.size(); ++i) {
    if (!out.empty()) out += " / ";
    out += lines[i];
  }
  if (out.size() > 300) out = out.substr(0, 297) + "...";
  return out;
}

// Whether the file at `path` begins as a file of `format` does: the 8-byte PNG signature;
// "%PDF-"; for SVG an XML declaration or the <svg> element, after any leading white space.
bool StartsLikeFormat(const std::string& path, PlotFormat format) {
  std::ifstream in(path, std::ios::binary);
  char head[64] = {};
  in.read(head, sizeof(head));
  const std::string start(head, static_cast<size_t>(in.gcount()));
  switch (format) {
    case PlotFormat::kPng:
      return start.compare(0, 8, std::string("\x89PNG\r\n\x1a\n", 8)) == 0;
    case PlotFormat::kPdf:
      return start.compare(0, 5, "%PDF-") == 0;
    case PlotFormat::kSvg: {
      const size_t first = start.find_first_not_of(" \t\r\n");
      return first != std::string::npos &&
             (start.compare(first, 5, "<?xml") == 0 || start.compare(first, 4, "<svg") == 0);
    }
  }
  return false;
}

std::string FileName(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

std::string ImageName(const std::string& stem, PlotFormat format) {
  return stem + "." + PlotFormatName(format);
}

// Runs STEM.gp in `dir` with the output redirected to a temporary name that is renamed onto
// STEM.EXT once gnuplot has succeeded. Returns whether the picture was made; *message says
// why not (or carries gnuplot's warnings).
bool RenderImage(const std::string& dir, const std::string& stem, const PlotOptions& options,
                 std::string* message) {
  const std::string format = PlotFormatName(options.format);
  const std::string image_name = ImageName(stem, options.format);
  const std::string image_path = JoinPath(dir, image_name);
  const std::string manual =
      "; data and script are in " + dir + ": run 'gnuplot " +
      (options.format == PlotFormat::kPng ? "" : "-e \"plot_format='" + format + "'\" ") + stem +
      ".gp' there to make " + image_name;
  bool written = false;
  if (!options.draw) {
    *message = "not drawn (not asked for)" + manual;
    ::unlink(image_path.c_str());
    return false;
  }
  const std::string gnuplot_name = ResolveGnuplotName(options.gnuplot_path);
  const std::optional<std::string> executable = internal::FindExecutable(gnuplot_name);
  if (!executable) {
    *message = "gnuplot ('" + gnuplot_name + "') was not found" + manual;
  } else {
    std::string warnings;
    std::string failure;
    const bool ok = WriteAtomically(
        image_path,
        [&](const std::string& temp_path, std::string* write_error) {
          // gnuplot runs inside `dir`, so the temporary file is named relative to it. Its
          // name (STEM.EXT.tmp.<pid>.<n>) holds no quote characters.
          const std::vector<std::string> args = {
              "-d", "-e", "plot_format='" + format + "'; outfile='" + FileName(temp_path) + "'",
              stem + ".gp"};
          const internal::SubprocessOutcome run =
              internal::RunSubprocess(*executable, args, dir, options.timeout_s);
          const std::string said = SummariseOutput(run.output);
          if (!run.started) {
            *write_error = run.error;
          } else if (run.timed_out) {
            *write_error =
                "gnuplot did not finish within " + Num(options.timeout_s) + " s and was stopped";
          } else if (!run.exited) {
            *write_error = "gnuplot was killed by signal " + std::to_string(run.signal);
          } else if (run.exit_code != 0) {
            *write_error = "gnuplot failed (exit status " + std::to_string(run.exit_code) + ")" +
                           (said.empty() ? "" : ": " + said);
          } else if (!StartsLikeFormat(temp_path, options.format)) {
            *write_error =
                "gnuplot made no " + format + " file" + (said.empty() ? "" : ": " + said);
          } else {
            warnings = said;
            return true;
          }
          failure = *write_error;
          return false;
        },
        &failure);
    if (ok) {
      written = true;
      *message = warnings.empty() ? "" : "gnuplot warnings: " + warnings;
    } else {
      *message = failure + manual;
    }
  }
  // A picture of earlier data must not pass for this one.
  if (!written) ::unlink(image_path.c_str());
  return written;
}

// Writes the data files and the script, then makes the picture. False only when a file
// cannot be written.
bool WritePlotFiles(const std::string& dir, const std::string& stem,
                    const std::vector<std::pair<std::string, std::string>>& data_files,
                    const std::string& script, const PlotOptions& options, PlotResult* result,
                    std::string* error) {
  if (dir.empty()) {
    *error = "the plot folder name is empty";
    return false;
  }
  if (!MakeDirectories(dir, error)) return false;
  PlotResult local;
  local.image_path = JoinPath(dir, ImageName(stem, options.format));
  local.script_path = JoinPath(dir, stem + ".gp");
  for (const auto& [name, contents] : data_files) {
    const std::string path = JoinPath(dir, name);
    if (!WriteTextFileAtomically(path, contents, error)) return false;
    local.data_paths.push_back(path);
  }
  if (!WriteTextFileAtomically(local.script_path, script, error)) return false;
  local.image_written = RenderImage(dir, stem, options, &local.message);
  if (result != nullptr) *result = std::move(local);
  return true;
}

// The opening of every script: how to run it, the output file and the terminal. `width` and
// `height` are the picture's size in PNG / SVG pixels. pngcairo sets fonts as at 96 pixels
// per inch, so the PDF page is width / 96 by height / 96 inches with the same font sizes: its
// text then takes the same share of the picture as in the PNG (checked by rendering both).
std::string ScriptPreamble(const std::string& stem, const std::string& what, int width, int height,
                           int font_size,
                           const std::vector<std::pair<std::string, std::string>>& data_files) {
  std::string files;
  for (const auto& file : data_files) files += (files.empty() ? "" : ", ") + file.first;
  std::string s;
  s += "# " + stem + ".gp: " + OneLine(what) + "\n";
  s += "# Written by ccdpsf. Reads " + files + " from this folder.\n";
  s += "# To restyle, edit this file and run `gnuplot " + stem + ".gp` here to remake " + stem +
       ".png;\n";
  s += "# `gnuplot -e \"plot_format='pdf'\" " + stem + ".gp` makes " + stem +
       ".pdf (or 'svg': " + stem + ".svg).\n";
  s += "# (ccdpsf runs it as gnuplot -d -e \"plot_format='...'; outfile='...'\" to write under a"
       " temporary name.)\n";
  s += "if (!exists(\"plot_format\")) plot_format = 'png'\n";
  s += "if (!exists(\"outfile\")) outfile = '" + stem + ".' . plot_format\n";
  const std::string font = " font 'Sans," + std::to_string(font_size) + "' noenhanced";
  const std::string pixels = " size " + std::to_string(width) + "," + std::to_string(height);
  char inches[64];
  std::snprintf(inches, sizeof(inches), " size %.3fin,%.3fin", width / 96.0, height / 96.0);
  s += "# pngcairo when this gnuplot has it (set terminal_name on the command line to choose).\n";
  s += "if (!exists(\"terminal_name\")) "
       "terminal_name = strstrt(GPVAL_TERMINALS, ' pngcairo ') > 0 ? 'pngcairo' : 'png'\n";
  s += "if (plot_format eq 'pdf') {\n";
  s += "  set terminal pdfcairo" + std::string(inches) + font + "\n";
  s += "} else {\n";
  s += "  if (plot_format eq 'svg') {\n";
  s += "    set terminal svg" + pixels + " fixed" + font + " background '#FFFFFF'\n";
  s += "  } else {\n";
  s += "    if (terminal_name eq 'pngcairo') {\n";
  s += "      set terminal pngcairo" + pixels + font + "\n";
  s += "    } else {\n";
  s += "      # libgd's png: truecolor, else palette changes between panels recolour earlier "
       "ones.\n";
  s += "      set terminal png truecolor" + pixels + font + "\n";
  s += "    }\n";
  s += "  }\n";
  s += "}\n";
  s += "set output outfile\n";
  s += "set encoding utf8\n";
  return s;
}

// ---------------------------------------------------------------------------------------------
// Corner plot.

// The posterior quantiles marked on the corner plot's histograms: the median and the central
// 68.27 % interval (1 sigma of a Gaussian; the same levels as fit.json's lo68 / hi68).
constexpr double kQuantileLow = 0.158655, kQuantileHigh = 0.841345;

// Quantile q of `sorted` (ascending) by linear interpolation between order statistics.
double SortedQuantile(const std::vector<double>& sorted, double q) {
  const double position = q * (sorted.size() - 1);
  const size_t below = static_cast<size_t>(std::floor(position));
  const size_t above = std::min(below + 1, sorted.size() - 1);
  return sorted[below] + (position - below) * (sorted[above] - sorted[below]);
}

// "median +up -down" with the digits the uncertainty supports: two significant digits of the
// smaller of the two error sizes, the median rounded to the same decimal place. Scientific
// notation beyond 1e6 or below 1e-2.
std::string ValueWithErrors(double median, double low, double high) {
  const double up = high - median, down = median - low;
  const double smaller = std::min(up, down) > 0 ? std::min(up, down) : std::max(up, down);
  char buffer[128];
  if (!(smaller > 0) || !std::isfinite(smaller)) {
    std::snprintf(buffer, sizeof(buffer), "%.4g", median);
    return buffer;
  }
  const int error_exponent = static_cast<int>(std::floor(std::log10(smaller)));
  const double magnitude = std::fabs(median);
  if (magnitude >= 1e6 || (magnitude > 0 && magnitude < 1e-2)) {
    const int median_exponent = static_cast<int>(std::floor(std::log10(magnitude)));
    const int digits = std::max(1, median_exponent - error_exponent + 1);
    std::snprintf(buffer, sizeof(buffer), "%.*e +%.1e -%.1e", digits, median, up, down);
    return buffer;
  }
  const int decimals = std::max(0, 1 - error_exponent);
  std::snprintf(buffer, sizeof(buffer), "%.*f +%.*f -%.*f", decimals, median, decimals, up,
                decimals, down);
  return buffer;
}

// Points drawn per scatter panel of a corner plot: enough to show the density at the panel's
// ~150 px; gnuplot's time grows with them (5000 took 0.8 s of a 3.5 s fit).
constexpr int kMaxScatterPoints = 2500;
// Mahalanobis radii of the 2-D Gaussian regions holding 68% and 95%: sqrt(-2 ln(1 - p)).
const double kEllipseRadius68 = std::sqrt(-2.0 * std::log(1.0 - 0.68));
const double kEllipseRadius95 = std::sqrt(-2.0 * std::log(1.0 - 0.95));

bool ValidateCorner(const CornerPlotInput& in, std::string* error) {
  const size_t dim = in.names.size();
  if (dim == 0) {
    *error = "corner plot: no parameter names";
    return false;
  }
  for (size_t k = 0; k < dim; ++k) {
    if (in.names[k].empty()) {
      *error = "corner plot: parameter " + std::to_string(k) + " has an empty name";
      return false;
    }
  }
  if (in.num_samples <= 0) {
    *error = "corner plot: num_samples is " + std::to_string(in.num_samples) +
             "; at least one sample is needed";
    return false;
  }
  if (in.samples.size() != static_cast<size_t>(in.num_samples) * dim) {
    *error = "corner plot: " + std::to_string(in.samples.size()) +
             " sample values for num_samples " + std::to_string(in.num_samples) + " x " +
             std::to_string(dim) + " parameters";
    return false;
  }
  for (size_t i = 0; i < in.samples.size(); ++i) {
    if (!std::isfinite(in.samples[i])) {
      *error = "corner plot: sample " + std::to_string(i / dim) + " of '" + in.names[i % dim] +
               "' is not finite";
      return false;
    }
  }
  if (!in.map.empty() && in.map.size() != dim) {
    *error = "corner plot: " + std::to_string(in.map.size()) + " MAP values for " +
             std::to_string(dim) + " parameters";
    return false;
  }
  if (!in.laplace_covariance.empty() && in.laplace_covariance.size() != dim * dim) {
    *error = "corner plot: Laplace covariance has " + std::to_string(in.laplace_covariance.size()) +
             " entries, expected " + std::to_string(dim * dim);
    return false;
  }
  if (!in.truth.empty() && in.truth.size() != dim) {
    *error = "corner plot: " + std::to_string(in.truth.size()) + " true values for " +
             std::to_string(dim) + " parameters";
    return false;
  }
  return true;
}

}  // namespace

const char* PlotFormatName(PlotFormat format) {
  switch (format) {
    case PlotFormat::kPng:
      return "png";
    case PlotFormat::kPdf:
      return "pdf";
    case PlotFormat::kSvg:
      return "svg";
  }
  return "png";
}

bool ParsePlotFormat(const std::string& text, PlotFormat* format, std::string* error) {
  for (PlotFormat f : {PlotFormat::kPng, PlotFormat::kPdf, PlotFormat::kSvg}) {
    if (text == PlotFormatName(f)) {
      *format = f;
      return true;
    }
  }
  *error = "unknown plot format '" + OneLine(text) + "': use png, pdf or svg";
  return false;
}

bool GnuplotAvailable(const std::string& gnuplot_path) {
  const std::optional<std::string> executable =
      internal::FindExecutable(ResolveGnuplotName(gnuplot_path));
  if (!executable) return false;
  return internal::RunSubprocess(*executable, {"--version"}, ".", 30.0).Succeeded();
}

bool WriteCornerPlot(const std::string& dir, const std::string& stem, const CornerPlotInput& input,
                     PlotResult* result, std::string* error, const PlotOptions& options) {
  if (!ValidateStem(stem, error) || !ValidateCorner(input, error)) return false;
  const int dim = static_cast<int>(input.names.size());
  const int n = input.num_samples;
  auto sample = [&](int i, int k) { return input.samples[static_cast<size_t>(i) * dim + k]; };
  auto map = [&](int k) { return input.map.empty() ? kNaN : input.map[k]; };
  auto truth = [&](int k) { return input.truth.empty() ? kNaN : input.truth[k]; };
  auto cov = [&](int a, int b) {
    return input.laplace_covariance.empty()
               ? kNaN
               : input.laplace_covariance[static_cast<size_t>(a) * dim + b];
  };

  // Laplace sd where the variance is finite and positive and the MAP (its centre) is known.
  std::vector<double> sd(dim, kNaN);
  std::vector<std::string> no_sd;
  for (int k = 0; k < dim; ++k) {
    const double v = cov(k, k);
    if (std::isfinite(map(k)) && std::isfinite(v) && v > 0) {
      sd[k] = std::sqrt(v);
    } else if (!input.laplace_covariance.empty()) {
      no_sd.push_back(input.names[k]);
    }
  }

  // Axis range per parameter: all samples, the MAP and the truth, padded by 5%.
  std::vector<double> lo(dim), hi(dim);
  for (int k = 0; k < dim; ++k) {
    lo[k] = hi[k] = sample(0, k);
    for (int i = 1; i < n; ++i) {
      lo[k] = std::min(lo[k], sample(i, k));
      hi[k] = std::max(hi[k], sample(i, k));
    }
    for (double v : {map(k), truth(k)}) {
      if (std::isfinite(v)) {
        lo[k] = std::min(lo[k], v);
        hi[k] = std::max(hi[k], v);
      }
    }
    PadRange(0.05, &lo[k], &hi[k]);
  }

  // Thinned samples for the scatter panels.
  const int stride = (n + kMaxScatterPoints - 1) / kMaxScatterPoints;
  const int kept = (n + stride - 1) / stride;
  std::string samples_dat;
  samples_dat += "# Posterior samples drawn in " + stem + ".gp: " + std::to_string(kept) + " of " +
                 std::to_string(n) + " (samples 0, " + std::to_string(stride) + ", 2 x " +
                 std::to_string(stride) + ", ...), one per row.\n";
  samples_dat +=
      "# Each value is in its parameter's unit, named by the suffix (_px pixels,"
      " _e electrons).\n";
  for (int k = 0; k < dim; ++k) {
    samples_dat += "#   column " + std::to_string(k + 1) + ": " + OneLine(input.names[k]) + "\n";
  }
  for (int i = 0; i < n; i += stride) {
    for (int k = 0; k < dim; ++k) samples_dat += (k ? " " : "") + Num(sample(i, k));
    samples_dat += "\n";
  }

  // Histograms of all samples, as densities so that the Laplace curve shares their scale.
  const int bins = std::clamp(static_cast<int>(std::lround(std::sqrt(n) / 1.5)), 10, 40);
  std::vector<double> hist_peak(dim, 0.0);
  std::string hist_dat;
  hist_dat += "# Histograms of all " + std::to_string(n) + " posterior samples, " +
              std::to_string(bins) + " bins over each axis range.\n";
  hist_dat += "# One block per parameter, in order (gnuplot index = parameter number - 1).\n";
  hist_dat +=
      "# Columns: bin_centre [parameter unit], bin_width [parameter unit],"
      " density [1/parameter unit], count\n";
  for (int k = 0; k < dim; ++k) {
    std::vector<long> counts(bins, 0);
    const double width = (hi[k] - lo[k]) / bins;
    for (int i = 0; i < n; ++i) {
      const int b = static_cast<int>(std::floor((sample(i, k) - lo[k]) / width));
      ++counts[std::clamp(b, 0, bins - 1)];
    }
    hist_dat += (k ? "\n\n" : "") + std::string("# parameter ") + std::to_string(k + 1) + ": " +
                OneLine(input.names[k]) + "\n";
    for (int b = 0; b < bins; ++b) {
      const double density = counts[b] / (static_cast<double>(n) * width);
      hist_peak[k] = std::max(hist_peak[k], density);
      hist_dat += Num(lo[k] + (b + 0.5) * width) + " " + Num(width) + " " + Num(density) + " " +
                  std::to_string(counts[b]) + "\n";
    }
  }

  // Laplace ellipses, one gnuplot index per (panel, level).
  struct EllipseIndex {
    int i68 = -1, i95 = -1;
  };
  std::vector<EllipseIndex> ellipse_index(static_cast<size_t>(dim) * dim);
  std::string ellipses_dat;
  int num_blocks = 0;
  for (int r = 1; r < dim; ++r) {
    for (int c = 0; c < r; ++c) {
      // x = parameter c, y = parameter r. With the Cholesky factor L of the 2x2 covariance,
      // the ellipse of Mahalanobis radius rho is map + rho L (cos t, sin t).
      const double sxx = cov(c, c), syy = cov(r, r), sxy = cov(c, r);
      if (!std::isfinite(sd[c]) || !std::isfinite(sd[r]) || !std::isfinite(sxy)) continue;
      const double l11 = std::sqrt(sxx);
      const double l21 = sxy / l11;
      const double schur = syy - l21 * l21;
      if (!(schur > 0)) continue;  // not positive definite
      const double l22 = std::sqrt(schur);
      EllipseIndex& index = ellipse_index[static_cast<size_t>(r) * dim + c];
      for (const auto& [radius, label] :
           {std::pair<double, const char*>{kEllipseRadius68, "68%"}, {kEllipseRadius95, "95%"}}) {
        if (num_blocks == 0) {
          ellipses_dat +=
              "# Laplace (Gaussian) contours about the MAP from each 2x2 covariance"
              " block, enclosing 68% or 95%.\n";
          ellipses_dat += "# One block per panel and level (gnuplot index in " + stem +
                          ".gp). Columns: x, y [units of the named parameters]\n";
        } else {
          ellipses_dat += "\n\n";
        }
        ellipses_dat += "# x = " + OneLine(input.names[c]) + ", y = " + OneLine(input.names[r]) +
                        ", " + label + "\n";
        constexpr int kPoints = 120;
        for (int t = 0; t <= kPoints; ++t) {
          const double angle = 2.0 * M_PI * t / kPoints;
          const double u = radius * std::cos(angle), v = radius * std::sin(angle);
          ellipses_dat += Num(map(c) + l11 * u) + " " + Num(map(r) + l21 * u + l22 * v) + "\n";
        }
        (label[0] == '6' ? index.i68 : index.i95) = num_blocks++;
      }
    }
  }

  // Median and central 68 % interval of all samples, per parameter.
  std::vector<double> q_low(dim), q_median(dim), q_high(dim);
  for (int k = 0; k < dim; ++k) {
    std::vector<double> sorted(n);
    for (int i = 0; i < n; ++i) sorted[i] = sample(i, k);
    std::sort(sorted.begin(), sorted.end());
    q_low[k] = SortedQuantile(sorted, kQuantileLow);
    q_median[k] = SortedQuantile(sorted, 0.5);
    q_high[k] = SortedQuantile(sorted, kQuantileHigh);
  }

  std::string summary_dat;
  summary_dat +=
      "# Per parameter: MAP, Laplace sd (NaN: undefined), true value (NaN: not"
      " given) and the plotted axis range,\n";
  summary_dat +=
      "# all in the parameter's unit. Columns: index name map laplace_sd truth"
      " axis_lo axis_hi q15.87 q50 q84.13\n";
  summary_dat +=
      "# (the last three: the samples' 15.87, 50 and 84.13 % quantiles, linear interpolation"
      " between order statistics)\n";
  for (int k = 0; k < dim; ++k) {
    std::string name = OneLine(input.names[k]);
    std::replace(name.begin(), name.end(), ' ', '_');
    summary_dat += std::to_string(k) + " " + name + " " + Num(map(k)) + " " + Num(sd[k]) + " " +
                   Num(truth(k)) + " " + Num(lo[k]) + " " + Num(hi[k]) + " " + Num(q_low[k]) + " " +
                   Num(q_median[k]) + " " + Num(q_high[k]) + "\n";
  }

  std::vector<std::pair<std::string, std::string>> files = {{stem + "_samples.dat", samples_dat},
                                                            {stem + "_hist.dat", hist_dat},
                                                            {stem + "_summary.dat", summary_dat}};
  if (num_blocks > 0) files.push_back({stem + "_ellipses.dat", ellipses_dat});

  // Layout in pixels. The legend goes in the empty upper triangle when there is one (dim >= 3),
  // else in an extra right margin.
  const double panel = dim <= 10 ? 200.0 : std::max(110.0, 2000.0 / dim);
  const double gap = 6.0, left = 100.0, bottom = 100.0;
  // Above the grid: the title lines, then the first column's two-line summary (name, median
  // and 68 % interval), which every column has above its histogram.
  constexpr double kColumnTitle = 34.0;
  const double top = (input.title.empty() && no_sd.empty() ? 40.0 : 70.0) + kColumnTitle;
  const double right = dim >= 3 ? 25.0 : 330.0;
  const double grid = dim * panel + (dim - 1) * gap;
  const int width = static_cast<int>(left + grid + right);
  const int height = static_cast<int>(top + grid + bottom);
  const int ticks_target = panel >= 160 ? 4 : 3;

  std::string s = ScriptPreamble(stem, "corner plot of posterior samples", width, height, 9, files);
  s += "\n# Styles: 1 samples, 2 MAP, 3 Laplace curve and 68% ellipse, 4 Laplace 95% ellipse,\n";
  s += "# 5 true values, 6 histogram bars. Colours are '#AARRGGBB' (AA = transparency).\n";
  // Samples as small filled squares: at this size they look as the circles did, and cairo
  // draws them in about half the time (the circles were most of a single fit's run).
  s += "set style line 1 pt 5 ps 0.2 lc rgb '#A0303030'\n";
  s += "set style line 2 lw 1.5 pt 7 ps 0.7 lc rgb '#D62728'\n";
  s += "set style line 3 lw 1.5 dt 1 lc rgb '#D62728'\n";
  s += "set style line 4 lw 1.3 dt 2 lc rgb '#E36464'\n";
  s += "set style line 5 lw 1.2 dt 1 lc rgb '#1F5FD0'\n";
  s += "set style line 6 lc rgb '#A8A8A8'\n";
  s += "# 7 the samples' 15.87 / 84.13 % quantiles, 8 their median (on the histograms).\n";
  s += "set style line 7 lw 1.2 dt 2 lc rgb '#202020'\n";
  s += "set style line 8 lw 1.2 dt 1 lc rgb '#202020'\n";
  s += "set style fill solid 1.0 noborder\n";
  s += "gauss(x, m, s) = exp(-0.5 * ((x - m) / s)**2) / (s * sqrt(2 * pi))\n";
  s += "set samples 1000\n";
  s += "unset key\n";
  s += "set tics scale 0.6 front\n";
  s += "set xlabel offset 0,0.5\n";
  s += "set multiplot\n";

  const std::string samples_file = GpString(stem + "_samples.dat");
  const std::string hist_file = GpString(stem + "_hist.dat");
  const std::string ellipses_file = GpString(stem + "_ellipses.dat");
  const int legend_row = dim >= 2 ? 1 : 0;
  for (int r = 0; r < dim; ++r) {
    for (int c = 0; c <= r; ++c) {
      const bool diagonal = r == c;
      s += "\n# Panel: row " + std::to_string(r + 1) + ", column " + std::to_string(c + 1) +
           ": x = " + OneLine(input.names[c]) +
           (diagonal ? ", histogram" : ", y = " + OneLine(input.names[r])) + "\n";
      s += "unset label; unset arrow; unset key\n";
      const double x0 = left + c * (panel + gap), y0 = top + r * (panel + gap);
      s += PanelMargins(x0, x0 + panel, y0, y0 + panel, width, height);
      if (r == 0 && c == 0) {
        if (!input.title.empty()) {
          s += "set label 1001 " + GpString(input.title) + " at screen 0.5," +
               Screen(height - 22, height) + " center font ',13'\n";
        }
        if (!no_sd.empty()) {
          std::string names;
          for (const std::string& name : no_sd) names += (names.empty() ? "" : ", ") + name;
          s += "set label 1002 " +
               GpString("No Laplace sd (not identified by the data): " + names) +
               " at screen 0.5," + Screen(height - 46, height) + " center\n";
        }
      }
      const bool bottom_row = r == dim - 1;
      s += "set xrange [" + Num(lo[c]) + ":" + Num(hi[c]) + "]\n";
      s += std::string("set xtics ") + (bottom_row ? "rotate by 45 right " : "norotate ") +
           TickList(lo[c], hi[c], ticks_target, 0.03, bottom_row) + "\n";
      s += bottom_row ? "set xlabel " + GpString(input.names[c]) + "\n" : "unset xlabel\n";

      std::vector<std::string> plots;
      if (diagonal) {
        double peak = hist_peak[c];
        if (std::isfinite(sd[c])) {
          // Show a Laplace curve up to 1.5x the histogram's peak; a narrower one is clipped.
          peak = std::max(peak, std::min(1.0 / (sd[c] * std::sqrt(2 * M_PI)), 1.5 * peak));
        }
        s += "set yrange [0:" + Num(1.1 * (peak > 0 ? peak : 1.0)) + "]\n";
        s += "unset ytics; unset ylabel\n";
        plots.push_back(hist_file + " index " + std::to_string(c) +
                        " using 1:3:2 with boxes ls 6 notitle");
        if (std::isfinite(sd[c])) {
          plots.push_back("gauss(x, " + Num(map(c)) + ", " + Num(sd[c]) +
                          ") with lines ls 3 notitle");
        }
        for (const auto& [q, style] :
             {std::pair<double, int>{q_low[c], 7}, {q_median[c], 8}, {q_high[c], 7}}) {
          s += "set arrow from first " + Num(q) + ", graph 0 to first " + Num(q) +
               ", graph 1 nohead ls " + std::to_string(style) + " front\n";
        }
        if (std::isfinite(map(c))) {
          s += "set arrow from first " + Num(map(c)) + ", graph 0 to first " + Num(map(c)) +
               ", graph 1 nohead ls 2 front\n";
        }
        // The column's summary above its histogram: name, then median +- the 68 % interval.
        s += "set label 1003 " + GpString(input.names[c]) + " at screen " +
             Screen(x0 + panel / 2, width) + "," + Screen(height - (y0 - 20), height) +
             " center font ',9'\n";
        s += "set label 1004 " + GpString(ValueWithErrors(q_median[c], q_low[c], q_high[c])) +
             " at screen " + Screen(x0 + panel / 2, width) + "," +
             Screen(height - (y0 - 7), height) + " center font ',9'\n";
        if (std::isfinite(truth(c))) {
          s += "set arrow from first " + Num(truth(c)) + ", graph 0 to first " + Num(truth(c)) +
               ", graph 1 nohead ls 5 front\n";
        }
      } else {
        s += "set yrange [" + Num(lo[r]) + ":" + Num(hi[r]) + "]\n";
        s += "set ytics norotate " + TickList(lo[r], hi[r], ticks_target, 0.03, c == 0) + "\n";
        s += c == 0 ? "set ylabel " + GpString(input.names[r]) + "\n" : "unset ylabel\n";
        plots.push_back(samples_file + " using " + std::to_string(c + 1) + ":" +
                        std::to_string(r + 1) + " with points ls 1 notitle");
        const EllipseIndex& index = ellipse_index[static_cast<size_t>(r) * dim + c];
        if (index.i68 >= 0) {
          plots.push_back(ellipses_file + " index " + std::to_string(index.i68) +
                          " with lines ls 3 notitle");
          plots.push_back(ellipses_file + " index " + std::to_string(index.i95) +
                          " with lines ls 4 notitle");
        }
        if (std::isfinite(truth(c))) {
          s += "set arrow from first " + Num(truth(c)) + ", graph 0 to first " + Num(truth(c)) +
               ", graph 1 nohead ls 5 front\n";
        }
        if (std::isfinite(truth(r))) {
          s += "set arrow from graph 0, first " + Num(truth(r)) + " to graph 1, first " +
               Num(truth(r)) + " nohead ls 5 front\n";
        }
        if (std::isfinite(map(c)) && std::isfinite(map(r))) {
          s += "set label 1 '' at first " + Num(map(c)) + ", first " + Num(map(r)) +
               " point ls 2 front\n";
        }
      }
      if (r == legend_row && c == 0) {
        // The legend: key entries placed in the empty top-right part of the canvas.
        const double key_x = dim >= 3 ? left + grid : width - 10.0;
        s += "set key at screen " + Screen(key_x, width) + "," + Screen(height - top, height) +
             " right top Left reverse box opaque samplen 2.5 spacing 1.3 width 1 font ',10'\n";
        plots.push_back(
            "keyentry with points pt 5 ps 0.5 lc rgb '#303030' title " +
            GpString("samples (" + std::to_string(n) + ", " + std::to_string(kept) + " plotted)"));
        plots.push_back("keyentry with lines ls 8 title 'median, 68 % interval (15.87-84.13 %)'");
        if (!input.map.empty()) plots.push_back("keyentry with linespoints ls 2 title 'MAP'");
        if (!input.laplace_covariance.empty()) {
          if (dim == 1) {
            plots.push_back("keyentry with lines ls 3 title 'Laplace approximation'");
          } else {
            plots.push_back("keyentry with lines ls 3 title 'Laplace approximation, 68%'");
            plots.push_back("keyentry with lines ls 4 title 'Laplace approximation, 95%'");
          }
        }
        if (!input.truth.empty()) plots.push_back("keyentry with lines ls 5 title 'true value'");
      }
      s += "plot ";
      for (size_t p = 0; p < plots.size(); ++p) s += (p ? ", \\\n     " : "") + plots[p];
      s += "\n";
    }
  }
  s += "\nunset multiplot\nunset output\n";

  return WritePlotFiles(dir, stem, files, s, options, result, error);
}

// ---------------------------------------------------------------------------------------------
// Residual maps.

namespace {

bool ValidateStamps(const std::vector<StampPanels>& exposures, std::string* error) {
  if (exposures.empty()) {
    *error = "residual maps: no exposures";
    return false;
  }
  for (size_t e = 0; e < exposures.size(); ++e) {
    const StampPanels& p = exposures[e];
    const std::string what = "residual maps: exposure " + std::to_string(e);
    if (p.data.nx <= 0 || p.data.ny <= 0) {
      *error = what + ": empty data image";
      return false;
    }
    const std::pair<const Image*, const char*> images[] = {{&p.data, "data"},
                                                           {&p.model, "model"},
                                                           {&p.residual, "residual"},
                                                           {&p.normalised, "normalised"}};
    for (const auto& [image, name] : images) {
      if (image->nx != p.data.nx || image->ny != p.data.ny) {
        *error = what + ": " + name + " image is " + std::to_string(image->nx) + " x " +
                 std::to_string(image->ny) + ", data is " + std::to_string(p.data.nx) + " x " +
                 std::to_string(p.data.ny);
        return false;
      }
      if (image->data.size() != static_cast<size_t>(image->nx) * image->ny) {
        *error = what + ": " + name + " image holds " + std::to_string(image->data.size()) +
                 " values for " + std::to_string(image->nx) + " x " + std::to_string(image->ny);
        return false;
      }
    }
  }
  return true;
}

// Smallest and largest finite values of the given images (NaN, NaN when there are none).
std::pair<double, double> FiniteRange(std::initializer_list<const Image*> images) {
  double lo = kNaN, hi = kNaN;
  for (const Image* image : images) {
    for (double v : image->data) {
      if (!std::isfinite(v)) continue;
      lo = std::isnan(lo) ? v : std::min(lo, v);
      hi = std::isnan(hi) ? v : std::max(hi, v);
    }
  }
  return {lo, hi};
}

// Non-finite values are written as NaN (undrawn).
std::string MapValue(double v) { return std::isfinite(v) ? Num(v) : "NaN"; }

// A gnuplot tic list for a colour axis that shows asinh(value / b) over the values
// [lo, hi]: zero and +-1, 2, 5 x 10^k inside the range, labelled with the values themselves,
// leaving out any tick closer than 7 % of the axis to one already kept (largest magnitudes
// first, so the decades survive).
std::string AsinhTicks(double lo, double hi, double b) {
  const double t_lo = std::asinh(lo / b), t_hi = std::asinh(hi / b);
  const double min_gap = 0.07 * (t_hi - t_lo);
  std::vector<double> candidates;
  const double largest = std::max(std::fabs(lo), std::fabs(hi));
  for (int e = static_cast<int>(std::floor(std::log10(largest))); e >= -12; --e) {
    const double decade = std::pow(10.0, e);
    if (decade < 0.1 * b) break;
    for (double m : {5.0, 2.0, 1.0}) {
      for (double sign : {1.0, -1.0}) {
        const double v = sign * m * decade;
        if (v >= lo && v <= hi) candidates.push_back(v);
      }
    }
  }
  std::vector<double> kept;
  if (lo <= 0 && hi >= 0) kept.push_back(0.0);
  // Powers of ten first (m = 1), then 2 and 5, each from the largest magnitude down.
  for (int pass = 0; pass < 2; ++pass) {
    for (double v : candidates) {
      const double mantissa = std::fabs(v) / std::pow(10.0, std::floor(std::log10(std::fabs(v))));
      const bool power_of_ten = std::fabs(mantissa - 1.0) < 1e-9;
      if (power_of_ten != (pass == 0)) continue;
      const double t = std::asinh(v / b);
      bool clear = true;
      for (double k : kept) clear = clear && std::fabs(std::asinh(k / b) - t) >= min_gap;
      if (clear) kept.push_back(v);
    }
  }
  std::sort(kept.begin(), kept.end());
  std::string out = "(";
  for (size_t i = 0; i < kept.size(); ++i) {
    char label[32];
    std::snprintf(label, sizeof(label), "%g", kept[i]);
    out += (i ? ", " : "") + GpString(label) + " " + Num(std::asinh(kept[i] / b));
  }
  return out + ")";
}

}  // namespace

bool WriteResidualMaps(const std::string& dir, const std::string& stem,
                       const std::vector<StampPanels>& exposures, PlotResult* result,
                       std::string* error, const PlotOptions& options) {
  if (!ValidateStem(stem, error) || !ValidateStamps(exposures, error)) return false;
  const int num = static_cast<int>(exposures.size());

  std::vector<std::pair<std::string, std::string>> files;
  for (int e = 0; e < num; ++e) {
    const StampPanels& p = exposures[e];
    const std::string unit = OneLine(p.unit.empty() ? "unknown unit" : p.unit);
    std::string d;
    d += "# " + OneLine(p.title.empty() ? "exposure " + std::to_string(e) : p.title) + "\n";
    d += "# One row per pixel, rows of the stamp separated by blank lines; NaN = masked.\n";
    d += "# Columns: x_px y_px [frame pixel, centre], data [" + unit + "], model [" + unit +
         "], residual = data - model [" + unit + "], normalised = residual / sigma [1]\n";
    for (int y = 0; y < p.data.ny; ++y) {
      if (y > 0) d += "\n";
      for (int x = 0; x < p.data.nx; ++x) {
        d += std::to_string(p.origin_x + x) + " " + std::to_string(p.origin_y + y) + " " +
             MapValue(p.data(x, y)) + " " + MapValue(p.model(x, y)) + " " +
             MapValue(p.residual(x, y)) + " " + MapValue(p.normalised(x, y)) + "\n";
      }
    }
    char name[32];
    std::snprintf(name, sizeof(name), "_%03d.dat", e);
    files.push_back({stem + name, d});
  }

  // Layout in pixels: per panel a plot area of at most `kSide` (square pixels), a left margin
  // for y tick labels, a right one for the colour box and its labels, a title above.
  constexpr double kSide = 250, kCellLeft = 62, kCellRight = 92, kGapTop = 58, kCellBottom = 46;
  constexpr double kHeader = 34, kOuter = 8;
  const double cell_width = kCellLeft + kSide + kCellRight;
  const double row_height = kGapTop + kSide + kCellBottom;
  const int width = static_cast<int>(2 * kOuter + 4 * cell_width);
  const int height = static_cast<int>(kHeader + num * row_height + kOuter);

  std::string s =
      ScriptPreamble(stem, "data, model and residual maps per exposure", width, height, 10, files);
  s += "\n# Colour maps (used as `set palette @name`): sequential for data and model, diverging\n";
  s += "# for residuals (white at zero). Data and model are shown on an asinh stretch,\n";
  s += "# colour = asinh(value / asinh_b); data_stretch = 'linear' or 'log' (here, or gnuplot -e\n";
  s += "# \"data_stretch = 'log'\" " + stem +
       ".gp) shows them on that scale; data_log = 1 means 'log'.\n";
  s += "palette_data = \"defined (0 '#440154', 0.25 '#3B528B', 0.5 '#21918C', 0.75 '#5EC962',"
       " 1 '#FDE725')\"\n";
  s += "palette_residual = \"defined (0 '#2166AC', 0.25 '#92C5DE', 0.5 '#F7F7F7', 0.75 '#F4A582',"
       " 1 '#B2182B')\"\n";
  s += "if (!exists(\"data_log\")) data_log = 0\n";
  s += "if (!exists(\"data_stretch\")) data_stretch = data_log ? 'log' : 'asinh'\n";
  s += "data_log = data_stretch eq 'log'\n";
  s += "data_asinh = data_stretch eq 'asinh'\n";
  s += "# On the log scale, values below the range (noise, negative pixels) get its lowest "
       "colour.\n";
  s += "clamp_log(v) = v > data_log_lo ? v : data_log_lo\n";
  s += "if (!exists(\"normalised_limit\")) normalised_limit = 5\n";
  s += "# Masked (NaN) pixels are drawn as boxes of this colour.\n";
  s += "masked_colour = '#BDBDBD'\n";
  s += "unset key\n";
  s += "set tics out scale 0.6 nomirror\n";
  s += "set cbtics out scale 0.6\n";
  s += "set format cb '%g'\n";
  s += "set xlabel 'x [px]' offset 0,0.3\n";
  s += "set title offset 0,-0.4\n";
  s += "set multiplot\n";

  const char* kPanelNames[4] = {"data", "model", "residual", "normalised residual"};
  for (int e = 0; e < num; ++e) {
    const StampPanels& p = exposures[e];
    const int nx = p.data.nx, ny = p.data.ny;
    const std::string unit = OneLine(p.unit);
    const double scale = kSide / std::max(nx, ny);
    const double plot_w = nx * scale, plot_h = ny * scale;

    auto [data_lo, data_hi] = FiniteRange({&p.data, &p.model});
    if (std::isnan(data_lo)) data_lo = 0, data_hi = 1;
    PadRange(0.0, &data_lo, &data_hi);
    const double data_pos_lo = data_hi > 0 ? data_hi * 1e-4 : 1e-4;
    const double log_hi = data_hi > 0 ? data_hi : 1.0;
    const double asinh_b = std::isfinite(p.asinh_softening) && p.asinh_softening > 0
                               ? p.asinh_softening
                               : 1e-3 * std::max(std::fabs(data_lo), std::fabs(data_hi));
    const auto [res_lo, res_hi] = FiniteRange({&p.residual});
    double res_max = std::isnan(res_lo) ? 0.0 : std::max(std::fabs(res_lo), std::fabs(res_hi));
    if (!(res_max > 0)) res_max = 1.0;

    const double row_top = kHeader + e * row_height;
    s += "\n# ---- Exposure " + std::to_string(e) + ": " + OneLine(p.title) + "\n";
    s += "file = " + GpString(files[e].first) + "\n";
    s += "data_lo = " + Num(data_lo) + "; data_hi = " + Num(data_hi) +
         "; data_log_lo = " + Num(data_pos_lo) + "; data_log_hi = " + Num(log_hi) + "\n";
    s += "residual_max = " + Num(res_max) + "\n";
    s += "asinh_b = " + Num(asinh_b) +
         "; asinh_lo = asinh(data_lo / asinh_b); asinh_hi = "
         "asinh(data_hi / asinh_b)\n";
    s += "asinh_label = " +
         GpString("asinh stretch, b = " + FormatTick(asinh_b, asinh_b / 10, 1) + " " + unit) + "\n";
    // About five labelled ticks on the linear colour boxes.
    s += "data_cbstep = " + Num(NiceStep(data_hi - data_lo, 5)) +
         "; residual_cbstep = " + Num(NiceStep(2 * res_max, 5)) + "\n";
    const double tick_step = NiceStep(std::max(nx, ny), 4);
    for (int c = 0; c < 4; ++c) {
      s += "# " + std::string(kPanelNames[c]) + "\n";
      s += "unset label\n";
      if (e == 0 && c == 0) {
        s += "set label 1001 " +
             GpString(
                 "Grey pixels are masked. Normalised residual = (data - model) / sigma,"
                 " shown on -5..5.") +
             " at screen " + Screen(kOuter + 4, width) + "," + Screen(height - 20, height) +
             " left font ',11'\n";
      }
      if (c == 0) {
        s += "set label 1002 " +
             GpString(p.title.empty() ? "exposure " + std::to_string(e) : p.title) + " at screen " +
             Screen(kOuter + 4, width) + "," + Screen(height - (row_top + 14), height) +
             " left font ',11'\n";
      }
      const double cell_left = kOuter + c * cell_width;
      const double x0 = cell_left + kCellLeft + (kSide - plot_w) / 2;
      const double y0 = row_top + kGapTop + (kSide - plot_h) / 2;
      s += PanelMargins(x0, x0 + plot_w, y0, y0 + plot_h, width, height);
      s += "set colorbox user origin screen " + Screen(x0 + plot_w + 10, width) + "," +
           Num(1.0 - std::round(y0 + plot_h) / height) + " size screen " + Num(14.0 / width) + "," +
           Num(std::round(plot_h) / height) + "\n";
      s += "set xrange [" + Num(p.origin_x - 0.5) + ":" + Num(p.origin_x + nx - 0.5) + "]\n";
      s += "set yrange [" + Num(p.origin_y - 0.5) + ":" + Num(p.origin_y + ny - 0.5) + "]\n";
      s += "set xtics " + Num(tick_step) + "; set ytics " + Num(tick_step) + "\n";
      std::string title = kPanelNames[c];
      if (c < 3) title += " [" + unit + "]";
      s += "set title " + GpString(title) + "\n";
      s += c == 0 ? "set ylabel 'y [px]' offset 1,0\n" : "unset ylabel\n";
      if (c < 2) {
        s += "set palette @palette_data\n";
        s += "if (data_log) { set logscale cb; set cbrange [data_log_lo:data_log_hi] } "
             "else { unset logscale cb; if (data_asinh) { set cbrange [asinh_lo:asinh_hi] } "
             "else { set cbrange [data_lo:data_hi] } }\n";
        s += "if (data_asinh) { set cbtics " + AsinhTicks(data_lo, data_hi, asinh_b) +
             "; set cblabel asinh_label offset -0.8,0 } else { unset cblabel; "
             "if (data_log) { set cbtics autofreq } else { set cbtics data_cbstep } }\n";
      } else if (c == 2) {
        s += "unset cblabel\n";
        s += "set palette @palette_residual\n";
        s += "unset logscale cb; set cbrange [-residual_max:residual_max];"
             " set cbtics residual_cbstep\n";
      } else {
        s += "set palette @palette_residual\n";
        s += "unset logscale cb; set cbrange [-normalised_limit:normalised_limit];"
             " set cbtics 1\n";
      }
      // valid(N) is false for the NaN of a masked pixel: the image leaves it out and the
      // second layer draws it as a grey box (half-widths 0.5 px).
      const std::string n = std::to_string(c + 3);
      if (c < 2) {
        s += "plot file using 1:2:(data_log ? clamp_log($" + n + ") : data_asinh ? asinh($" + n +
             " / asinh_b) : $" + n + ") with image, \\\n";
      } else {
        s += "plot file using 1:2:" + n + " with image, \\\n";
      }
      s += "     file using 1:2:(0.5):(valid(" + n +
           ") ? NaN : 0.5) with boxxyerror fillstyle solid 1.0 noborder"
           " fillcolor rgb masked_colour\n";
    }
  }
  s += "\nunset multiplot\nunset output\n";

  return WritePlotFiles(dir, stem, files, s, options, result, error);
}

// ---------------------------------------------------------------------------------------------
// X-y plot.

namespace {

bool ValidateXy(const XyPlotInput& in, std::string* error) {
  auto fail = [&](const std::string& what) {
    *error = "x-y plot: " + what;
    return false;
  };
  bool any = false;
  for (size_t k = 0; k < in.series.size(); ++k) {
    const Series& s = in.series[k];
    const std::string name =
        "series " + std::to_string(k) + (s.label.empty() ? "" : " ('" + OneLine(s.label) + "')");
    if (s.x.size() != s.y.size()) {
      return fail(name + " has " + std::to_string(s.x.size()) + " x and " +
                  std::to_string(s.y.size()) + " y values");
    }
    if (s.limit_x.size() != s.limit_y.size()) {
      return fail(name + " has " + std::to_string(s.limit_x.size()) + " limit x and " +
                  std::to_string(s.limit_y.size()) + " limit y values");
    }
    if (s.x.empty() && s.limit_x.empty()) return fail(name + " has no points and no limits");
    for (size_t i = 0; i < s.limit_x.size(); ++i) {
      const std::string limit = name + " limit " + std::to_string(i);
      if (!std::isfinite(s.limit_x[i]) || !std::isfinite(s.limit_y[i])) {
        return fail(limit + " is not finite");
      }
      if (in.log_x && !(s.limit_x[i] > 0)) return fail(limit + " has x <= 0 on a log x axis");
      if (in.log_y && !(s.limit_y[i] > 0)) return fail(limit + " has y <= 0 on a log y axis");
    }
    if (s.y_lo.empty() != s.y_hi.empty()) return fail(name + " has y_lo or y_hi but not both");
    if (!s.y_lo.empty() && (s.y_lo.size() != s.x.size() || s.y_hi.size() != s.x.size())) {
      return fail(name + " has " + std::to_string(s.y_lo.size()) + " y_lo and " +
                  std::to_string(s.y_hi.size()) + " y_hi values for " + std::to_string(s.x.size()) +
                  " points");
    }
    for (size_t i = 0; i < s.x.size(); ++i) {
      const std::string point = name + " point " + std::to_string(i);
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) return fail(point + " is not finite");
      if (in.log_x && !(s.x[i] > 0)) return fail(point + " has x <= 0 on a log x axis");
      if (in.log_y && !(s.y[i] > 0)) return fail(point + " has y <= 0 on a log y axis");
      if (!s.y_lo.empty()) {
        if (!std::isfinite(s.y_lo[i]) || !std::isfinite(s.y_hi[i])) {
          return fail(point + " has a non-finite error bound");
        }
        if (!(s.y_lo[i] <= s.y[i] && s.y[i] <= s.y_hi[i])) {
          return fail(point + " has y outside [y_lo, y_hi] (they are bounds, not error sizes)");
        }
      }
    }
    any = true;
  }
  for (size_t k = 0; k < in.curves.size(); ++k) {
    const Curve& c = in.curves[k];
    const std::string name =
        "curve " + std::to_string(k) + (c.label.empty() ? "" : " ('" + OneLine(c.label) + "')");
    if (c.x.size() != c.y.size()) {
      return fail(name + " has " + std::to_string(c.x.size()) + " x and " +
                  std::to_string(c.y.size()) + " y values");
    }
    if (c.x.empty()) return fail(name + " has no points");
    for (size_t i = 0; i < c.x.size(); ++i) {
      const std::string point = name + " point " + std::to_string(i);
      if (!std::isfinite(c.x[i]) || !std::isfinite(c.y[i])) return fail(point + " is not finite");
      if (in.log_x && !(c.x[i] > 0)) return fail(point + " has x <= 0 on a log x axis");
      if (in.log_y && !(c.y[i] > 0)) return fail(point + " has y <= 0 on a log y axis");
    }
    any = true;
  }
  for (size_t k = 0; k < in.requirements.size(); ++k) {
    const double y = in.requirements[k].y;
    const std::string name =
        "requirement " + std::to_string(k) + " ('" + OneLine(in.requirements[k].label) + "')";
    if (!std::isfinite(y)) return fail(name + " is not finite");
    if (in.log_y && !(y > 0)) return fail(name + " is <= 0 on a log y axis");
  }
  for (size_t k = 0; k < in.curves.size(); ++k) {
    const Curve& c = in.curves[k];
    const std::string name = "curve " + std::to_string(k);
    if (c.y_lo.empty() != c.y_hi.empty()) return fail(name + " has y_lo or y_hi but not both");
    if (c.y_lo.empty()) continue;
    if (c.y_lo.size() != c.x.size() || c.y_hi.size() != c.x.size()) {
      return fail(name + " has a band of " + std::to_string(c.y_lo.size()) + " / " +
                  std::to_string(c.y_hi.size()) + " values for " + std::to_string(c.x.size()) +
                  " points");
    }
    for (size_t i = 0; i < c.x.size(); ++i) {
      if (!std::isfinite(c.y_lo[i]) || !std::isfinite(c.y_hi[i]) ||
          !(c.y_lo[i] <= c.y[i] && c.y[i] <= c.y_hi[i])) {
        return fail(name + " point " + std::to_string(i) +
                    " has a band that is not finite or does not hold the curve");
      }
    }
  }
  const std::pair<const std::vector<Curve>*, const char*> truth_lists[] = {
      {&in.truth.curves, "truth curve "}, {&in.truth.points, "truth points "}};
  for (const auto& [list, what] : truth_lists) {
    for (size_t k = 0; k < list->size(); ++k) {
      const Curve& c = (*list)[k];
      const std::string name = what + std::to_string(k);
      if (c.x.size() != c.y.size() || c.x.empty()) {
        return fail(name + " has " + std::to_string(c.x.size()) + " x and " +
                    std::to_string(c.y.size()) + " y values");
      }
      for (size_t i = 0; i < c.x.size(); ++i) {
        if (!std::isfinite(c.x[i]) || !std::isfinite(c.y[i]) || (in.log_x && !(c.x[i] > 0)) ||
            (in.log_y && !(c.y[i] > 0))) {
          return fail(name + " point " + std::to_string(i) +
                      " is not finite or not positive on a log axis");
        }
      }
    }
  }
  if (!(in.dodge_fraction >= 0.0 && in.dodge_fraction <= 0.05)) {
    return fail("dodge_fraction " + Num(in.dodge_fraction) + " is outside [0, 0.05]");
  }
  if (!any) return fail("nothing to plot (no series or curves)");
  return true;
}

// Axis range covering `values` with a 5% margin, in log space for a log axis. Values that a
// log axis cannot show (<= 0) are left out.
std::pair<double, double> AxisRange(const std::vector<double>& values, bool log_axis) {
  double lo = kNaN, hi = kNaN;
  for (double v : values) {
    if (log_axis && !(v > 0)) continue;
    const double t = log_axis ? std::log10(v) : v;
    lo = std::isnan(lo) ? t : std::min(lo, t);
    hi = std::isnan(hi) ? t : std::max(hi, t);
  }
  if (log_axis && std::isnan(lo)) lo = hi = 0.0;
  if (!log_axis && std::isnan(lo)) lo = hi = 0.0;
  if (log_axis && !(hi > lo)) {
    lo -= 0.3;  // a factor of 2 either side of a single value
    hi += 0.3;
  }
  PadRange(0.05, &lo, &hi);
  if (log_axis) return {std::pow(10.0, lo), std::pow(10.0, hi)};
  return {lo, hi};
}

// Tick marks for a log axis over [lo, hi] (lo > 0). gnuplot labels only powers of ten, so a
// range of less than a decade would show no labelled tick: below one decade use round linear
// steps, up to three decades 1-2-5 per decade; beyond that gnuplot's own powers of ten ("").
std::string LogTicks(double lo, double hi) {
  const double decades = std::log10(hi / lo);
  std::vector<double> ticks;
  if (decades > 3) return "";
  if (decades > 1) {
    for (int e = static_cast<int>(std::floor(std::log10(lo))); std::pow(10.0, e) <= hi; ++e) {
      for (double m : {1.0, 2.0, 5.0}) {
        const double v = m * std::pow(10.0, e);
        if (v >= lo && v <= hi) ticks.push_back(v);
      }
    }
  } else {
    const double step = NiceStep(hi - lo, 5);
    for (double k = std::ceil(lo / step); k * step <= hi; k += 1.0) {
      if (k * step > 0) ticks.push_back(k * step);
    }
  }
  if (ticks.size() < 2) return "";
  std::string out = "(";
  for (size_t i = 0; i < ticks.size(); ++i) {
    char label[32];
    std::snprintf(label, sizeof(label), "%g", ticks[i]);
    out += (i ? ", " : "") + GpString(label) + " " + Num(ticks[i]);
  }
  return out + ")";
}

// Colours for series / curve k (no red: it marks requirements) and point types.
const char* const kColours[] = {"#1F77B4", "#2CA02C", "#9467BD", "#FF7F0E", "#8C564B",
                                "#E377C2", "#17BECF", "#7F7F7F", "#BCBD22", "#393B79"};
const int kPointTypes[] = {7, 5, 9, 11, 13, 15};

}  // namespace

bool WriteXyPlot(const std::string& dir, const std::string& stem, const XyPlotInput& input,
                 PlotResult* result, std::string* error, const PlotOptions& options) {
  if (!ValidateStem(stem, error) || !ValidateXy(input, error)) return false;

  const std::string x_name = input.x_label.empty() ? "x" : OneLine(input.x_label);
  const std::string y_name = input.y_label.empty() ? "y" : OneLine(input.y_label);
  std::vector<size_t> with_points;  // series with points, in order (the series file's indexes)
  std::vector<size_t> with_limits;  // series with limits, in order (the limits file's indexes)
  for (size_t k = 0; k < input.series.size(); ++k) {
    if (!input.series[k].x.empty()) with_points.push_back(k);
    if (!input.series[k].limit_x.empty()) with_limits.push_back(k);
  }

  // Axis ranges over everything drawn: true positions first, then (below) the dodged ones.
  std::vector<double> xs, ys;
  for (const Series& series : input.series) {
    for (size_t i = 0; i < series.x.size(); ++i) {
      xs.push_back(series.x[i]);
      ys.push_back(series.y[i]);
      if (!series.y_lo.empty()) ys.insert(ys.end(), {series.y_lo[i], series.y_hi[i]});
    }
    xs.insert(xs.end(), series.limit_x.begin(), series.limit_x.end());
    ys.insert(ys.end(), series.limit_y.begin(), series.limit_y.end());
  }
  for (const std::vector<Curve>* list : {&input.curves, &input.truth.curves, &input.truth.points}) {
    for (const Curve& curve : *list) {
      xs.insert(xs.end(), curve.x.begin(), curve.x.end());
      ys.insert(ys.end(), curve.y.begin(), curve.y.end());
    }
  }
  for (const Curve& curve : input.curves) {
    // On a log axis a band's lower edge <= 0 runs to the bottom (AxisRange skips it).
    ys.insert(ys.end(), curve.y_lo.begin(), curve.y_lo.end());
    ys.insert(ys.end(), curve.y_hi.begin(), curve.y_hi.end());
  }
  for (const HorizontalLine& line : input.requirements) ys.push_back(line.y);
  auto [x_lo, x_hi] = AxisRange(xs, input.log_x);
  const auto [y_lo, y_hi] = AxisRange(ys, input.log_y);

  // Dodge: series b of m moves by (b - (m - 1) / 2) f of the axis width.
  std::vector<double> shift(input.series.size(), 0.0);  // [axis units, log10 on a log axis]
  if (input.dodge_fraction > 0 && with_points.size() > 1) {
    const double axis_width = input.log_x ? std::log10(x_hi / x_lo) : x_hi - x_lo;
    const double m = static_cast<double>(with_points.size());
    for (size_t b = 0; b < with_points.size(); ++b) {
      shift[with_points[b]] = (b - (m - 1) / 2) * input.dodge_fraction * axis_width;
    }
  }
  auto drawn_x = [&](size_t k, double x) {
    return input.log_x ? x * std::pow(10.0, shift[k]) : x + shift[k];
  };
  {
    std::vector<double> dodged = xs;
    for (size_t k = 0; k < input.series.size(); ++k) {
      for (double x : input.series[k].x) dodged.push_back(drawn_x(k, x));
      for (double x : input.series[k].limit_x) dodged.push_back(drawn_x(k, x));
    }
    std::tie(x_lo, x_hi) = AxisRange(dodged, input.log_x);
  }

  std::vector<std::pair<std::string, std::string>> files;
  if (!with_points.empty()) {
    std::string d;
    d += "# Point series of " + stem +
         ".gp, one block per series that has points (gnuplot index = block"
         " number - 1).\n";
    d += "# Columns: x [" + x_name + "], y [" + y_name + "], y_lo, y_hi [" + y_name +
         "; absolute bounds, equal to y when the series has no error bars], x_drawn [" + x_name +
         "; x moved aside so that series at the same x stay apart; equal to x when not]\n";
    for (size_t b = 0; b < with_points.size(); ++b) {
      const size_t k = with_points[b];
      const Series& series = input.series[k];
      d += (b ? "\n\n" : "") + std::string("# series ") + std::to_string(k + 1) + ": " +
           OneLine(series.label) + "\n";
      for (size_t i = 0; i < series.x.size(); ++i) {
        const double lo = series.y_lo.empty() ? series.y[i] : series.y_lo[i];
        const double hi = series.y_hi.empty() ? series.y[i] : series.y_hi[i];
        d += Num(series.x[i]) + " " + Num(series.y[i]) + " " + Num(lo) + " " + Num(hi) + " " +
             Num(drawn_x(k, series.x[i])) + "\n";
      }
    }
    files.push_back({stem + "_series.dat", d});
  }
  if (!input.curves.empty()) {
    std::string d;
    d += "# Curves of " + stem + ".gp, one block per curve (gnuplot index = curve number - 1).\n";
    d += "# Columns: x [" + x_name + "], y [" + y_name + "], band_lo, band_hi [" + y_name +
         "; the shaded band; NaN: none]\n";
    for (size_t k = 0; k < input.curves.size(); ++k) {
      const Curve& curve = input.curves[k];
      d += (k ? "\n\n" : "") + std::string("# curve ") + std::to_string(k + 1) + ": " +
           OneLine(curve.label) + "\n";
      for (size_t i = 0; i < curve.x.size(); ++i) {
        d += Num(curve.x[i]) + " " + Num(curve.y[i]) + " " +
             Num(curve.y_lo.empty() ? kNaN : curve.y_lo[i]) + " " +
             Num(curve.y_hi.empty() ? kNaN : curve.y_hi[i]) + "\n";
      }
    }
    files.push_back({stem + "_curves.dat", d});
  }
  const size_t num_truths = input.truth.curves.size() + input.truth.points.size();
  if (num_truths > 0) {
    std::string d;
    d += "# True values (simulated data) in " + stem +
         ".gp: one block per truth curve, then one per set of truth points (gnuplot index = "
         "block number - 1).\n";
    d += "# Columns: x [" + x_name + "], y [" + y_name + "]\n";
    size_t block = 0;
    for (const std::vector<Curve>* list : {&input.truth.curves, &input.truth.points}) {
      for (const Curve& curve : *list) {
        d += (block++ ? "\n\n" : "") + std::string("# ") +
             (list == &input.truth.curves ? "curve: " : "points: ") + OneLine(curve.label) + "\n";
        for (size_t i = 0; i < curve.x.size(); ++i) {
          d += Num(curve.x[i]) + " " + Num(curve.y[i]) + "\n";
        }
      }
    }
    files.push_back({stem + "_truth.dat", d});
  }
  if (!with_limits.empty()) {
    // 4 % of the height: less than the 5 % margin below the lowest value (4.5 % of the height),
    // so no arrow leaves the plot.
    constexpr double kArrowFraction = 0.04;
    std::string d;
    d += "# Upper limits of " + stem + ".gp: one block per series that has them (gnuplot index "
         "= block number - 1), each point drawn as a downward arrow.\n";
    d += "# Columns: x [" + x_name + "], limit y [" + y_name + "], arrow dy [" + y_name +
         "; negative], x_drawn [" + x_name + "; moved aside like the series' points]\n";
    for (size_t b = 0; b < with_limits.size(); ++b) {
      const size_t k = with_limits[b];
      const Series& series = input.series[k];
      d += (b ? "\n\n" : "") + std::string("# series ") + std::to_string(k + 1) + ": " +
           OneLine(series.limit_label) + "\n";
      for (size_t i = 0; i < series.limit_x.size(); ++i) {
        const double y = series.limit_y[i];
        const double end = input.log_y ? y * std::pow(y_lo / y_hi, kArrowFraction)
                                       : y - kArrowFraction * (y_hi - y_lo);
        d += Num(series.limit_x[i]) + " " + Num(y) + " " + Num(end - y) + " " +
             Num(drawn_x(k, series.limit_x[i])) + "\n";
      }
    }
    files.push_back({stem + "_limits.dat", d});
  }

  // The key sits outside on the right: the canvas widens with its longest entry so that the
  // plotting area keeps its width (~7 px per character at 11 pt beyond 30 characters).
  size_t longest = 0;
  for (const Series& series : input.series) {
    longest = std::max({longest, series.label.size(), series.limit_label.size()});
  }
  for (const Curve& curve : input.curves) longest = std::max(longest, curve.label.size());
  for (const std::vector<Curve>* truth : {&input.truth.curves, &input.truth.points}) {
    for (const Curve& curve : *truth) longest = std::max(longest, curve.label.size() + 7);
  }
  const int width =
      1000 + 7 * static_cast<int>(std::min<size_t>(std::max<size_t>(longest, 30) - 30, 100));
  std::string s =
      ScriptPreamble(stem, input.title.empty() ? "x-y plot" : input.title, width, 620, 11, files);
  s += "\n# Styles: series/curve k uses line style k; requirements use style 100.\n";
  const size_t num_styles = std::max(input.series.size(), input.curves.size());
  for (size_t k = 0; k < num_styles; ++k) {
    s += "set style line " + std::to_string(k + 1) + " lw 1.5 pt " +
         std::to_string(kPointTypes[k % std::size(kPointTypes)]) + " ps 1.1 lc rgb '" +
         kColours[k % std::size(kColours)] + "'\n";
  }
  s += "set style line 100 lw 1.5 dt 2 lc rgb '#D62728'\n";
  s += "# Truth (simulated data): 101 curves, 102 points.\n";
  s += "set style line 101 lw 1.5 dt (6,4) lc rgb '#000000'\n";
  s += "set style line 102 lw 1.2 pt 12 ps 1.6 lc rgb '#000000'\n";
  s += "# Bands: the curve's colour, this opacity.\n";
  s += "band_opacity = 0.18\n";
  if (!input.title.empty()) s += "set title " + GpString(input.title) + " font ',13'\n";
  if (!input.x_label.empty()) s += "set xlabel " + GpString(input.x_label) + "\n";
  if (!input.y_label.empty()) s += "set ylabel " + GpString(input.y_label) + "\n";
  if (input.log_x) s += "set logscale x\nset xtics " + LogTicks(x_lo, x_hi) + "\n";
  if (input.log_y) s += "set logscale y\nset ytics " + LogTicks(y_lo, y_hi) + "\n";
  s += "set xrange [" + Num(x_lo) + ":" + Num(x_hi) + "]\n";
  s += "set yrange [" + Num(y_lo) + ":" + Num(y_hi) + "]\n";
  s += "set grid lc rgb '#E0E0E0'\n";
  s += "set key outside right top vertical Left reverse box samplen 3 spacing 1.3\n";
  s += "set bars small\n";
  for (size_t k = 0; k < input.requirements.size(); ++k) {
    const HorizontalLine& line = input.requirements[k];
    s += "set arrow from graph 0, first " + Num(line.y) + " to graph 1, first " + Num(line.y) +
         " nohead ls 100 front\n";
    if (!line.label.empty()) {
      s += "set label " + GpString(line.label) + " at graph 0.99, first " + Num(line.y) +
           " right offset 0,0.7 textcolor rgb '#D62728' front\n";
    }
  }

  std::vector<std::string> plots;
  const std::string series_file = GpString(stem + "_series.dat");
  const std::string curves_file = GpString(stem + "_curves.dat");
  // On a log y axis a lower bound <= 0 cannot be drawn: its bar runs to the bottom instead.
  const std::string low_column = input.log_y ? "($3 > 0 ? $3 : " + Num(y_lo) + ")" : "3";
  for (size_t b = 0; b < with_points.size(); ++b) {
    const size_t k = with_points[b];
    const Series& series = input.series[k];
    const std::string title =
        series.label.empty() ? std::string("notitle") : "title " + GpString(series.label);
    if (series.y_lo.empty()) {
      plots.push_back(series_file + " index " + std::to_string(b) + " using 5:2 with points ls " +
                      std::to_string(k + 1) + " " + title);
    } else {
      plots.push_back(series_file + " index " + std::to_string(b) + " using 5:2:" + low_column +
                      ":4 with yerrorbars ls " + std::to_string(k + 1) + " " + title);
    }
  }
  const std::string limits_file = GpString(stem + "_limits.dat");
  for (size_t b = 0; b < with_limits.size(); ++b) {
    const Series& series = input.series[with_limits[b]];
    const std::string title = series.limit_label.empty()
                                  ? std::string("notitle")
                                  : "title " + GpString(series.limit_label);
    plots.push_back(limits_file + " index " + std::to_string(b) +
                    " using 4:2:(0):3 with vectors head filled size screen 0.008,30 ls " +
                    std::to_string(with_limits[b] + 1) + " " + title);
  }
  for (size_t k = 0; k < input.curves.size(); ++k) {
    const Curve& curve = input.curves[k];
    const std::string title =
        curve.label.empty() ? std::string("notitle") : "title " + GpString(curve.label);
    plots.push_back(curves_file + " index " + std::to_string(k) + " using 1:2 with lines ls " +
                    std::to_string(k + 1) + " " + title);
  }
  // Bands go first, so that points, bars and lines are drawn over them.
  std::vector<std::string> bands;
  const std::string band_low = input.log_y ? "($3 > 0 ? $3 : " + Num(y_lo) + ")" : "3";
  for (size_t k = 0; k < input.curves.size(); ++k) {
    if (input.curves[k].y_lo.empty()) continue;
    bands.push_back(curves_file + " index " + std::to_string(k) + " using 1:" + band_low +
                    ":4 with filledcurves fillstyle transparent solid band_opacity noborder"
                    " lc rgb '" +
                    kColours[k % std::size(kColours)] + "' notitle");
  }
  plots.insert(plots.begin(), bands.begin(), bands.end());
  const std::string truth_file = GpString(stem + "_truth.dat");
  size_t truth_block = 0;
  for (const Curve& curve : input.truth.curves) {
    plots.push_back(
        truth_file + " index " + std::to_string(truth_block++) + " using 1:2 with lines ls 101 " +
        (curve.label.empty() ? std::string("notitle") : "title " + GpString(curve.label)));
  }
  for (const Curve& curve : input.truth.points) {
    plots.push_back(
        truth_file + " index " + std::to_string(truth_block++) + " using 1:2 with points ls 102 " +
        (curve.label.empty() ? std::string("notitle") : "title " + GpString(curve.label)));
  }
  s += "plot ";
  for (size_t p = 0; p < plots.size(); ++p) s += (p ? ", \\\n     " : "") + plots[p];
  s += "\nunset output\n";

  return WritePlotFiles(dir, stem, files, s, options, result, error);
}

}  // namespace ccdpsf

namespace ccdpsf {

bool WriteSensorMap(const std::string& dir, const std::string& stem, const SensorMapInput& input,
                    PlotResult* result, std::string* error, const PlotOptions& options) {
  if (!ValidateStem(stem, error)) return false;
  if (input.x.size() != input.y.size() || input.x.size() != input.value.size() ||
      input.refused_x.size() != input.refused_y.size()) {
    *error = "sensor map '" + stem + "': coordinate and value lists differ in length";
    return false;
  }
  if (input.nx <= 0 || input.ny <= 0) {
    *error = "sensor map '" + stem + "': the frame size must be positive";
    return false;
  }
  // Spots: x y value (frame pixels; 1-based in the picture as in DS9). Refused: x y.
  std::string spots = "# x_px y_px value (x, y 1-based as in DS9: frame coordinate + 1)\n";
  for (size_t i = 0; i < input.x.size(); ++i) {
    if (!std::isfinite(input.value[i])) continue;
    spots += Num(input.x[i] + 1) + " " + Num(input.y[i] + 1) + " " + Num(input.value[i]) + "\n";
  }
  std::string refused = "# x_px y_px of spots not fitted (1-based)\n";
  for (size_t i = 0; i < input.refused_x.size(); ++i) {
    refused += Num(input.refused_x[i] + 1) + " " + Num(input.refused_y[i] + 1) + "\n";
  }
  const std::vector<std::pair<std::string, std::string>> files = {{stem + "_spots.dat", spots},
                                                                  {stem + "_refused.dat", refused}};
  std::string s = ScriptPreamble(stem, input.title, 760, 680, 11, files);
  s += "set title " + GpString(input.title) + "\n";
  s += "set xlabel 'x [px] (frame column, 1-based)'\nset ylabel 'y [px] (frame row, 1-based)'\n";
  s += "set xrange [0.5:" + Num(input.nx + 0.5) + "]\nset yrange [0.5:" + Num(input.ny + 0.5) +
       "]\n";
  s += "set size ratio -1\nset cblabel " + GpString(input.value_label) + "\n";
  s += "set palette defined (0 '#313695', 1 '#74add1', 2 '#ffffbf', 3 '#f46d43', 4 '#a50026')\n";
  s += "set key outside bottom center horizontal\n";
  s += "plot '" + stem +
       "_spots.dat' using 1:2:3 with points pt 7 ps 2.2 lc palette title "
       "'fitted spots (colour: value)', \\\n";
  s += "     '" + stem +
       "_refused.dat' using 1:2 with points pt 2 ps 1.5 lc rgb '#808080' "
       "title 'not fitted (see psf_map.csv)'\n";
  return WritePlotFiles(dir, stem, files, s, options, result, error);
}

}  // namespace ccdpsf
