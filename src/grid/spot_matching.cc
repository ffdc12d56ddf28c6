// Sources matched across the exposures of a setting (spot_matching.h).
#include "ccdpsf/grid/spot_matching.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>

namespace ccdpsf::grid {

std::vector<GridSpot> MatchSpots(const std::vector<ScannedFrame>& frames, double match_radius_px) {
  const int n = static_cast<int>(frames.size());
  std::vector<GridSpot> spots;
  for (int e = 0; e < n; ++e) {
    const std::vector<FrameSource>& sources = frames[e].sources;
    // Pairs (distance, spot, source) within the radius, nearest first: a greedy assignment
    // that is exact when spots are much further apart than the radius.
    struct Pair {
      double d2;
      int spot, source;
    };
    std::vector<Pair> pairs;
    for (int s = 0; s < static_cast<int>(spots.size()); ++s) {
      for (int k = 0; k < static_cast<int>(sources.size()); ++k) {
        const double dx = sources[k].x_px - spots[s].x_px, dy = sources[k].y_px - spots[s].y_px;
        const double d2 = dx * dx + dy * dy;
        if (d2 <= match_radius_px * match_radius_px) pairs.push_back({d2, s, k});
      }
    }
    std::stable_sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) {
      return a.d2 != b.d2 ? a.d2 < b.d2
                          : (a.spot != b.spot ? a.spot < b.spot : a.source < b.source);
    });
    std::vector<uint8_t> taken(sources.size(), 0);
    for (const Pair& p : pairs) {
      if (taken[p.source] || spots[p.spot].source[e] >= 0) continue;
      spots[p.spot].source[e] = p.source;
      taken[p.source] = 1;
    }
    for (int k = 0; k < static_cast<int>(sources.size()); ++k) {
      if (taken[k]) continue;
      GridSpot spot;
      spot.x_px = sources[k].x_px;
      spot.y_px = sources[k].y_px;
      spot.source.assign(n, -1);
      spot.source[e] = k;
      spots.push_back(std::move(spot));
    }
  }
  for (GridSpot& spot : spots) {
    int present = 0;
    for (int e = 0; e < n; ++e) {
      if (spot.source[e] < 0) continue;
      ++present;
      const FrameSource& s = frames[e].sources[spot.source[e]];
      if (spot.refused.empty() && !s.refused.empty()) {
        spot.refused = s.refused;
        spot.reason =
            s.reason + " (in " + std::filesystem::path(frames[e].path).filename().string() + ")";
      }
    }
    if (spot.refused.empty() && present < n) {
      spot.refused = "missing";
      spot.reason = "found in " + std::to_string(present) + " of " + std::to_string(n) +
                    " exposures (a transient such as a cosmic ray, or a source at the "
                    "detection threshold)";
    }
  }
  std::stable_sort(spots.begin(), spots.end(), [](const GridSpot& a, const GridSpot& b) {
    const double ya = std::round(a.y_px), yb = std::round(b.y_px);
    return ya != yb ? ya < yb : a.x_px < b.x_px;
  });
  return spots;
}

}  // namespace ccdpsf::grid
