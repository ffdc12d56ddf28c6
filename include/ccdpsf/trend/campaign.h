// A characterisation campaign: exposures grouped into settings (one wavelength, one
// intensity), each group to be fitted jointly.
//
// Two ways in:
//   manifest  a JSON file (or a folder holding manifest.json), as `ccdpsf simulate` writes
//             for campaigns:
//               {"groups": [{"name": "g00_600nm_7900e", "wavelength_nm": 600,
//                            "nominal_peak_e": 7900, "exptime_s": 0.1, "focus_series": false,
//                            "files": ["g00_600nm_7900e/exposure_000.fits", ...]}, ...]}
//             (file paths relative to the manifest's folder; name, wavelength_nm and files
//             required, the rest optional; unknown keys are errors);
//   folders   FITS files (or folders of them, not recursive) grouped by their headers:
//             WAVELEN, then EXPTIME (with a stable lamp the peak intensity at one wavelength
//             follows the exposure time). A group whose files carry three or more distinct
//             FOCUSPOS values is a through-focus series.
// A file that cannot be placed (unreadable, no WAVELEN) becomes a failed group of its own
// with the reason, so the run can go on with the rest and the report can show the gap.
#ifndef CCDPSF_TREND_CAMPAIGN_H_
#define CCDPSF_TREND_CAMPAIGN_H_

#include <optional>
#include <string>
#include <vector>

namespace ccdpsf::trend {

struct CampaignGroup {
  std::string name;
  double wavelength_nm = 0.0;          // NaN when unknown (then problem is set)
  std::optional<double> nominal_peak_e;  // from a manifest; informational
  std::optional<double> exptime_s;
  bool focus_series = false;
  std::vector<std::string> files;
  // Set when the group cannot be fitted at all (e.g. a file without WAVELEN): why.
  std::string problem;
};

// Reads the campaign from the command's inputs: one manifest (file or folder containing
// manifest.json), or any number of FITS files and folders. False, with a one-line reason,
// only when nothing usable was given (no inputs, a malformed manifest, no FITS file found).
bool LoadCampaign(const std::vector<std::string>& inputs, std::vector<CampaignGroup>* groups,
                  std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_CAMPAIGN_H_
