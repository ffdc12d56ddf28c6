// The known true values of simulated data, for drawing on plots.
//
// Two truth.json layouts exist:
//   `ccdpsf simulate` (simulate.cc): "parameters" {airy_radius_px, defocus_sigma_px or
//       defocus_radius_px, ccd_sigma_x_px, ccd_sigma_y_px}, "exposures" [{file, x_px, y_px,
//       flux_e or peak_e, ...}], "effects" when any were injected;
//   a campaign simulation (campaign_simulation.h): "relations" {<metric>_vs_wavelength: {a,
//       alpha}, <metric>_vs_intensity: {intercept, slope}, reference_intensity_e,
//       reference_wavelength_nm}, "groups" [{name, wavelength_nm, nominal_peak_e, <metrics>,
//       focus_series, ...}]; each group's folder holds a truth.json of the first layout.
// Only what maps unambiguously onto a fitted quantity is used (see FitParameterTruths).
#ifndef CCDPSF_TRUTH_H_
#define CCDPSF_TRUTH_H_

#include <optional>
#include <string>
#include <vector>

#include "nlohmann/json.hpp"

namespace ccdpsf {

struct TruthFile {
  std::string path;  // as found or given
  nlohmann::json document;
};

// The truth for a run on `inputs` (files or folders): the file `given` (--truth) when not
// empty, else truth.json in the one folder that holds every input (a folder input counts as
// that folder; a file input as its parent folder); none when the inputs lie in several
// folders or there is no truth.json. False, with a one-line reason, only when a truth file
// (given or found) cannot be read or is not a JSON object.
bool FindTruth(const std::string& given, const std::vector<std::string>& inputs,
               std::optional<TruthFile>* truth, std::string* error);

// True values of a fit's parameters `names` (fit_model.h: flux_e or peak_e, airy_radius_px,
// the defocus, ccd_sigma_x_px, ccd_sigma_y_px, x_px_K, y_px_K, flux_ratio_K, ...), NaN where
// the truth does not say. `sources` are the fitted exposures' files in fit order; an
// exposure is matched to the truth's exposure whose "file" has the same base name. Mapped:
//   - a shared parameter present by the same name in "parameters"; the CCD widths and the
//     defocus only when no effects were injected (they change the kernel the fit sees);
//   - x_px_K, y_px_K: matched exposure K's x_px, y_px;
//   - flux_e / peak_e: matched exposure 0's value, and when `flux_shared` only if every
//     matched exposure has the same value (else there is no single true flux);
//   - flux_ratio_K: matched exposure K's value over exposure 0's.
// A campaign-level truth (no "parameters") maps nothing.
std::vector<double> FitParameterTruths(const nlohmann::json& truth,
                                       const std::vector<std::string>& names,
                                       const std::vector<std::string>& sources, bool flux_shared);

}  // namespace ccdpsf

#endif  // CCDPSF_TRUTH_H_
