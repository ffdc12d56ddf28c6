// FIT.json: the fit's options as a file (command-line flags override it).
//
//   {"sampling": "integrated", "defocus": "gaussian", "pixel_response_width": 1.0,
//    "likelihood": "gaussian",
//    "joint": false, "through_focus": false, "flux": "auto",
//    "effects": {"serial_cti": {"trail_fraction": [0, 0.01], "trail_length_px": [0.2, 10]},
//                "brighter_fatter": {}},
//    "priors": {"airy_radius_px": [0.1, 1.5], "defocus_px": [0.0, 1.5],
//               "ccd_sigma_x_px": [0.05, 1.5], "ccd_sigma_y_px": [0.05, 1.5],
//               "position_halfwidth_px": 2.0, "flux_fraction": [0.2, 5.0]},
//    "map":  {"start_airy_radii_px": [0.35, 0.6, 0.9], "start_defocus_shares": [0.25, 0.75],
//             "max_iterations": 1000, "start_ccd_variance_scales": [1.0, 0.5],
//             "start_best_focus_fractions": [0.2, 0.5, 0.8]},
//    "mcmc": {"enabled": true, "walkers": 0, "max_steps": 20000, "target_ess": 1000,
//             "min_tau_multiple": 50, "seed": 1, "threads": 2, "marginal_defocus": true,
//             "positions_by_conditional": true, "position_update_every": 2},
//    "calibration": {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000,
//                    "saturation_adu": 65535, "pixel_um": 12, "stamp_size": 21},
//    "keywords": {"gain_e_per_adu": "EGAIN", "exptime_s": {"keyword": "EXPMS", "scale": 1e-3}},
//    "flags": {"pixel_um": 12, "outliers": true}}
//
// "calibration" takes stamp_size and any quantity of metadata.h (values for every file, of
// lower precedence than a flag or a manifest row); "keywords" is the keyword map (metadata.h).
//
// "flags" holds command-line options of the command the file is given to that the keys above
// do not (the metadata flags, --outliers, trend's --reference_intensity_e, diagnose's
// --max_rounds, ...), by flag name, each as if given on the command line, where a flag given
// outranks it; trend's "requirements" is the list itself (trend/requirements.h). The library
// keeps it as read (FitConfig::flags); the ccdpsf tool checks and applies it. Every run of
// `ccdpsf fit`, `trend` and `diagnose` writes config.json in this format: every option it
// resolved, so that `--config=OUT/config.json` with the same inputs repeats the run.
//
// "effects" names the catalogue's effects fitted with the spot (fit_model.h, Effects), each
// with optional flat prior ranges by parameter name (absent: the catalogue's, `ccdpsf
// effects`); defocus_offset cannot be fitted (IsFittableEffect says why); jitter is fitted per
// exposure in a joint fit (fit_model.h).
//
// "pixel_response_width" (integrated sampling only) is the width [px] of each pixel's
// collecting window (model::ModelOptions::pixel_response_width), held fixed: 1, the whole
// pixel, is the paper's model; `ccdpsf diagnose` writes its measured value when it names a
// narrower pixel response.
//
// Every key is optional; unknown keys are errors. "through_focus" fits a joint set as a
// through-focus series (fit_model.h); `ccdpsf fit --joint` switches it on by itself when it
// is not given and the files form one (FOCUSPOS on all, >= 3 distinct values).
#ifndef CCDPSF_FIT_FIT_CONFIG_H_
#define CCDPSF_FIT_FIT_CONFIG_H_

#include <string>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::fit {

struct FitConfig {
  FitModelOptions model;
  FitOptions fit;
  CalibrationOptions calibration;
  bool joint = false;
  // model.through_focus was set explicitly (FIT.json or a flag): no automatic choice.
  bool through_focus_given = false;
  // model.flux was set explicitly ("flux" in FIT.json, --flux): no choice from the data.
  bool flux_given = false;
  // "flags": command-line options by name (a JSON object; empty when absent), unchecked here.
  nlohmann::json flags = nlohmann::json::object();
};

// Overlays the JSON onto *config (keys absent keep their current values). False with a
// one-line reason on malformed JSON, unknown keys, wrong types or out-of-range values.
bool ParseFitConfig(const std::string& json_text, FitConfig* config, std::string* error);
bool LoadFitConfig(const std::string& path, FitConfig* config, std::string* error);

// The ranges of the MCMC's settings, whether they come from FIT.json or from flags:
// walkers 0 (automatic) to kMaxWalkers, max_steps 1 to kMaxSteps, threads 1 to kMaxThreads,
// target_ess 0 to kMaxSteps. (The chain's memory, walkers x steps x parameters, is checked
// by the sampler, which knows the parameters.) False with a one-line reason naming the
// setting as `prefix` + name ("--walkers", "mcmc.walkers").
constexpr long long kMaxWalkers = 100000;
constexpr long long kMaxSteps = 100000000;
constexpr long long kMaxThreads = 1024;
bool CheckMcmcSettings(long long walkers, long long max_steps, long long threads,
                       double target_ess, const std::string& prefix, std::string* error);

// FIT.json's "effects" object, and `--effects=a,b` (catalogue priors; "" or "none": no
// effects). False with a one-line reason on unknown or unfittable effects, unknown
// parameters, ranges outside a parameter's domain or repeated names.
bool ParseFitEffects(const nlohmann::json& effects, std::vector<FitEffect>* out,
                     std::string* error);
bool ParseFitEffectList(const std::string& text, std::vector<FitEffect>* out, std::string* error);
// The effects as FIT.json holds them, every prior range written out.
nlohmann::json FitEffectsJson(const std::vector<FitEffect>& effects);

// The resolved configuration as JSON (for run.json; FIT.json reads it back).
nlohmann::json FitConfigJson(const FitConfig& config);
// The "calibration" object: the quantities given, and stamp_size.
nlohmann::json CalibrationJson(const CalibrationOptions& options);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_CONFIG_H_
