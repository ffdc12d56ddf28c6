#include "ccdpsf/fit/intensity_plot.h"

#include <cmath>
#include <utility>
#include <vector>

namespace ccdpsf::fit {

bool WriteIntensityPlot(const std::string& dir, const std::string& stem,
                        const IntensityPoints& points, const PlotOptions& options,
                        PlotResult* result, std::string* error) {
  if (points.effect.empty()) {
    *error = "the intensity plot needs a joint fit with brighter_fatter or boundary_shift";
    return false;
  }
  // Curve slots 0, 1 are the CCD widths, 2, 3 the totals (WidthSummaries' order).
  const int first = points.ccd_identified ? 0 : 2;
  const char* kind = points.ccd_identified ? "CCD kernel width" : "total width sqrt(defocus^2 + sigma^2)";
  XyPlotInput in;
  in.title = std::string("widths against signal (") + points.effect + ")";
  in.x_label = "peak pixel [e-]";
  in.y_label = std::string(kind) + " [px]";
  in.dodge_fraction = 0.005;
  const char* axis_name[2] = {"x", "y"};
  // The series first, so that series k and curve k (one axis) share a colour.
  for (int a = 0; a < 2; ++a) {
    Series alone;
    alone.label = std::string(axis_name[a]) + ": each exposure alone, without the effect (MAP +- Laplace sd)";
    for (const IntensityPoint& p : points.points) {
      const Summary& s = WidthAt(p.measured, first + a);
      if (!p.failure.empty() || !std::isfinite(s.map) || !std::isfinite(p.peak_e)) continue;
      const double sd = std::isfinite(s.laplace_sd) ? s.laplace_sd : 0.0;
      alone.x.push_back(p.peak_e);
      alone.y.push_back(s.map);
      alone.y_lo.push_back(s.map - sd);
      alone.y_hi.push_back(s.map + sd);
    }
    if (!alone.x.empty()) in.series.push_back(std::move(alone));
  }
  for (int a = 0; a < 2; ++a) {
    Curve predicted;
    const std::vector<Summary>& nodes = points.curve_widths[first + a];
    bool banded = true;
    for (size_t i = 0; i < nodes.size() && i < points.curve_peak_e.size(); ++i) {
      banded = banded && std::isfinite(nodes[i].median);
    }
    for (size_t i = 0; i < nodes.size() && i < points.curve_peak_e.size(); ++i) {
      const Summary& s = nodes[i];
      const double centre = banded ? s.median : s.map;
      if (!std::isfinite(points.curve_peak_e[i]) || !std::isfinite(centre)) continue;
      predicted.x.push_back(points.curve_peak_e[i]);
      predicted.y.push_back(centre);
      if (banded) {
        predicted.y_lo.push_back(s.lo68);
        predicted.y_hi.push_back(s.hi68);
      }
    }
    predicted.label = std::string(axis_name[a]) + ": predicted, " +
                      (banded ? "posterior median and 68 % band" : "at the MAP");
    if (predicted.x.size() >= 2) in.curves.push_back(std::move(predicted));
  }
  if (in.curves.empty()) {
    *error = "the intensity plot has no predicted curve to draw";
    return false;
  }
  // The intrinsic width: flat over the curve's span.
  const double x_lo = in.curves[0].x.front(), x_hi = in.curves[0].x.back();
  for (int a = 0; a < 2; ++a) {
    const Summary& s = WidthAt(points.intrinsic, first + a);
    const double level = std::isfinite(s.median) ? s.median : s.map;
    if (!std::isfinite(level)) continue;
    Curve flat;
    flat.label = std::string(axis_name[a]) + ": intrinsic (zero signal), " +
                 (std::isfinite(s.median) ? "posterior median" : "MAP");
    flat.x = {x_lo, x_hi};
    flat.y = {level, level};
    in.curves.push_back(std::move(flat));
  }
  return WriteXyPlot(dir, stem, in, result, error, options);
}

}  // namespace ccdpsf::fit
