// A characterisation campaign: exposures grouped into settings (one wavelength, one
// intensity), each group to be fitted jointly.
//
// Ways in:
//   manifest  a manifest (manifest.h: CSV or JSON, or a folder holding manifest.json, or
//             --manifest with or without files), e.g. the campaign form `ccdpsf simulate`
//             writes. Files with a `setting` form that setting's group; the others are
//             grouped as folders' files are;
//   a campaign folder laid out as one subfolder per setting: each subfolder holding FITS
//             files is a group, named after it (files directly in the folder are grouped by
//             their metadata);
//   files and folders (not recursive) grouped by their metadata: wavelength, then exposure
//             time (with a stable lamp the peak intensity at one wavelength follows the
//             exposure time).
// Each file's metadata comes from metadata.h's sources (flags, its manifest row, FIT.json,
// its header through the keyword map). A group whose files carry three or more distinct
// focus positions is a through-focus series. A file that cannot be placed (unreadable, no
// wavelength) becomes a failed group of its own with the reason, so the run can go on with
// the rest and the report can show the gap; so does a group whose files are at different
// wavelengths.
#ifndef CCDPSF_TREND_CAMPAIGN_H_
#define CCDPSF_TREND_CAMPAIGN_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/manifest.h"

namespace ccdpsf::trend {

struct CampaignGroup {
  std::string name;
  double wavelength_nm = 0.0;          // NaN when unknown (then problem is set)
  std::optional<double> nominal_peak_e;  // from a manifest; informational
  std::optional<double> exptime_s;
  bool focus_series = false;
  std::vector<std::string> files;
  std::vector<InputFile> inputs;  // the same files with each one's options
  // Set when the group cannot be fitted at all (e.g. a file without WAVELEN): why.
  std::string problem;
};

// Reads the campaign from the command's inputs: one manifest (file or folder containing
// manifest.json), or any number of FITS files and folders. False, with a one-line reason,
// only when nothing usable was given (no inputs, a malformed manifest, no FITS file found).
struct CampaignOptions {
  GivenMetadata flags;         // values given on the command line, for every file
  CalibrationOptions config;   // FIT.json's calibration and keyword map
  std::string manifest;        // --manifest (may be empty)
};

bool LoadCampaign(const std::vector<std::string>& inputs, const CampaignOptions& options,
                  std::vector<CampaignGroup>* groups, std::string* error);
// With default options (headers only).
bool LoadCampaign(const std::vector<std::string>& inputs, std::vector<CampaignGroup>* groups,
                  std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_CAMPAIGN_H_
