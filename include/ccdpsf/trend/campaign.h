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

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/manifest.h"

namespace ccdpsf::trend {

// The defocus of a single-focus setting as a through-focus series measured it
// (defocus_anchor.h): the box prior its fit takes instead of the flat one.
struct DefocusAnchor {
  std::string series;  // the anchoring series' group name
  double series_wavelength_nm = NAN;
  double focus_position_um = NAN;  // the setting's stage position z [um]
  // Percentiles 0.135 / 50 / 99.865 of rate |z - z0| over the series' draws [px]; the box is
  // [lower_px, upper_px] (already intersected with the configured defocus prior).
  double lower_px = NAN, median_px = NAN, upper_px = NAN;
};

struct CampaignGroup {
  std::string name;
  double wavelength_nm = 0.0;          // NaN when unknown (then problem is set)
  std::optional<double> nominal_peak_e;  // from a manifest; informational
  std::optional<double> exptime_s;
  bool focus_series = false;
  // The distinct stage positions of its files (FOCUSPOS) [um], ascending; empty unless every
  // file carries one.
  std::vector<double> focus_positions_um;
  // Set before the fit when a through-focus series anchors this setting's defocus.
  std::optional<DefocusAnchor> defocus_anchor;
  std::vector<std::string> files;
  std::vector<InputFile> inputs;  // the same files with each one's options
  // An intensity series (intensity_series.h): the single-focus settings of one wavelength
  // fitted jointly with the brighter-fatter slope; member_settings names the setting of each
  // file (parallel to files).
  bool intensity_series = false;
  std::vector<std::string> member_settings;
  std::vector<std::string> member_focus_series;  // the members that are through-focus series
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
