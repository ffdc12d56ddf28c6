#include "ccdpsf/diagnose/signatures.h"

#include <map>
#include <set>
#include <utility>

namespace ccdpsf::diagnose {

const std::vector<std::string>& SignatureStatistics(const std::string& name) {
  // From what each effect does to the image (model/effects.h) and the statistics' definitions
  // (statistics.h).
  static const std::map<std::string, std::vector<std::string>> table = {
      {"background", {"chi2_per_dof", "outer_z", "radial_chi2"}},
      {"halo", {"chi2_per_dof", "ring_z", "outer_z", "radial_chi2", "core_z"}},
      {"serial_cti", {"chi2_per_dof", "odd_x_z"}},
      {"parallel_cti", {"chi2_per_dof", "odd_y_z"}},
      {"ipc", {"chi2_per_dof", "neighbour_z", "core_z", "peak_z"}},
      {"jitter", {"chi2_per_dof", "width_scatter", "ring_z", "core_z"}},
      {"nonlinearity", {"chi2_per_dof", "peak_trend_z", "core_z", "peak_z"}},
      {"brighter_fatter", {"chi2_per_dof", "peak_trend_z", "width_scatter", "core_z", "ring_z"}},
      // A boundary moved by the charge: the core flattens with the signal and the four edge
      // neighbours gain more than the diagonals (model/boundary_shift.h).
      {"boundary_shift",
       {"chi2_per_dof", "peak_trend_z", "width_scatter", "core_z", "neighbour_z"}},
      {"defocus", {"chi2_per_dof", "core_z", "ring_z", "radial_chi2", "peak_z"}},
      {"defocus_offset", {"chi2_per_dof", "odd_x_z", "odd_y_z"}},
      {"pillbox_defocus", {"chi2_per_dof", "core_z", "ring_z", "radial_chi2", "peak_z"}},
      {"pixel_response",
       {"chi2_per_dof", "core_z", "ring_z", "neighbour_z", "peak_z", "radial_chi2"}},
  };
  static const std::vector<std::string> none;
  const auto it = table.find(name);
  return it == table.end() ? none : it->second;
}

std::string SeparatingData(const std::string& a, const std::string& b) {
  const std::set<std::string> pair = {a, b};
  const auto is = [&](const std::string& x, const std::string& y) {
    return pair == std::set<std::string>{x, y};
  };
  const auto has = [&](const std::string& x) { return pair.count(x) > 0; };
  if (is("boundary_shift", "brighter_fatter")) {
    return "flat fields (ccdpsf ptc): moved boundaries correlate neighbouring pixels of a flat "
           "as a_ij mu^2, the empirical width law predicts nothing there; and brighter spots: "
           "moved boundaries give the edge neighbours more than the diagonals, a wider "
           "Gaussian gives both alike";
  }
  if (is("nonlinearity", "boundary_shift")) {
    return "a wider range of intensities, with exposure times known: moved boundaries keep "
           "the charge, nonlinearity compresses the peak and loses signal against exposure "
           "time";
  }
  if (is("nonlinearity", "brighter_fatter")) {
    return "a wider range of intensities, with exposure times known: brighter-fatter widens the "
           "whole profile and keeps the charge, nonlinearity compresses the peak and loses "
           "signal against exposure time";
  }
  if (is("halo", "background")) {
    return "a larger stamp: a halo falls off with distance from the spot, a pedestal does not";
  }
  if (has("ipc") &&
      (has("brighter_fatter") || has("boundary_shift") || has("nonlinearity"))) {
    return "a second intensity: interpixel capacitance does not change with the signal";
  }
  if (has("jitter") && (has("brighter_fatter") || has("boundary_shift"))) {
    return "exposures at one intensity: jitter still changes the widths, brighter-fatter does "
           "not";
  }
  if (is("serial_cti", "defocus_offset") || is("parallel_cti", "defocus_offset")) {
    return "the spot at another place on the sensor (more or fewer transfers): a trail grows "
           "with the transfers, an optical offset does not";
  }
  if (has("pillbox_defocus") || has("defocus")) {
    return "a through-focus series: the defocus grows away from best focus, the CCD's own "
           "blur does not";
  }
  if (has("pixel_response")) {
    return "a sharper spot (in focus, shorter wavelength) or flat fields: the pixel's "
           "collecting window shows most when the spot is smaller than the pixel";
  }
  return "more exposures, or exposures at other intensities or focus positions";
}

}  // namespace ccdpsf::diagnose
