// A photon-transfer estimate of a camera's gain [e-/ADU] and read noise [e-] from the frames
// a user has, for cameras whose headers record neither (`ccdpsf gain`).
//
// The photon transfer relation, per pixel, for a pixel whose mean level is m [ADU]:
//
//     var [ADU^2] = (m - bias) / g + (RN / g)^2 + q        q = 1/12 for integer data
//
// (Poisson photo-electrons: variance (m - bias) g [e-^2] = (m - bias) / g [ADU^2]; read noise
// RN [e-]; q the ADC's rounding of a uniformly distributed fraction, 0 for floating-point
// data). Points (mean, variance) at several levels are fitted with the straight line
// var = a + m / g; g is the inverse slope. The intercept is a = -bias / g + (RN / g)^2 + q, so
// the read noise follows from it only when the bias is known.
//
// Where the points come from, chosen by what the input allows (PhotonTransferOptions::method):
//
//   pairs          two frames under the same illumination (the same exposure time, the same
//                  scene, and WAVELEN / FOCUSPOS equal where both headers have them), taken two
//                  by two in input order: the difference d = A - B cancels everything fixed
//                  (the spot, vignetting, the pupil image, pixel response non-uniformity),
//                  leaving twice the single-frame noise. Each pixel's d is binned by the level
//                  of its 8 neighbours in (A + B) / 2 (not its own level, whose noise would
//                  otherwise select the sample); a bin's point is (mean of the pixels' own
//                  (A + B) / 2, var(d) / 2), the variance taken about the bin's mean difference
//                  so that a small change of illumination between the frames drops out. A pixel
//                  is used only where the difference did cancel, judged by its 8 neighbours'
//                  differences (again independent of its own noise): a spot that moved between
//                  the frames leaves coherent lobes, which are left out.
//   single_frame   no two frames share an illumination: one frame's own pixels. The sample is
//                  the difference of two horizontally adjacent pixels minus the same difference
//                  one row below, dd = (p[x+1,y] - p[x,y]) - (p[x+1,y+1] - p[x,y+1]), over
//                  non-overlapping 2 x 2 blocks: var(dd) = 4 var(pixel). It cancels any plane
//                  (the illumination gradient, in x and in y), any curvature along x or along y
//                  alone, and row and column offsets; only the mixed curvature d2I/dxdy at the
//                  one-pixel scale remains. Blocks are kept only where the frame is smooth: a
//                  plane is fitted to the 32 pixels of the 6 x 6 box centred on the block
//                  without the block's own 4 pixels (so the choice is independent of the
//                  block's noise; a 5 x 5 box cannot be centred on a 2 x 2 block), and the
//                  block is smooth when that plane's residual variance is at most 1.5 x the
//                  noise variance at that level (the 95th percentile of a chi-square with 29
//                  degrees of freedom over 29 is 1.47: ~5 % of pure-noise blocks are dropped,
//                  and blocks whose structure reaches half the noise variance are). The noise
//                  variance is first each bin's median ring variance (most blocks of a level
//                  are smooth), then the fitted line. The binning level is the ring's mean; the
//                  point's level is the mean of the blocks' own pixels. Fixed pattern at the
//                  pixel scale (pixel response non-uniformity) is not cancelled, nor is noise
//                  correlated between neighbouring pixels: both bias this estimator (PRNU adds
//                  (f m)^2 and lowers g; correlation lowers the variance and raises g), which
//                  pairs avoid.
//
// The frames' exposure times, ADC limits, pairing and bias: photon_transfer_frames.h (shared
// with `ccdpsf ptc`). Levels the ADC cannot record faithfully are kept out (rules in
// photon_transfer.cc):
//   - a black level clipped by the ADC (the frame's minimum value holds >= 1 % of its pixels
//     and >= 10 of them): pixels at that value (and any at the ADC's bottom) are "at the
//     floor". Going up from the lowest bin, every bin in which more than 0.1 % of the samples
//     touch the floor is excluded until the first that is clear of it (a normal distribution
//     cut 3.1 sd below its mean loses ~1 % of its variance); a higher bin that touches the
//     floor through structure (an arc beside dark pixels) is excluded alone;
//   - the top: samples with a pixel at or above min(ADC maximum, saturation) are dropped, and
//     every bin from the lowest whose noise reaches the top (mean + 3.1 sd above it, i.e.
//     more than 0.1 % of its pixels would be clipped) upwards is excluded; so are bins above
//     90 % of the ADC's range (the compression before full scale).
//
// The fit is weighted least squares over the bins, weight = dof / (2 var_model^2) (the
// variance of a sample variance of dof degrees of freedom), iterated with the fitted model;
// the parameter covariance is scaled by chi2 / dof when that exceeds 1. sd(g) = sd(1/g) g^2.
// The whole is repeated with the fitted line as the noise model (at most 6 rounds, until it
// no longer changes): outliers are then clipped at 5 sd of the noise expected at each
// sample's own level (a bin may hold pixels of very different levels beside a sharp spot),
// a bin's dof is Satterthwaite's effective number of samples, and the selections above use
// it. A point further than 6 of its sds from the line through the others is dropped (with
// the reason). A gain is given only when the slope is positive by 3 sd (by Student's t at
// the same tail probability when the fit has few degrees of freedom).
// Everything is deterministic: no random numbers are drawn.
#ifndef CCDPSF_PHOTON_TRANSFER_H_
#define CCDPSF_PHOTON_TRANSFER_H_

#include <limits>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/photon_transfer_frames.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

enum class PtcMethod { kAuto, kPairs, kSingleFrame };
// "auto", "pairs", "single_frame"; Parse returns false on anything else.
const char* PtcMethodName(PtcMethod method);
bool ParsePtcMethod(const std::string& text, PtcMethod* method);

// The frames' exposure times, scenes, bias and saturation: photon_transfer_frames.h.
struct PhotonTransferOptions : TransferFrameOptions {
  // kAuto: pairs when at least two frames share an illumination (above), else single_frame.
  PtcMethod method = PtcMethod::kAuto;
  int num_bins = 24;              // level bins before merging (see BuildBins in the .cc)
  int min_samples_per_bin = 100;  // a bin with fewer samples is merged into its neighbour

  bool IsValid(std::string* error) const;
};

// One level bin of the transfer curve.
struct PtcPoint {
  double mean_adu = 0.0;          // mean level of the samples' own pixels [ADU]
  double variance_adu2 = 0.0;     // single-pixel variance [ADU^2]
  double variance_sd_adu2 = 0.0;  // its sd from the fitted model: var sqrt(2 / dof)
  long long pixels = 0;           // samples: pixel positions (pairs) or 2 x 2 blocks
  double dof = 0.0;               // degrees of freedom of the variance (Satterthwaite's
                                  // effective number of samples, less one per cell)
  double bin_low_adu = 0.0;       // the bin's edges in the binning level [ADU]
  double bin_high_adu = 0.0;
  double floor_fraction = 0.0;    // samples touching the clipped black level
  double ceiling_fraction = 0.0;  // samples that touched the ADC's top or saturation
  bool used = false;
  std::string excluded_because;  // empty when used
};

struct PhotonTransferResult {
  std::string method;  // "pairs" or "single_frame"
  double gain_e_per_adu = std::numeric_limits<double>::quiet_NaN();
  double gain_sd_e_per_adu = std::numeric_limits<double>::quiet_NaN();
  // From the intercept, given the bias; NaN (with a warning saying why) when the bias is
  // unknown or the read-noise variance is not positive by 2 sd.
  double read_noise_e = std::numeric_limits<double>::quiet_NaN();
  double read_noise_sd_e = std::numeric_limits<double>::quiet_NaN();
  double read_noise_upper_e = std::numeric_limits<double>::quiet_NaN();  // 2-sd bound when
                                                                         // not significant
  double bias_adu = std::numeric_limits<double>::quiet_NaN();
  double bias_sd_adu = std::numeric_limits<double>::quiet_NaN();
  std::string bias_source = "unknown";
  double intercept_adu2 = 0.0;  // a of var = a + m / g
  double intercept_sd_adu2 = 0.0;
  double slope_per_adu = 0.0;  // 1 / g
  double slope_sd_per_adu = 0.0;
  double rounding_adu2 = 0.0;  // q: 1/12 for integer data, 0 for floating point
  double chi2 = 0.0;
  int dof = 0;
  double min_level_adu = 0.0;  // levels of the points used [ADU]
  double max_level_adu = 0.0;
  int points_used = 0;
  int pairs = 0;                 // frame pairs (pairs method)
  int frames_used = 0;           // frames whose pixels entered the points
  std::vector<PtcPoint> points;  // every bin, used or not, in level order
  std::vector<PtcFrameInfo> frames;
  std::vector<std::string> warnings;
};

// Estimates gain and read noise from `frames` (names label them in messages; empty: "frame
// N"). Returns false with a one-line reason when no estimate is possible: no frame, a wrong
// number of exposure times or scenes, a forced pairs method the input does not allow, frames
// with a single value (flat and noiseless, all zero), fewer than 3 usable level bins, a
// variance that is 0 everywhere, or one that does not grow significantly with the level.
bool EstimatePhotonTransfer(const std::vector<FitsImage>& frames,
                            const std::vector<std::string>& names,
                            const PhotonTransferOptions& options, PhotonTransferResult* result,
                            std::string* error);

// Reads each file with ReadFitsImage and calls the above.
bool EstimatePhotonTransferFromFiles(const std::vector<std::string>& paths,
                                     const PhotonTransferOptions& options,
                                     PhotonTransferResult* result, std::string* error);

// The result as JSON (gain.json) and the points as CSV (gain.csv: mean_adu, variance_adu2,
// variance_sd_adu2, pixels, used; one row per bin).
nlohmann::json PhotonTransferJson(const PhotonTransferResult& result);
std::string PhotonTransferCsv(const PhotonTransferResult& result);

}  // namespace ccdpsf

#endif  // CCDPSF_PHOTON_TRANSFER_H_
