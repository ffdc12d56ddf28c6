// Calibration of one spot exposure: from a FITS frame in ADU to a Stamp in electrons.
//
// Usage:
//   CalibrationOptions options;             // what the user gave; the rest from the header
//   options.Set("gain_e_per_adu", 3.1, "flag --gain_e_per_adu");
//   std::string error;
//   std::optional<Exposure> exposure = LoadExposure("spot.fits", options, &error);
//   if (!exposure) { std::cerr << error << "\n"; return 1; }   // one line, names the file
//   const Stamp& stamp = exposure->stamp;
//
// Where each number comes from is metadata.h's precedence (given value, then the header
// keyword under the keyword map's name, then an estimate, else unknown). Here:
//
//   gain [e-/ADU]      given or keyword, else an error (a gain cannot be estimated from one
//                      frame; `ccdpsf gain` estimates it from a set)
//   bias [ADU]         given or keyword, else the sigma-clipped mean of the bias section
//                      (overscan), else of the background far from the spot
//   read noise [e-]    given or keyword, else gain x the sigma-clipped sd of the same pixels
//                      (less the 1/12 ADU^2 of rounding for integer data)
//                      Both estimates are refused, with the reason, when they cannot be
//                      right: a background clipped at the black level (many pixels at
//                      exactly its minimum) or a spread below the ADC step.
//   saturation [ADU]   given or keyword, else none; pixels at or above it are censored
//                      ("at least this much"), not masked and not fitted as data
//   pixel size [um]    given or keyword, else unknown (NaN; a fit refuses to run without it)
//   wavelength, exposure time, focus position: given or keyword, else unknown (NaN)
//
// Detector limits, all recorded in the report:
//   - the ADC's range (FitsImage::adc_min / adc_max, from BITPIX and BZERO/BSCALE): pixels
//     at its top are censored from above, at its bottom from below (a clipped black level);
//   - a black-level clip below the ADC's range: when >= 1 % of the data section's pixels sit
//     at exactly the frame's minimum value, pixels at that value are censored from below;
//   - a clipped top without a saturation level: >= 2 pixels of the stamp at exactly its
//     maximum value, far above the background, are censored from above (finding
//     "clipped_top");
//   - a peak within 10 % of the ADC's full scale with no saturation level known (finding
//     "near_full_scale": it may be compressed).
// Contamination (contamination.h): a user's bad-pixel mask (non-zero = bad), columns that
// differ from their neighbours over the rows away from the spot (masked in the stamp), and
// other sources in the stamp (masked beyond the spot's core, reported).
// The spot (spot_finder.h): the given position, else the compact, isolated source of the
// data section (or of the search region) with the candidates reported.
//
// The stamp is stamp_size x stamp_size with the peak pixel at index c = (stamp_size - 1) / 2
// in both axes (10 for 21 x 21, 9 for 20 x 20): the centre convention of the authors' 2015
// code. All coordinates follow image.h: 0-based, pixel centres at integers, x = column.
#ifndef CCDPSF_EXPOSURE_H_
#define CCDPSF_EXPOSURE_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/contamination.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/image.h"
#include "ccdpsf/metadata.h"
#include "ccdpsf/quality.h"
#include "ccdpsf/spot_finder.h"

namespace ccdpsf {

struct CalibrationOptions {
  // Values given for this file (flags, manifest row, FIT.json), already merged by precedence.
  GivenMetadata given;
  KeywordMap keywords;

  int stamp_size = 21;        // side of the square stamp [px], >= 5; odd or even
  double min_peak_snr = 5.0;  // a found spot's 3x3-smoothed peak must exceed this many
                              // standard deviations of the smoothed background
  bool mask_column_defects = true;
  bool mask_stamp_sources = true;

  // A value given in code (source "option" unless named).
  void Set(const std::string& quantity, double value, const std::string& source = "option");
  void SetText(const std::string& quantity, const std::string& value,
               const std::string& source = "option");

  // Returns false with a one-line reason if a given value is out of range (non-finite, a
  // gain <= 0, a stamp smaller than 5, only one of spot_x_px / spot_y_px, a malformed
  // section, ...).
  bool IsValid(std::string* error) const;
};

// Pixels of the stamp that are masked, and why.
struct StampMask {
  std::string reason;    // "bad-pixel mask", "column 37 (hot, +129 ADU)", "source at ..."
  int pixels = 0;        // masked in the stamp
  int core_pixels = 0;   // of which within 1.5 px of the peak pixel
};

// Where each number came from and what calibration saw, for the run's log and report.
struct CalibrationReport {
  MetadataRecord metadata;    // every quantity, its value and its source
  std::string Source(const std::string& quantity) const;

  std::string spot_source;    // "flag --spot_x_px ...", "manifest ...", or "found"
  SpotSearch spot_search;     // candidates examined (empty when the position was given)
  SpotCandidate spot;         // the chosen source's shape measures
  double spot_x_px = 0.0;     // spot position in frame coordinates [px]: the given position,
  double spot_y_px = 0.0;     // or the flux-weighted first moment in a 5 x 5 box at the peak
  int peak_x_px = 0;          // the peak pixel (frame coordinates), placed at the stamp's
  int peak_y_px = 0;          // centre index
  double peak_adu = 0.0;      // stored value of the peak pixel [ADU], bias included
  double peak_e = 0.0;        // bias-subtracted peak pixel [e-]; NaN if masked
  double peak_snr = 0.0;      // significance of the found spot; NaN when it was given

  // Standard deviation of the pixels the bias / read noise were estimated from [ADU]
  // (rounding included), and how many; NaN and 0 when nothing was estimated.
  double noise_rms_adu = 0.0;
  int noise_pixels = 0;
  // The background around the spot used for spot finding [ADU] and its single-pixel sd.
  double background_adu = 0.0;
  double background_sd_adu = 0.0;

  // Censoring levels [ADU] (+-infinity: none) and their sources.
  double ceiling_adu = INFINITY;
  std::string ceiling_source = "none";
  double floor_adu = -INFINITY;
  std::string floor_source = "none";
  int censored_high = 0;  // stamp pixels at or above the ceiling
  int censored_low = 0;   // stamp pixels at or below the floor
  int censored_core = 0;  // censored pixels within 1.5 px of the peak pixel

  int masked_pixels = 0;  // masked pixels in the stamp
  std::vector<StampMask> masks;
  bool columns_checked = false;
  std::vector<ColumnDefect> column_defects;  // those crossing the stamp
  std::vector<StampSource> stamp_sources;

  Quality quality;  // findings of calibration (quality.h)
};

nlohmann::json CalibrationReportJson(const CalibrationReport& report);

// A calibrated exposure: the stamp every fit consumes, and how it was made.
struct Exposure {
  Stamp stamp;
  CalibrationReport report;
};

// Calibrates a frame that has already been read. `source` names it in messages and in
// stamp.info.source. `bad_pixels` (may be null) is a mask of the frame's size, non-zero =
// bad. On failure returns nullopt and a one-line reason, starting with the quoted source,
// in *error: no gain, a gain <= 0, a malformed or out-of-frame section, no usable pixels,
// no significant spot, a spot too close to the frame edge for the stamp, a stamp in which
// every pixel is masked, a bias or read noise that cannot be estimated, ...
std::optional<Exposure> CalibrateExposure(const FitsImage& image, const std::string& source,
                                          const CalibrationOptions& options, std::string* error,
                                          const Image* bad_pixels = nullptr);

// Reads the file (the HDU the options name; for a file with several image extensions and
// no HDU given, the segment holding the most significant compact source, recorded as
// "auto"), its bad-pixel mask if one is given, and calibrates it.
std::optional<Exposure> LoadExposure(const std::string& path, const CalibrationOptions& options,
                                     std::string* error);

// ---------------------------------------------------------------------------------------
// Building blocks, public so that they can be tested and reused.

// Parses an IRAF image section "[x1:x2,y1:y2]" (1-based, inclusive; x counts NAXIS1
// columns) for an nx x ny frame. "*" stands for a whole axis and a single number for one
// column or row; reversed ranges ("[20:1,...]") cover the same pixels. Blanks are allowed.
// Fails with a reason (which quotes the section) if the text is not such a section or
// reaches outside the frame.
std::optional<PixelRegion> ParseIrafSection(const std::string& section, int nx, int ny,
                                            std::string* error);

// Robust statistics of a sample contaminated by a few outliers (cosmic rays, spot wings).
struct ClippedStats {
  double mean = 0.0;    // mean of the values kept
  double median = 0.0;  // median of the values kept
  // Standard deviation of the parent normal distribution: the sample standard deviation of
  // the values kept, divided by the factor by which clipping at +-clip_sigma standard
  // deviations shrinks it (0.985 for clip_sigma = 3), so that it is unbiased for normal data.
  double stddev = 0.0;
  int num_used = 0;  // values kept after clipping
};

// Iterated sigma clipping: drops values further than clip_sigma standard deviations from the
// median and repeats until nothing changes (at most 20 rounds). Non-finite values are
// ignored. Returns nullopt if no finite value is left.
std::optional<ClippedStats> SigmaClippedStats(std::vector<double> values, double clip_sigma = 3.0);

}  // namespace ccdpsf

#endif  // CCDPSF_EXPOSURE_H_
