// The exposures of one run, read and calibrated together, with the checks only a set can
// make: the same exposure given twice, a missing pixel size, mixed wavelengths, and a peak
// that stops growing with the signal (compression before the saturation level).
//
// Compression: on a linear detector the fraction of a spot's light in its peak pixel does
// not depend on the exposure's signal. Across a set whose signals span at least a factor
// 1.5, the fraction f = peak / (5 x 5 box) [both e-, bias-subtracted; the peak scaled to a
// spot centred on its pixel, from a parabola through the logarithms of it and its
// neighbours] of the faintest third (at least two exposures) is the reference; an exposure at
// least 1.3 times brighter than all of them whose fraction falls short of the reference's
// median by more than 3 % (the centring correction leaves 2 % on photon-shot spots) and by
// more than 3 sd of the counting noise of the two fractions (binomial, in electrons) is
// flagged "compressed_peak" (suspect). A core that broadens with the signal (brighter-fatter)
// lowers the fraction too; the finding names both readings and says by how much and, where
// the intensity was varied by exposure time, how far the peak falls below the line through
// the reference peaks. Only exposures at one focus position (FOCUSPOS) are compared: a
// through-focus series changes the fraction by its defocus. When the fit's model holds an
// effect that explains the finding (brighter_fatter or nonlinearity), it is a note saying so.
#ifndef CCDPSF_EXPOSURE_SET_H_
#define CCDPSF_EXPOSURE_SET_H_

#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/quality.h"

namespace ccdpsf {

struct ExposureSetOptions {
  // Every exposure needs a pixel size (the metrics are in um): false only for callers that
  // report in pixels.
  bool require_pixel_size = true;
  // Exposures at wavelengths more than 1 nm apart are refused unless this is set (they do
  // not share one PSF).
  bool allow_mixed_wavelengths = false;
  // Not empty: the fit models a core that changes with the signal, and the compression
  // finding is a note ending with this text (e.g. "the model fits brighter_fatter").
  std::string compression_modelled;
};

struct ExposureSet {
  std::vector<Exposure> exposures;
  std::vector<std::string> settings;  // the manifest's setting of each, if any
  // Per-exposure findings of the set checks (exposure index set), to be merged with each
  // exposure's calibration findings.
  Quality quality;
};

// `path` made absolute with links resolved where they exist (to tell one file under two
// names); as given when that fails.
std::string CanonicalPath(const std::string& path);

// The one-line refusal of an exposure counted twice: `path` names the same file and HDU as
// `earlier` (`same_file`), or holds identical pixels. fit and grid refuse both alike.
std::string CountedTwice(const std::string& path, const std::string& earlier, bool same_file);

// Loads every input (LoadExposure) and runs the checks. False with a one-line reason when a
// file cannot be calibrated, a file is given twice (the same path and HDU, or identical
// pixels), a pixel size is missing, or wavelengths are mixed without leave.
bool LoadExposureSet(const std::vector<InputFile>& inputs, const ExposureSetOptions& options,
                     ExposureSet* set, std::string* error);

// The compression check above on calibrated exposures; findings go to *quality with the
// exposure's index; `modelled` as ExposureSetOptions::compression_modelled.
void CheckPeakCompression(const std::vector<Exposure>& exposures, Quality* quality,
                          const std::string& modelled = "");

}  // namespace ccdpsf

#endif  // CCDPSF_EXPOSURE_SET_H_
