// Spot selection: the spot to fit is the compact, isolated source the model can describe,
// not merely the brightest pixel (a lab frame may hold bright caustic arcs, vignetting
// edges, a second pinhole, hot columns).
//
// Candidates are the local maxima of the 3 x 3 box-smoothed frame (the brightest in their
// 5 x 5 neighbourhood) that stand min_significance standard deviations of the smoothed
// background above its level. For each, on the unsmoothed frame less the background level,
// counting only pixels more than 2 single-pixel sd above it (so that noise does not inflate
// the moments):
//   size_px            sqrt of the mean of the second moments about the centroid in the
//                      7 x 7 box around the peak pixel [px]
//   elongation         sqrt(largest / smallest eigenvalue) of that moment matrix, each
//                      eigenvalue at least 1/12 px^2 (a pixel's own)
//   core_fraction      signal in the 3 x 3 box / signal in the 7 x 7 box
//   surround_fraction  signal at Chebyshev distance 4-7 px from the peak / 3 x 3 signal
// A candidate is compact when size_px <= max_size_px, elongation <= max_elongation and
// core_fraction >= min_core_fraction; isolated when surround_fraction <= max_surround and
// no pixel at distance 4-7 px exceeds max_neighbour_peak of the peak. (The paper's spots,
// total sigma ~0.6 px, have size ~0.6 px, elongation ~1.1, core fraction ~0.9; a caustic
// arc is elongated, a defocused pedestal is large with a small core fraction.)
// The chosen spot is the most significant compact candidate whose stamp fits the frame,
// isolated ones first; when none is compact, the most significant candidate is chosen and
// the search says so (the fit's verdict then cannot be "ok").
#ifndef CCDPSF_SPOT_FINDER_H_
#define CCDPSF_SPOT_FINDER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "ccdpsf/image.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

// A rectangle of frame pixels, 0-based and half-open: x_begin <= x < x_end.
struct PixelRegion {
  int x_begin = 0;
  int x_end = 0;
  int y_begin = 0;
  int y_end = 0;
  bool Contains(int x, int y) const {
    return x >= x_begin && x < x_end && y >= y_begin && y < y_end;
  }
  int Width() const { return x_end - x_begin; }
  int Height() const { return y_end - y_begin; }
};

struct SpotFinderOptions {
  double min_significance = 5.0;
  int stamp_size = 21;           // a candidate's stamp must fit inside the frame region
  double max_size_px = 2.5;
  double max_elongation = 2.5;
  double min_core_fraction = 0.5;
  double max_surround = 0.15;
  double max_neighbour_peak = 0.25;
  int max_candidates = 20;       // the most significant ones are examined and reported
};

struct SpotCandidate {
  int peak_x = 0, peak_y = 0;  // brightest pixel of the source (frame coordinates)
  double peak_adu = 0.0;       // its stored value [ADU]
  double significance = 0.0;   // smoothed peak above the background [sd of the smoothed bkg]
  double size_px = 0.0;
  double elongation = 1.0;
  double core_fraction = 0.0;
  double surround_fraction = 0.0;
  bool compact = false;
  bool isolated = false;
  bool stamp_fits = false;     // its stamp lies inside the frame region
  std::string note;            // "chosen", or why not
};

struct SpotSearch {
  std::vector<SpotCandidate> candidates;  // most significant first
  int chosen = -1;                        // index into candidates, -1 if none
  std::string problem;  // set when the chosen spot is not a compact, isolated source
};

// The frame in ADU with its mask (1 = usable) and its SmoothBox3; `region` the pixels to
// search (the data section, or a user's search region within it); `background_adu` and the
// sds of single pixels and of 3 x 3 means of the background [ADU].
SpotSearch FindSpots(const Image& adu, const std::vector<uint8_t>& valid, const Image& smoothed,
                     const PixelRegion& region, double background_adu, double pixel_sd_adu,
                     double smoothed_sd_adu, const SpotFinderOptions& options);

// The shape measures above for a source whose peak pixel is given (a user's position).
SpotCandidate DescribeSource(const Image& adu, const std::vector<uint8_t>& valid,
                             const PixelRegion& region, int peak_x, int peak_y,
                             double background_adu, double pixel_sd_adu,
                             const SpotFinderOptions& options);

// Mean of the valid pixels in the 3 x 3 box centred on every pixel of `region` [ADU]
// (NaN where the box holds fewer than 3 valid pixels, and outside the region).
Image SmoothBox3(const Image& adu, const std::vector<uint8_t>& valid, const PixelRegion& region);

nlohmann::json SpotCandidateJson(const SpotCandidate& c);

}  // namespace ccdpsf

#endif  // CCDPSF_SPOT_FINDER_H_
