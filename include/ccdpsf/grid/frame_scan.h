// Every spot of a full frame, found in one pass over its rows: the catalogue of sources with
// the reason each one cannot be fitted, and a small cutout around each one that can.
//
// The frame is read a strip of rows at a time (FitsImageStream), each row once, and only the
// strip in hand plus a margin of rows on either side is kept: for a 4096 x 4096 frame about
// 5 MB of doubles instead of 128 MB. In each strip the sources are found as spot_finder.h
// finds them (local maxima of the 3 x 3-smoothed frame that stand min_significance sds of
// the smoothed background above its level, with the background level and sds measured in
// that strip, so a slow gradient across the sensor does not matter), every one of them
// kept, not only the best. A source is fitted only when it is
//   inside:   its stamp fits in the data section                 (else "edge")
//   extended: not a single pixel: its peak pixel holds at most max_single_pixel_fraction
//             (0.95) of the 3 x 3 core's signal. A hot pixel or cosmic-ray hit holds nearly
//             all of it; a centred Gaussian spot of total sigma s holds
//             [erf(0.5 / (s sqrt 2)) / erf(1.5 / (s sqrt 2))]^2: 0.36 at s = 0.6 px, 0.82 at
//             0.3 px (an undersampled bench spot holds 0.84), 0.95 at 0.22 px, below which
//             the widths are not measurable anyway                  (else "single_pixel")
//   compact:  spot_finder.h's size, elongation and core fraction (else "extended")
//   isolated: spot_finder.h's surround (no light 4-7 px from the peak) (else "crowded")
// Each fitted source keeps a cutout of (2 cutout_half + 1)^2 pixels centred on its peak
// pixel (clipped at the frame's edges), in ADU as stored, for calibration (exposure.h): the
// stamp, and background around it for the bias and read noise when no keyword or flag gives
// them.
//
// Coordinates are frame coordinates (image.h): 0-based, pixel centres at integers.
#ifndef CCDPSF_GRID_FRAME_SCAN_H_
#define CCDPSF_GRID_FRAME_SCAN_H_

#include <cstdint>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/image.h"
#include "ccdpsf/spot_finder.h"

namespace ccdpsf::grid {

struct FrameScanOptions {
  SpotFinderOptions finder;  // thresholds and stamp size; max_candidates is not used
  double max_single_pixel_fraction = 0.95;
  int cutout_half = 24;  // cutouts of 49 x 49 px: the 21 x 21 stamp and ~1800 px around
  int strip_rows = 128;  // rows read at a time
};

// One detected source.
struct FrameSource {
  SpotCandidate shape;  // spot_finder.h's measures; peak in frame coordinates
  double x_px = 0.0;    // flux-weighted centroid of the 5 x 5 box at the peak [px]
  double y_px = 0.0;
  double background_adu = 0.0;         // the strip's background level [ADU]
  double single_pixel_fraction = 0.0;  // peak pixel signal / 3 x 3 core signal
  std::string refused;                 // "" when it is fitted; else "edge", "single_pixel", ...
  std::string reason;                  // the refusal in words, with the numbers
  int cutout = -1;                     // index into ScannedFrame::cutouts, -1 when refused
};

// A cutout as a FitsImage: the frame's header without its section keywords, the frame's
// BITPIX and ADC range, pixels in ADU; (x0, y0) is its first pixel in frame coordinates.
struct FrameCutout {
  FitsImage image;
  int x0 = 0;
  int y0 = 0;
};

struct ScannedFrame {
  std::string path;
  std::string hdu;     // as asked ("" = ReadFitsImage's choice)
  int hdu_number = 1;  // 1-based absolute HDU read
  std::string extname;
  int nx = 0, ny = 0;
  FitsHeader header;                 // the HDU's keywords
  PixelRegion data_region;           // the data section (DATASEC or flag), else the whole frame
  std::vector<FrameSource> sources;  // every source found, by peak row then column
  std::vector<FrameCutout> cutouts;
  uint64_t pixel_digest = 0;  // FNV-1a of every pixel read: the same frame under two names
};

// Scans one frame. `calibration` gives the HDU, the keyword map and given values (a data
// section, a search region). False with a one-line reason, naming the file, when it cannot
// be read or a section is malformed; a frame with no source is not an error (no sources).
bool ScanFrame(const std::string& path, const CalibrationOptions& calibration,
               const FrameScanOptions& options, ScannedFrame* out, std::string* error);

}  // namespace ccdpsf::grid

#endif  // CCDPSF_GRID_FRAME_SCAN_H_
