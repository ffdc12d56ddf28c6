// Calibration of one spot exposure: from a FITS frame in ADU to a Stamp in electrons.
//
// Usage:
//   CalibrationOptions options;        // unset fields: use the header keywords or estimate
//   options.gain_e_per_adu = 3.1;      // a command-line override
//   std::string error;
//   std::optional<Exposure> exposure = LoadExposure("spot.fits", options, &error);
//   if (!exposure) { std::cerr << error << "\n"; return 1; }   // one line, names the file
//   const Stamp& stamp = exposure->stamp;
//
// Each calibration number has one source, in this order of precedence (the report says
// which one was used):
//
//   gain [e-/ADU]      option, keyword GAIN, else an error (a gain cannot be estimated from
//                      one frame)
//   bias [ADU]         option, keyword BIASLVL, the sigma-clipped mean of the BIASSEC region,
//                      else the sigma-clipped mean of the background (pixels far from the spot)
//   read noise [e-]    option, keyword RDNOISE, else gain x the sigma-clipped standard
//                      deviation of the same pixels as the bias (BIASSEC if present, else the
//                      background), with the 1/12 ADU^2 rounding variance removed when the
//                      pixel values are integers
//   saturation [ADU]   option, keyword SATURATE, else none
//
// Masked pixels (valid = 0): non-finite values and values >= saturation. The spot is found
// automatically (the brightest 3x3 region of the frame, which must stand min_peak_snr times
// the background noise above the background) unless its position is given. The stamp is
// stamp_size x stamp_size with the peak pixel at index c = (stamp_size - 1) / 2 in both axes
// (10 for 21 x 21, 9 for 20 x 20): the centre convention of the authors' 2015 code.
//
// All coordinates follow image.h: 0-based, pixel centres at integers, x = column (NAXIS1).
#ifndef CCDPSF_EXPOSURE_H_
#define CCDPSF_EXPOSURE_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/image.h"

namespace ccdpsf {

// Overrides of what the header says. An unset field means "use the keyword, else estimate
// (or use the default)".
struct CalibrationOptions {
  std::optional<double> gain_e_per_adu;     // [e-/ADU], > 0; overrides GAIN
  std::optional<double> read_noise_e;       // [e-], >= 0; overrides RDNOISE
  std::optional<double> bias_adu;           // [ADU]; overrides BIASLVL and BIASSEC
  std::optional<double> saturation_adu;     // [ADU]; overrides SATURATE; pixels >= it are masked
  std::optional<double> wavelength_nm;      // [nm], > 0; overrides WAVELEN
  std::optional<double> exptime_s;          // [s], >= 0; overrides EXPTIME
  std::optional<double> pixel_um;           // [um], > 0; overrides PIXSIZE (default 12)
  std::optional<double> focus_position_um;  // [um]; overrides FOCUSPOS

  // Spot position in frame coordinates [px]. Give both to skip spot finding: the stamp is
  // then centred on the pixel nearest to (spot_x_px, spot_y_px).
  std::optional<double> spot_x_px;
  std::optional<double> spot_y_px;

  int stamp_size = 21;        // side of the square stamp [px], >= 5; odd or even
  double min_peak_snr = 5.0;  // a found spot's 3x3-smoothed peak must exceed this many
                              // standard deviations of the smoothed background

  // Returns false with a one-line reason if a field is out of range (non-finite values, a
  // gain <= 0, a stamp smaller than 5, only one of spot_x_px / spot_y_px, ...).
  bool IsValid(std::string* error) const;
};

// Where each number came from and what the spot finder saw, for the run's log and report.
struct CalibrationReport {
  std::string gain_source;        // "option" or "keyword GAIN"
  std::string bias_source;        // "option", "keyword BIASLVL", "BIASSEC [1:10,1:64] (640 px)"
                                  // or "sigma-clipped background (7367 px)"
  std::string read_noise_source;  // as bias_source, with RDNOISE for the keyword
  std::string saturation_source;  // "option", "keyword SATURATE" or "none"
  std::string spot_source;        // "option" or "found"

  double spot_x_px = 0.0;  // spot position in frame coordinates [px]: the given position, or
  double spot_y_px = 0.0;  // the flux-weighted first moment in a 5 x 5 box around the peak
  int peak_x_px = 0;       // the peak pixel (frame coordinates), placed at the stamp's
  int peak_y_px = 0;       // centre index
  double peak_adu = 0.0;   // stored value of the peak pixel [ADU], bias included (comparable
                           // with SATURATE); NaN if that pixel is not finite
  double peak_e = 0.0;     // bias-subtracted peak pixel [e-]; NaN if the pixel is masked
  double peak_snr = 0.0;   // significance of the found spot (see min_peak_snr); NaN when the
                           // position was given

  // Standard deviation of the pixels the bias / read noise were estimated from [ADU] (rounding
  // included), and how many there were; NaN and 0 when nothing was estimated from pixels.
  double noise_rms_adu = 0.0;
  int noise_pixels = 0;

  int masked_pixels = 0;  // masked pixels in the stamp
};

// A calibrated exposure: the stamp every fit consumes, and how it was made.
struct Exposure {
  Stamp stamp;
  CalibrationReport report;
};

// Calibrates a frame that has already been read. `source` names it in messages and in
// stamp.info.source. On failure returns nullopt and a one-line reason, starting with the
// quoted source, in *error: no gain, a gain <= 0, a malformed or out-of-frame BIASSEC, no
// usable pixels, no significant spot, a spot too close to the frame edge for the stamp, a
// stamp in which every pixel is masked, ...
std::optional<Exposure> CalibrateExposure(const FitsImage& image, const std::string& source,
                                          const CalibrationOptions& options, std::string* error);

// ReadFitsImage followed by CalibrateExposure; errors of either come back in *error.
std::optional<Exposure> LoadExposure(const std::string& path, const CalibrationOptions& options,
                                     std::string* error);

// ---------------------------------------------------------------------------------------
// Building blocks, public so that they can be tested and reused.

// A rectangle of frame pixels, 0-based and half-open: x_begin <= x < x_end.
struct PixelRegion {
  int x_begin = 0;
  int x_end = 0;
  int y_begin = 0;
  int y_end = 0;
};

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
