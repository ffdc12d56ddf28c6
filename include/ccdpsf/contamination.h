// Contamination of a spot stamp found before any fit: hot or dead columns through it, and
// other sources in it (a second pinhole, a cosmic ray, a hot pixel). What is found is masked
// in the stamp where that is safe, and reported either way. (Contamination that only the
// fit can see, such as a cosmic ray on the spot's core, is the robust fit's business:
// fit/robust_fit.h.)
#ifndef CCDPSF_CONTAMINATION_H_
#define CCDPSF_CONTAMINATION_H_

#include <cstdint>
#include <string>
#include <vector>

#include "ccdpsf/image.h"
#include "ccdpsf/spot_finder.h"

namespace ccdpsf {

// A column whose level differs from its neighbours' over the rows away from the spot.
struct ColumnDefect {
  int x = 0;                 // frame column
  double excess_adu = 0.0;   // its median minus the median of its neighbours [ADU]
  double significance = 0.0; // excess / robust spread of such differences over the frame
};

// Columns of `region` (x within [x_first, x_last], inclusive) whose median over the rows of
// `region` further than exclude_rows from row y_spot differs from the median of the columns
// up to 5 away on either side by more than `threshold` robust sds of that difference across
// all columns (and by at least 1 sd of a single pixel, so that a frame with a flat,
// noiseless background flags nothing). Needs at least 8 such rows; with fewer, returns
// nothing and sets *checked = false.
std::vector<ColumnDefect> FindColumnDefects(const Image& adu, const std::vector<uint8_t>& valid,
                                            const PixelRegion& region, int x_first, int x_last,
                                            int y_spot, int exclude_rows, double pixel_sd_adu,
                                            double threshold, bool* checked);

// Another source in a stamp: a local maximum of the 3 x 3-smoothed stamp at least
// min_distance_px from the spot's peak pixel and min_significance smoothed sds above the
// background.
struct StampSource {
  int x = 0, y = 0;            // peak pixel, frame coordinates
  double distance_px = 0.0;    // from the spot's peak pixel
  double peak_adu = 0.0;       // above the background
  double significance = 0.0;
  int radius_px = 0;           // masked disc radius (0: not masked)
  int masked_pixels = 0;
};

// Finds such sources in the stamp [x0, x0 + n) x [y0, y0 + n) of the frame and masks (in
// `stamp_valid`, n x n, row-major) a disc around each, out to the first ring (of the pixels
// nearer to it than to the spot) whose mean signal is below 2 single-pixel sds of the
// background, but never a pixel within protect_radius_px of the spot's peak: light of a
// source that close cannot be told from the spot's before a fit (the caller reports it).
// A source is a pixel that is the maximum of its 3 x 3 neighbourhood, min_significance
// pixel sds above the background and min_significance times its own noise above the mean of
// its neighbours (a spot's profile falls smoothly outwards, so at >= 3 px its pixels are
// neither maxima nor sharp; a cosmic ray, a hot pixel or another spot is both).
std::vector<StampSource> FindAndMaskStampSources(const Image& adu, const std::vector<uint8_t>& valid,
                                                 int x0, int y0, int n, int spot_x, int spot_y,
                                                 double background_adu, double pixel_sd_adu,
                                                 double smoothed_sd_adu, double min_significance,
                                                 double min_distance_px, double protect_radius_px,
                                                 std::vector<uint8_t>* stamp_valid);

}  // namespace ccdpsf

#endif  // CCDPSF_CONTAMINATION_H_
