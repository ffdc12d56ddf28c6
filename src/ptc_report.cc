// The plots and report.md of `ccdpsf ptc` (ptc_report.h).
#include "ccdpsf/ptc_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "ccdpsf/atomic_file.h"

namespace ccdpsf {
namespace {

// Model curves are drawn through this many levels, spaced evenly in log(level).
constexpr int kCurvePoints = 120;

std::string Fmt(double v, const char* format = "%.4g") {
  if (!std::isfinite(v)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), format, v);
  return text;
}

// Levels for the model curves: from the lowest to the highest positive level used.
std::vector<double> CurveLevels(const PtcResult& r) {
  double lo = std::numeric_limits<double>::infinity(), hi = 0.0;
  for (const PtcPair& p : r.pairs) {
    if (!p.used || !(p.cov.mean_adu > 0.0)) continue;
    lo = std::min(lo, p.cov.mean_adu);
    hi = std::max(hi, p.cov.mean_adu);
  }
  std::vector<double> levels;
  if (!(hi > lo)) return levels;
  for (int k = 0; k < kCurvePoints; ++k) {
    levels.push_back(lo * std::pow(hi / lo, k / (kCurvePoints - 1.0)));
  }
  return levels;
}

// The series of lag `l`: C / mu with its sampling error, over the used pairs of positive level.
Series LagSeries(const PtcResult& r, int l, const std::string& label) {
  Series s;
  s.label = label;
  for (const PtcPair& p : r.pairs) {
    if (!p.used || !(p.cov.mean_adu > 0.0) || !std::isfinite(p.cov.cov_adu2[l])) continue;
    const double mu = p.cov.mean_adu;
    const double sd = std::isfinite(p.sd_adu2[l]) ? p.sd_adu2[l] : 0.0;
    s.x.push_back(mu);
    s.y.push_back(p.cov.cov_adu2[l] / mu);
    s.y_lo.push_back((p.cov.cov_adu2[l] - sd) / mu);
    s.y_hi.push_back((p.cov.cov_adu2[l] + sd) / mu);
  }
  return s;
}

// Draws one plot; a failure to draw is a warning, a failure to write an error.
bool Plot(const std::string& dir, const std::string& stem, const XyPlotInput& input,
          const PlotOptions& options, std::vector<std::string>* images,
          std::vector<std::string>* warnings, std::string* error) {
  PlotResult plot;
  if (!WriteXyPlot(dir, stem, input, &plot, error, options)) return false;
  const std::string name = stem + "." + PlotFormatName(options.format);
  if (plot.image_written) {
    images->push_back(name);
  } else {
    warnings->push_back(name + " not made: " + plot.message);
  }
  return true;
}

}  // namespace

bool WritePtcReport(const std::string& dir, const PtcResult& r, const PlotOptions& plot_options,
                    std::vector<std::string>* warnings, std::string* error) {
  const int side = r.max_lag + 1;
  const std::vector<double> levels = CurveLevels(r);
  std::vector<std::string> images;
  const double g = r.gain_e_per_adu.value;

  if (!levels.empty()) {
    XyPlotInput variance;
    variance.title = "Photon transfer curve: variance / mean of the flat pairs";
    variance.x_label = "mean level mu [ADU]";
    variance.y_label = "C_00 / mu [ADU]";
    variance.log_x = true;
    variance.series.push_back(LagSeries(r, 0, "C_00 / mu (pair differences)"));
    Curve model, poisson;
    model.label = "model (a_ij fitted)";
    poisson.label = "without the a_ij: (g mu + n_00) / (g^2 mu)";
    for (double mu : levels) {
      model.x.push_back(mu);
      model.y.push_back(r.ModelAdu2(0, mu) / mu);
      poisson.x.push_back(mu);
      poisson.y.push_back((g * mu + r.n[0].value) / (g * g * mu));
    }
    variance.curves = {model, poisson};
    if (!Plot(dir, "ptc_variance", variance, plot_options, &images, warnings, error)) return false;

    XyPlotInput covariances;
    covariances.title = "Pixel covariances of the flat pairs";
    covariances.x_label = "mean level mu [ADU]";
    covariances.y_label = "C_ij / mu [ADU]";
    covariances.log_x = true;
    covariances.dodge_fraction = 0.01;
    for (const auto& [i, j] :
         std::vector<std::pair<int, int>>{{1, 0}, {0, 1}, {1, 1}, {2, 0}, {0, 2}}) {
      if (i > r.max_lag || j > r.max_lag) continue;
      const int l = j * side + i;
      const std::string name = "C_" + r.lag_names[l];
      covariances.series.push_back(LagSeries(r, l, name + " / mu"));
      Curve c;
      c.label = name + " model";
      for (double mu : levels) {
        c.x.push_back(mu);
        c.y.push_back(r.ModelAdu2(l, mu) / mu);
      }
      covariances.curves.push_back(c);
    }
    if (!Plot(dir, "ptc_covariances", covariances, plot_options, &images, warnings, error)) {
      return false;
    }
  }

  std::ostringstream md;
  md << "# ccdpsf ptc\n\n"
     << "Photon transfer with pixel covariances from " << r.pairs_used << " flat pair(s) of "
     << r.pairs.size() << ", levels " << Fmt(r.min_level_adu) << " to " << Fmt(r.max_level_adu)
     << " ADU above the bias (" << Fmt(r.bias_adu, "%.6g") << " ADU, " << r.bias_source << ").\n\n"
     << "| quantity | value | sd |\n|---|---|---|\n"
     << "| gain [e-/ADU] | " << Fmt(g, "%.5g") << " | " << Fmt(r.gain_e_per_adu.sd, "%.2g")
     << " |\n";
  if (std::isfinite(r.read_noise_e.value)) {
    md << "| read noise [e-] | " << Fmt(r.read_noise_e.value) << " | "
       << Fmt(r.read_noise_e.sd, "%.2g") << " |\n";
  } else {
    md << "| read noise [e-] | < " << Fmt(r.read_noise_upper_e) << " (2 sd) | - |\n";
  }
  md << "| sum of the a_ij within the range [1/e-] | " << Fmt(r.a_sum.value, "%.3g") << " | "
     << Fmt(r.a_sum.sd, "%.2g") << " |\n\n";
  md << "## Boundary-shift coefficients\n\n"
     << "a_ij [1/e-]: the fractional area change of pixel (i, j) (i along x, j along y) per "
        "electron in pixel (0, 0) (Astier et al. 2019); n_ij [e-^2]: the constant term "
        "(read noise and the ADC's rounding at lag 0).\n\n"
     << "| lag | a_ij | sd | n_ij | sd |" << (r.b.empty() ? "" : " b_ij | sd |") << "\n"
     << "|---|---|---|---|---|" << (r.b.empty() ? "" : "---|---|") << "\n";
  for (size_t l = 0; l < r.a.size(); ++l) {
    md << "| " << r.lag_names[l] << " | " << Fmt(r.a[l].value, "%.4g") << " | "
       << Fmt(r.a[l].sd, "%.2g") << " | " << Fmt(r.n[l].value, "%.4g") << " | "
       << Fmt(r.n[l].sd, "%.2g") << " |";
    if (!r.b.empty()) {
      md << " " << Fmt(r.b[l].value, "%.3g") << " | " << Fmt(r.b[l].sd, "%.2g") << " |";
    }
    md << "\n";
  }
  md << "\n## Model\n\n"
     << "C_ij(mu) = (K_ij(g mu) + n_ij) / g^2 [ADU^2] at the pair's mean level mu [ADU, bias "
        "subtracted], with K [e-^2] the solution of dK/dmu = 2 a(mu) (*) K + delta, "
        "a_ij(mu) = a_ij (1 + b_ij mu): per spatial frequency K^ = mu f0(x) + (ab)^ mu^3 h(x), "
        "x = 2 a^ mu, f0(x) = (e^x - 1) / x, h(x) = e^x / x - 2 (e^x - 1 - x) / x^3 (exact in "
        "a, first order in b; its series is Astier et al.'s eq. 20). Model \""
     << PtcModelName(r.model) << "\"" << (r.b.empty() ? " (b_ij = 0)" : " (b_ij fitted)")
     << ", lags 0 <= i, j <= " << r.max_lag << ". Weighted least squares, weights the inverse "
     << "sampling variances C_00^2 / N_ij (2 C_00^2 / N_00 at lag 0); chi2 " << Fmt(r.chi2, "%.5g")
     << " for " << r.dof << " degrees of freedom";
  if (r.sd_scale > 1.0) {
    md << "; the sds are scaled by sqrt(chi2/dof) = " << Fmt(r.sd_scale, "%.3g");
  }
  md << ".\n\n## Pairs\n\n| files | exposure [s] | mu [ADU] | C_00 [ADU^2] | C_10 | C_01 | "
        "pixels kept | used |\n|---|---|---|---|---|---|---|---|\n";
  for (const PtcPair& p : r.pairs) {
    md << "| " << p.first << ", " << p.second << " | " << Fmt(p.exptime_s) << " | "
       << Fmt(p.cov.mean_adu, "%.6g") << " | " << Fmt(p.cov.cov_adu2[0], "%.6g") << " | "
       << Fmt(p.cov.cov_adu2[1], "%.4g") << " | " << Fmt(p.cov.cov_adu2[side], "%.4g") << " | "
       << p.cov.kept << " | " << (p.used ? "yes" : "no: " + p.excluded_because) << " |\n";
  }
  md << "\n## Plots\n\n";
  if (images.empty()) {
    md << "No picture was made (see the warnings); the .dat and .gp files are here.\n";
  }
  for (const std::string& image : images) md << "![" << image << "](" << image << ")\n\n";
  std::vector<std::string> all = r.warnings;
  all.insert(all.end(), warnings->begin(), warnings->end());
  if (!all.empty()) {
    md << "\n## Warnings\n\n";
    for (const std::string& w : all) md << "- " << w << "\n";
  }
  return WriteTextFileAtomically(dir + "/report.md", md.str(), error);
}

}  // namespace ccdpsf
