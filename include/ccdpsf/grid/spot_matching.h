// The same spot in every exposure of a setting: sources matched by position.
//
// The first exposure's sources are the reference; a source of another exposure belongs to
// the reference source whose centroid is nearest, if within match_radius_px (a projector
// drifts by hundredths of a pixel between exposures; grid spots are hundreds apart), each
// reference taken at most once. A source no reference takes starts a spot of its own (seen
// from that exposure on), so a source missing from the first exposure is still reported.
// A spot is fitted only when every exposure holds it and none refused it: one refusal in
// any exposure (crowded, extended, ...) refuses the spot with that reason and exposure, and
// a spot missing from some exposures is refused as "missing" (a transient such as a cosmic
// ray, or a source at the detection threshold).
//
// Spots are numbered by their reference position, row (y rounded to whole pixels) first,
// then x, so the numbering depends only on the frames, not on the order of work.
#ifndef CCDPSF_GRID_SPOT_MATCHING_H_
#define CCDPSF_GRID_SPOT_MATCHING_H_

#include <string>
#include <vector>

#include "ccdpsf/grid/frame_scan.h"

namespace ccdpsf::grid {

struct GridSpot {
  double x_px = 0.0;  // centroid in the first exposure that holds it [px, frame]
  double y_px = 0.0;
  std::vector<int> source;  // per exposure: index into that frame's sources, -1 if absent
  std::string refused;      // "" when fitted; else "edge", "crowded", ..., "missing"
  std::string reason;       // in words, naming the exposure
};

std::vector<GridSpot> MatchSpots(const std::vector<ScannedFrame>& frames, double match_radius_px);

}  // namespace ccdpsf::grid

#endif  // CCDPSF_GRID_SPOT_MATCHING_H_
