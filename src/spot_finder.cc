// Spot selection (spot_finder.h).
#include "ccdpsf/spot_finder.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// A box needs this many valid pixels to count, so that a lone valid pixel between masked
// ones cannot masquerade as a bright smoothed region.
constexpr int kMinValidInBox = 3;

// Boxes of the shape measures (spot_finder.h): 3 x 3 core, 7 x 7 moments, surround 4-7 px.
constexpr int kCoreHalf = 1;
constexpr int kMomentHalf = 3;
constexpr int kSurroundInner = 4;
constexpr int kSurroundOuter = 7;

// Pixels counted by the shape measures must be this many single-pixel sds above the
// background: at 2 sd a pure-noise pixel passes 2.3 % of the time, which keeps the moments
// of a faint spot from being dominated by the noise of the 49-pixel box.
constexpr double kSignalThresholdSd = 2.0;

}  // namespace

Image SmoothBox3(const Image& adu, const std::vector<uint8_t>& valid, const PixelRegion& region) {
  Image smoothed(adu.nx, adu.ny, kNaN);
  for (int y = region.y_begin; y < region.y_end; ++y) {
    for (int x = region.x_begin; x < region.x_end; ++x) {
      double sum = 0.0;
      int count = 0;
      for (int yy = std::max(region.y_begin, y - 1); yy <= std::min(region.y_end - 1, y + 1); ++yy) {
        for (int xx = std::max(region.x_begin, x - 1); xx <= std::min(region.x_end - 1, x + 1);
             ++xx) {
          const size_t k = static_cast<size_t>(yy) * adu.nx + xx;
          if (!valid[k]) continue;
          sum += adu.data[k];
          ++count;
        }
      }
      if (count >= kMinValidInBox) smoothed(x, y) = sum / count;
    }
  }
  return smoothed;
}

SpotCandidate DescribeSource(const Image& adu, const std::vector<uint8_t>& valid,
                             const PixelRegion& region, int peak_x, int peak_y,
                             double background_adu, double pixel_sd_adu,
                             const SpotFinderOptions& options) {
  SpotCandidate c;
  c.peak_x = peak_x;
  c.peak_y = peak_y;
  c.peak_adu = adu(peak_x, peak_y);
  const double threshold = kSignalThresholdSd * pixel_sd_adu;
  auto signal = [&](int x, int y) {
    if (!region.Contains(x, y)) return 0.0;
    const size_t k = static_cast<size_t>(y) * adu.nx + x;
    if (!valid[k]) return 0.0;
    const double s = adu.data[k] - background_adu;
    return s > threshold ? s : 0.0;
  };
  double core = 0.0, box = 0.0, sum = 0.0, sx = 0.0, sy = 0.0;
  for (int dy = -kMomentHalf; dy <= kMomentHalf; ++dy) {
    for (int dx = -kMomentHalf; dx <= kMomentHalf; ++dx) {
      const double s = signal(peak_x + dx, peak_y + dy);
      box += s;
      if (std::abs(dx) <= kCoreHalf && std::abs(dy) <= kCoreHalf) core += s;
      sum += s;
      sx += s * dx;
      sy += s * dy;
    }
  }
  double ixx = 1.0 / 12.0, iyy = 1.0 / 12.0, ixy = 0.0;
  if (sum > 0.0) {
    const double mx = sx / sum, my = sy / sum;
    double wxx = 0.0, wyy = 0.0, wxy = 0.0;
    for (int dy = -kMomentHalf; dy <= kMomentHalf; ++dy) {
      for (int dx = -kMomentHalf; dx <= kMomentHalf; ++dx) {
        const double s = signal(peak_x + dx, peak_y + dy);
        wxx += s * (dx - mx) * (dx - mx);
        wyy += s * (dy - my) * (dy - my);
        wxy += s * (dx - mx) * (dy - my);
      }
    }
    // Each pixel spreads its light over its own unit square: 1/12 px^2 per axis.
    ixx = wxx / sum + 1.0 / 12.0;
    iyy = wyy / sum + 1.0 / 12.0;
    ixy = wxy / sum;
  }
  const double mean = 0.5 * (ixx + iyy);
  const double half_diff = std::sqrt(0.25 * (ixx - iyy) * (ixx - iyy) + ixy * ixy);
  const double largest = mean + half_diff;
  const double smallest = std::max(1.0 / 12.0, mean - half_diff);
  c.size_px = std::sqrt(mean);
  c.elongation = std::sqrt(largest / smallest);
  c.core_fraction = box > 0.0 ? core / box : 0.0;

  double surround = 0.0, surround_peak = 0.0;
  for (int dy = -kSurroundOuter; dy <= kSurroundOuter; ++dy) {
    for (int dx = -kSurroundOuter; dx <= kSurroundOuter; ++dx) {
      if (std::max(std::abs(dx), std::abs(dy)) < kSurroundInner) continue;
      const double s = signal(peak_x + dx, peak_y + dy);
      surround += s;
      surround_peak = std::max(surround_peak, s);
    }
  }
  const double peak_signal = std::max(0.0, c.peak_adu - background_adu);
  c.surround_fraction = core > 0.0 ? surround / core : INFINITY;
  c.compact = c.size_px <= options.max_size_px && c.elongation <= options.max_elongation &&
              c.core_fraction >= options.min_core_fraction;
  c.isolated = c.surround_fraction <= options.max_surround &&
               surround_peak <= options.max_neighbour_peak * peak_signal;
  const int n = options.stamp_size, half = (n - 1) / 2;
  c.stamp_fits = peak_x - half >= region.x_begin && peak_y - half >= region.y_begin &&
                 peak_x - half + n <= region.x_end && peak_y - half + n <= region.y_end;
  return c;
}

SpotSearch FindSpots(const Image& adu, const std::vector<uint8_t>& valid, const Image& smoothed,
                     const PixelRegion& region, double background_adu, double pixel_sd_adu,
                     double smoothed_sd_adu, const SpotFinderOptions& options) {
  SpotSearch search;
  const double floor = background_adu + options.min_significance * smoothed_sd_adu;
  struct Peak {
    int x, y;
    double value;
  };
  std::vector<Peak> peaks;
  for (int y = region.y_begin; y < region.y_end; ++y) {
    for (int x = region.x_begin; x < region.x_end; ++x) {
      const double v = smoothed(x, y);
      if (!(v > floor) && !(smoothed_sd_adu <= 0.0 && v > background_adu)) continue;
      // A local maximum: no neighbour within 2 px is higher, and none earlier in reading
      // order is equal (so a flat top yields one peak).
      bool is_max = true;
      for (int dy = -2; dy <= 2 && is_max; ++dy) {
        for (int dx = -2; dx <= 2; ++dx) {
          if (dx == 0 && dy == 0) continue;
          const int xx = x + dx, yy = y + dy;
          if (!region.Contains(xx, yy)) continue;
          const double w = smoothed(xx, yy);
          if (w > v || (w == v && (dy < 0 || (dy == 0 && dx < 0)))) {
            is_max = false;
            break;
          }
        }
      }
      if (is_max) peaks.push_back({x, y, v});
    }
  }
  std::stable_sort(peaks.begin(), peaks.end(),
                   [](const Peak& a, const Peak& b) { return a.value > b.value; });
  if (static_cast<int>(peaks.size()) > options.max_candidates) peaks.resize(options.max_candidates);
  for (const Peak& p : peaks) {
    // The source's peak pixel: the brightest valid pixel of the 3 x 3 box.
    int bx = p.x, by = p.y;
    double best = -INFINITY;
    for (int y = std::max(region.y_begin, p.y - 1); y <= std::min(region.y_end - 1, p.y + 1); ++y) {
      for (int x = std::max(region.x_begin, p.x - 1); x <= std::min(region.x_end - 1, p.x + 1);
           ++x) {
        const size_t k = static_cast<size_t>(y) * adu.nx + x;
        if (valid[k] && adu.data[k] > best) {
          best = adu.data[k];
          bx = x;
          by = y;
        }
      }
    }
    SpotCandidate c =
        DescribeSource(adu, valid, region, bx, by, background_adu, pixel_sd_adu, options);
    c.significance = smoothed_sd_adu > 0.0 ? (p.value - background_adu) / smoothed_sd_adu
                                           : std::numeric_limits<double>::infinity();
    search.candidates.push_back(c);
  }

  // Isolated compact sources first, then compact ones; the most significant of the class.
  auto pick = [&](bool need_isolated) {
    for (size_t i = 0; i < search.candidates.size(); ++i) {
      const SpotCandidate& c = search.candidates[i];
      if (c.compact && c.stamp_fits && (c.isolated || !need_isolated)) return static_cast<int>(i);
    }
    return -1;
  };
  search.chosen = pick(true);
  if (search.chosen < 0) search.chosen = pick(false);
  if (search.chosen >= 0 && !search.candidates[search.chosen].isolated) {
    search.problem = "the spot is not isolated: other light lies 4-7 px from it";
  }
  if (search.chosen < 0) {
    for (size_t i = 0; i < search.candidates.size() && search.chosen < 0; ++i) {
      if (search.candidates[i].stamp_fits) search.chosen = static_cast<int>(i);
    }
    if (search.chosen >= 0) {
      const SpotCandidate& c = search.candidates[search.chosen];
      char text[256];
      std::snprintf(text, sizeof(text),
                    "no compact source found: the most significant, at (%d, %d), is extended "
                    "(size %.2f px, elongation %.2f, core fraction %.2f)",
                    c.peak_x, c.peak_y, c.size_px, c.elongation, c.core_fraction);
      search.problem = text;
    }
  }
  for (size_t i = 0; i < search.candidates.size(); ++i) {
    SpotCandidate& c = search.candidates[i];
    if (static_cast<int>(i) == search.chosen) {
      c.note = "chosen";
    } else if (!c.stamp_fits) {
      c.note = "too close to the edge for the stamp";
    } else if (!c.compact) {
      c.note = "extended";
    } else if (!c.isolated) {
      c.note = "compact, not isolated";
    } else {
      c.note = "compact, less significant";
    }
  }
  return search;
}

nlohmann::json SpotCandidateJson(const SpotCandidate& c) {
  auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); };
  return {{"peak_px", {c.peak_x, c.peak_y}},
          {"peak_adu", num(c.peak_adu)},
          {"significance", num(c.significance)},
          {"size_px", num(c.size_px)},
          {"elongation", num(c.elongation)},
          {"core_fraction", num(c.core_fraction)},
          {"surround_fraction", num(c.surround_fraction)},
          {"compact", c.compact},
          {"isolated", c.isolated},
          {"note", c.note}};
}

}  // namespace ccdpsf
