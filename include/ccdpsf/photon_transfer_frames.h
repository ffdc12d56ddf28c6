// The frames of a photon-transfer set, as `ccdpsf gain` (photon_transfer.h) and `ccdpsf ptc`
// (ptc.h) both read them: each frame's exposure time, data region and the levels its ADC
// cannot record faithfully (a clipped black level, the top); pairs of frames taken under one
// illumination; and the bias level.
//
//   exposure time  the option's value for the frame when given (a flag or a manifest row),
//                  else the EXPTIME keyword; frames without one are never paired. Frames of
//                  exposure time 0 are bias frames.
//   data region    DATASEC when the header has a valid one, else the whole frame.
//   floor          a black level clipped by the ADC: the frame's minimum value holds >= 1 %
//                  of its pixels and >= 10 of them; pixels at it (and any at the ADC's bottom)
//                  are "at the floor".
//   ceiling        min(the ADC's maximum, the saturation level: the option, else SATURATE);
//                  pixels at or above it are "at the top".
//   rounding       q = step^2 / 12 [ADU^2], the variance the ADC's rounding adds to a pixel
//                  (step = the range over the 2^BITPIX - 1 steps; 0 for floating point).
//   pairs          two frames under the same illumination: the same exposure time (relative
//                  tolerance 1e-6), the same scene (e.g. a manifest's setting), WAVELEN and
//                  FOCUSPOS equal where both headers have them, and the same size; taken two
//                  by two in input order.
//   bias           the option's value, else BIASLVL (when every frame has it: their mean),
//                  else the mean of the bias sections (BIASSEC, every frame), else the mean of
//                  the zero-second frames; a section or frame sitting on a clipped black level
//                  is refused (its mean is not the bias). Else unknown.
#ifndef CCDPSF_PHOTON_TRANSFER_FRAMES_H_
#define CCDPSF_PHOTON_TRANSFER_FRAMES_H_

#include <cstddef>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/spot_finder.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

// A sample touching the floor is trusted in a statistic only when at most this fraction of
// its samples do: a normal distribution cut 3.1 sd from its mean (0.1 % beyond) loses about
// 1 % of its variance, and censoring at the cut (what the floor does) loses less.
inline constexpr double kTransferMaxFloorFraction = 1e-3;
// Outliers (cosmic rays, a pixel that changed between two frames) are clipped at this many
// sd; a normal sample loses 6e-7 of its points and a negligible 1e-5 of its variance.
inline constexpr double kTransferOutlierClipSigma = 5.0;
// A level is trusted when less than 0.1 % of its pixels' noise distribution reaches the top:
// level + this many sd below the ceiling.
inline constexpr double kTransferTailSd = 3.1;
// Levels above this fraction of the ADC's range are left out: many ADCs and output
// amplifiers compress there before they clip.
inline constexpr double kTransferFullScaleFraction = 0.9;

// What is known of the frames beyond their headers.
struct TransferFrameOptions {
  // One entry per frame [s] (NaN: not given, then the frame's EXPTIME keyword), or empty:
  // every frame's EXPTIME.
  std::vector<double> exptime_s;
  std::vector<std::string> exptime_sources;  // optional, parallel to exptime_s ("manifest ...")
  // Optional, one per frame: frames pair only within the same scene.
  std::vector<std::string> scene;
  // The bias level [ADU] when known from elsewhere; NaN: the header's, as above.
  double bias_adu = std::numeric_limits<double>::quiet_NaN();
  std::string bias_source = "option";
  // Saturation [ADU]; NaN: the SATURATE keyword, else only the ADC's maximum.
  double saturation_adu = std::numeric_limits<double>::quiet_NaN();

  // False with a one-line reason for a non-finite bias or saturation, a negative or infinite
  // exposure time, or lists that are not parallel.
  bool IsValid(std::string* error) const;
};

// What was learnt about one input frame (reported per frame by both commands).
struct PtcFrameInfo {
  std::string name;
  double exptime_s = std::numeric_limits<double>::quiet_NaN();
  std::string exptime_source = "unknown";
  double floor_adu = -std::numeric_limits<double>::infinity();  // clipped black level
  bool floor_clipped = false;
  double floor_pixel_fraction = 0.0;  // pixels at the frame's minimum
  double ceiling_adu = std::numeric_limits<double>::infinity();
  std::string ceiling_source = "none";
  std::string role;  // "pair 1 (with X)", "single frame", "not used: ..."
};

// A frame ready for sampling: its pixels, region and ADC limits.
struct TransferFrame {
  const FitsImage* image = nullptr;
  PixelRegion region;
  double floor = -std::numeric_limits<double>::infinity();   // at or below: at the floor
  double ceiling = std::numeric_limits<double>::infinity();  // at or above: at the top
};

// The prepared set, parallel to the input frames.
struct TransferFrameSet {
  std::vector<std::string> names;  // given, or "frame N"
  std::vector<TransferFrame> frames;
  std::vector<double> exptimes;  // [s], NaN when unknown
  std::vector<PtcFrameInfo> info;
  double rounding_adu2 = 0.0;  // the largest q of the frames
};

// Reads each file with ReadFitsImage, in order. False with its one-line reason.
bool ReadTransferFrames(const std::vector<std::string>& paths, std::vector<FitsImage>* frames,
                        std::string* error);

// Prepares `frames` (names label them in messages; empty: "frame N"). The set keeps pointers
// to `frames`, which must outlive it. False with a one-line reason for options that are not
// valid or not one per frame, or an empty image. Warnings (an invalid DATASEC) are appended.
bool PrepareTransferFrames(const std::vector<FitsImage>& frames,
                           const std::vector<std::string>& names,
                           const TransferFrameOptions& options, TransferFrameSet* set,
                           std::vector<std::string>* warnings, std::string* error);

// The pairs of frames under one illumination (indices into the set), by the rule above. Says
// once in `warnings` why frames sharing an exposure time were not paired, when some frame is
// left without a partner.
std::vector<std::pair<size_t, size_t>> FindIlluminationPairs(const TransferFrameSet& set,
                                                             const TransferFrameOptions& options,
                                                             std::vector<std::string>* warnings);

// Records each frame's role ("pair N (with X)", or why it is not used) in set->info, and
// warns of the frames without a partner. Returns the number of frames in pairs.
int DescribePairs(const std::vector<std::pair<size_t, size_t>>& pairs, TransferFrameSet* set,
                  std::vector<std::string>* warnings);

// The frames' records as the result files list them: per frame `file`, `exptime_s`,
// `exptime_source`, `black_level_clipped`, `floor_adu`, `pixels_at_minimum_fraction`,
// `ceiling_adu`, `ceiling_source`, `role`.
nlohmann::json TransferFramesJson(const std::vector<PtcFrameInfo>& frames);

struct BiasEstimate {
  double value = std::numeric_limits<double>::quiet_NaN();
  double sd = std::numeric_limits<double>::quiet_NaN();
  std::string source = "unknown";
};

// The bias level by the precedence above; unknown (NaN) when nothing gives it. Warnings say
// why a bias section or zero-second frames were refused.
BiasEstimate ResolveTransferBias(const TransferFrameSet& set, const TransferFrameOptions& options,
                                 std::vector<std::string>* warnings);

}  // namespace ccdpsf

#endif  // CCDPSF_PHOTON_TRANSFER_FRAMES_H_
