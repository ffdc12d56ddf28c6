// Column defects and other sources in a stamp (contamination.h).
#include "ccdpsf/contamination.h"

#include <algorithm>
#include <cmath>

namespace ccdpsf {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return NAN;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  const double upper = v[mid];
  if (v.size() % 2 == 1) return upper;
  return 0.5 * (upper + *std::max_element(v.begin(), v.begin() + mid));
}

// Rows needed for a column's median to mean something (its sd is ~1.25 sigma / sqrt(n)).
constexpr int kMinRowsForColumns = 8;
// Neighbouring columns on each side that form a column's reference level.
constexpr int kColumnNeighbours = 5;

}  // namespace

std::vector<ColumnDefect> FindColumnDefects(const Image& adu, const std::vector<uint8_t>& valid,
                                            const PixelRegion& region, int x_first, int x_last,
                                            int y_spot, int exclude_rows, double pixel_sd_adu,
                                            double threshold, bool* checked) {
  std::vector<ColumnDefect> out;
  *checked = false;
  const int nx = region.Width();
  if (nx < 2 * kColumnNeighbours + 1) return out;
  // Median of every column of the region over the rows away from the spot.
  std::vector<double> level(nx, NAN);
  std::vector<double> values;
  int rows = 0;
  for (int y = region.y_begin; y < region.y_end; ++y) rows += std::abs(y - y_spot) > exclude_rows;
  if (rows < kMinRowsForColumns) return out;
  for (int i = 0; i < nx; ++i) {
    const int x = region.x_begin + i;
    values.clear();
    for (int y = region.y_begin; y < region.y_end; ++y) {
      if (std::abs(y - y_spot) <= exclude_rows) continue;
      const size_t k = static_cast<size_t>(y) * adu.nx + x;
      if (valid[k]) values.push_back(adu.data[k]);
    }
    if (static_cast<int>(values.size()) >= kMinRowsForColumns) level[i] = Median(values);
  }
  // Each column against the median of its neighbours; the spread of those differences over
  // the frame (1.4826 x MAD) is the noise of the test, as illumination may vary slowly.
  std::vector<double> diff(nx, NAN);
  std::vector<double> finite;
  for (int i = 0; i < nx; ++i) {
    if (std::isnan(level[i])) continue;
    std::vector<double> around;
    for (int j = i - kColumnNeighbours; j <= i + kColumnNeighbours; ++j) {
      if (j == i || j < 0 || j >= nx || std::isnan(level[j])) continue;
      around.push_back(level[j]);
    }
    if (around.size() < 4) continue;
    diff[i] = level[i] - Median(around);
    finite.push_back(diff[i]);
  }
  if (finite.size() < 10) return out;
  const double centre = Median(finite);
  std::vector<double> deviations;
  for (double d : finite) deviations.push_back(std::fabs(d - centre));
  const double spread = 1.4826 * Median(deviations);
  // The difference of medians of >= 8 noisy values cannot be sharper than the pixels' own
  // noise allows: 1.25 sd / sqrt(rows) per column median.
  const double floor_sd = 1.2533 * pixel_sd_adu / std::sqrt(static_cast<double>(rows));
  const double sd = std::max(spread, floor_sd);
  *checked = true;
  for (int i = std::max(0, x_first - region.x_begin); i <= std::min(nx - 1, x_last - region.x_begin);
       ++i) {
    if (std::isnan(diff[i]) || !(sd > 0)) continue;
    const double z = (diff[i] - centre) / sd;
    if (std::fabs(z) > threshold && std::fabs(diff[i] - centre) >= pixel_sd_adu) {
      out.push_back({region.x_begin + i, diff[i] - centre, z});
    }
  }
  return out;
}

std::vector<StampSource> FindAndMaskStampSources(const Image& adu, const std::vector<uint8_t>& valid,
                                                 int x0, int y0, int n, int spot_x, int spot_y,
                                                 double background_adu, double pixel_sd_adu,
                                                 double smoothed_sd_adu, double min_significance,
                                                 double min_distance_px, double protect_radius_px,
                                                 std::vector<uint8_t>* stamp_valid) {
  (void)smoothed_sd_adu;
  std::vector<StampSource> out;
  auto usable = [&](int x, int y) {
    if (x < x0 || y < y0 || x >= x0 + n || y >= y0 + n) return false;
    return valid[static_cast<size_t>(y) * adu.nx + x] != 0 &&
           (*stamp_valid)[static_cast<size_t>(y - y0) * n + (x - x0)] != 0;
  };
  // The noise of one pixel holding signal s [ADU]: sqrt(s / g + sd^2) needs the gain, which
  // this stage does not use; s itself bounds the Poisson variance in ADU for g >= 1 e-/ADU,
  // and the test below is one-sided, so sqrt(s + sd^2) is a conservative (larger) noise.
  auto noise = [&](double signal) {
    return std::sqrt(std::max(0.0, signal) + pixel_sd_adu * pixel_sd_adu);
  };
  for (int y = y0; y < y0 + n; ++y) {
    for (int x = x0; x < x0 + n; ++x) {
      if (!usable(x, y)) continue;
      const double distance = std::hypot(x - spot_x, y - spot_y);
      if (distance < min_distance_px) continue;
      const double v = adu(x, y);
      const double signal = v - background_adu;
      if (!(signal >= min_significance * pixel_sd_adu)) continue;
      // A local maximum standing clear of its neighbours: the spot's own profile falls
      // smoothly outwards, so at >= 3 px its pixels are neither maxima nor sharp.
      double sum = 0.0;
      int count = 0;
      bool is_max = true;
      for (int dy = -1; dy <= 1 && is_max; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0) continue;
          if (!usable(x + dx, y + dy)) continue;
          const double w = adu(x + dx, y + dy);
          if (w >= v) {
            is_max = false;
            break;
          }
          sum += w;
          ++count;
        }
      }
      if (!is_max || count < 3) continue;
      const double excess = v - sum / count;
      if (excess < min_significance * noise(signal)) continue;
      StampSource s;
      s.x = x;
      s.y = y;
      s.distance_px = distance;
      s.peak_adu = signal;
      s.significance = signal / pixel_sd_adu;
      out.push_back(s);
    }
  }
  // Mask a disc around each: out to the first ring (of the pixels nearer to it than to the
  // spot) whose mean signal is below 2 pixel sds.
  for (StampSource& s : out) {
    int radius = 6;
    for (int r = 1; r <= 6; ++r) {
      double sum = 0.0;
      int count = 0;
      for (int y = s.y - r - 1; y <= s.y + r + 1; ++y) {
        for (int x = s.x - r - 1; x <= s.x + r + 1; ++x) {
          const double d = std::hypot(x - s.x, y - s.y);
          if (d < r - 0.5 || d >= r + 0.5 || !usable(x, y)) continue;
          if (std::hypot(x - spot_x, y - spot_y) <= d) continue;
          sum += adu(x, y) - background_adu;
          ++count;
        }
      }
      if (count == 0 || sum / count < 2.0 * pixel_sd_adu) {
        radius = r;
        break;
      }
    }
    s.radius_px = radius;
    for (int y = s.y - radius; y <= s.y + radius; ++y) {
      for (int x = s.x - radius; x <= s.x + radius; ++x) {
        if (x < x0 || y < y0 || x >= x0 + n || y >= y0 + n) continue;
        if (std::hypot(x - s.x, y - s.y) > radius + 0.01) continue;
        if (std::hypot(x - spot_x, y - spot_y) <= protect_radius_px) continue;
        uint8_t& v = (*stamp_valid)[static_cast<size_t>(y - y0) * n + (x - x0)];
        if (v) {
          v = 0;
          ++s.masked_pixels;
        }
      }
    }
  }
  return out;
}

}  // namespace ccdpsf
