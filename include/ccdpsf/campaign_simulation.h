// A whole characterisation campaign with a known truth: the settings of the paper's Table 1
// (wavelength, peak-pixel intensity, exposure time, number of exposures), optionally
// through-focus series, with the CCD kernel widths of every setting following given
// wavelength and intensity relations (default: the paper's, section 4). Each setting becomes
// one group of exposures written by RunSimulation (simulate.h) into its own folder, plus a
// manifest and the campaign's truth.
//
// Configuration (strict JSON: unknown keys, wrong types and out-of-domain values are
// one-line errors naming the key; defaults in brackets):
//
//   {"campaign": {
//      "seed": 11,                                           required, >= 0
//      "image": {"nx": 21, "ny": 21, "prescan_x": 0},        as in the simulation config
//                                                             [21, 21, 0]
//      "detector": {"gain_e_per_adu":, "read_noise_e":, "bias_adu":, "pixel_um":,
//                   "saturation_adu":},                       as in the simulation config
//                                                             [3.1, 4.5, 1000, 12, 65535]
//      "sampling": "integrated" | "pixel_centre",             ["integrated"]
//      "airy_radius_px_at_800nm": 0.47,                       r scales linearly with the
//                                                             wavelength (r = 1.22 lambda F# / p)
//                                                             [0.47]
//      "defocus": {"kind": "gaussian", "sigma_px": 0.41}      or {"kind": "pillbox", "radius_px":};
//                                                             the same for every setting
//                                                             [gaussian 0.41]
//      "position_jitter_px": 0.1,                             per exposure, uniform in (-j, j) on
//                                                             each axis around the centre pixel;
//                                                             0 <= j < 0.5 [0.1]
//      "truth": {...},                                        CampaignTruth below
//      "settings": [{"wavelength_nm":, "peak_e":, "exptime_s":, "exposures":,
//                    "focus_position_um": optional}, ...],   [Table 1 of the paper]
//      "focus_series": [{"wavelength_nm":, "peak_e":, "exptime_s":,
//                        "focus_positions_um": [...], "exposures_per_position": 1,
//                        "best_focus_um": 0.0, "defocus_sigma_px_per_um":}]   optional
//   }}
//
// Intensity. Each group's intensity parameter (flux_e in integrated sampling, the 2015 peak
// meta-parameter m in pixel_centre sampling; docs/conventions.md, Sampling) is chosen so that the
// noiseless model of a spot centred exactly on the centre pixel has its maximum pixel equal
// to the nominal peak_e. It is fixed within a group (a stable lab source): exposures differ
// only by their position jitter, so their own peak pixels differ slightly from peak_e. A
// focus series is calibrated at best focus (no defocus).
//
// Centre pixel: (prescan_x + int(nx/2 - 0.5), int(ny/2 - 0.5)) in frame coordinates, i.e.
// pixel (10, 10) of a 21 x 21 image, as in the 2015 code.
//
// Through-focus series: the exposure at stage position z [um] gets a Gaussian defocus
// sigma_f(z) = defocus_sigma_px_per_um |z - best_focus_um| (whatever the campaign's
// "defocus" kind; written per exposure through SimulatedExposure::defocus_px, and z as the
// FOCUSPOS keyword); its CCD widths are those of its (peak_e, wavelength). pixel_centre
// sampling cannot render sigma_f = 0 (the 2015 code's unit-peak Gaussian degenerates), so
// there sigma_f is floored at kPixelCentreMinDefocusPx; both the nominal and the rendered
// value are recorded in truth.json. Integrated sampling renders sigma_f = 0 exactly. A
// setting with "focus_position_um" is one exposure group at that stage position, with the
// defocus the first series at its wavelength gives there (CampaignSetting); truth.json
// records its position and defocus.
//
// Seeds: group k of the settings uses DeriveSeed(DeriveSeed(seed, 0), k), focus series k
// DeriveSeed(DeriveSeed(seed, 1), k); within a group, the noise uses
// DeriveSeed(group_seed, 0) as its simulation seed and the position jitter a std::mt19937_64
// seeded with DeriveSeed(group_seed, 1). Same configuration, same bytes.
//
// Output (everything staged, moved into place only when all of it succeeded; truth.json
// last):
//   DIR/<group>/exposure_NNN.fits (model_NNN.fits when noiseless), DIR/<group>/truth.json
//     groups "g00_600nm_7900e", ..., focus series "f00_800nm_100000e_focus", ...
//   DIR/manifest.json  {"groups": [{"name":, "wavelength_nm":, "nominal_peak_e":,
//                       "exptime_s":, "focus_series":, "files": ["<group>/exposure_000.fits",
//                       ...]}]}   (paths relative to the manifest's folder)
//   DIR/truth.json     the relations used (with the derived a_x, a_y and the implied
//                      geometric-mean law), and per group the CCD widths, the true metrics
//                      and the total (defocus-included) widths; the seed; software versions.
#ifndef CCDPSF_CAMPAIGN_SIMULATION_H_
#define CCDPSF_CAMPAIGN_SIMULATION_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/model/spot_model.h"
#include "ccdpsf/simulate.h"

namespace ccdpsf {

// pixel_centre sampling only: the smallest Gaussian defocus sigma rendered [px] (the
// library's smallest Gaussian width, model::kMinGaussianWidthPx). Used at best focus of a
// through-focus series, where the nominal sigma_f is 0. Note that the 2015 model's unit-peak
// defocus Gaussian, centred on the spot, attenuates the image by about
// exp(-d^2 / (2 sigma_f^2)) for a spot d px off the pixel centre, so at such small sigma_f
// the position jitter changes the image's brightness strongly: that is the 2015 model.
constexpr double kPixelCentreMinDefocusPx = model::kMinGaussianWidthPx;

// The linear intensity relation FWHM(I) = intercept_um + slope_um_per_e * I at the
// reference wavelength (paper section 4.3) [um, um / e-].
struct IntensityRelation {
  double intercept_um = 0.0;
  double slope_um_per_e = 0.0;
  double FwhmUm(double intensity_e) const { return intercept_um + slope_um_per_e * intensity_e; }
};

// The CCD kernel widths as a function of peak-pixel intensity I [e-] and wavelength lambda
// [nm], the paper's combined model (section 4.4):
//
//   FWHM_x(I, lambda) = FWHM_x(lambda) FWHM_x(I) / FWHM_x(I0),
//   FWHM_x(lambda)    = a_x lambda^alpha_x,   FWHM_x(I) = c_x + s_x I,        same for y,
//   sigma_x [px]      = FWHM_x / (2 sqrt(2 ln 2) pixel_um).
//
// a_x and a_y are not free: they are derived so that the two laws agree at the reference
// point, FWHM_x(lambda0) = c_x + s_x I0, i.e. a_x = (c_x + s_x I0) / lambda0^alpha_x (same
// for y). The geometric-mean FWHM at I0 then follows FWHM(lambda) = sqrt(a_x a_y)
// lambda^((alpha_x + alpha_y) / 2) exactly.
//
// Defaults: a consistent subset of the paper's fitted relations (its separately fitted x, y
// and geometric-mean laws do not agree with each other exactly): alpha_x = -0.237 (paper),
// alpha_y = -0.307 (chosen so that (alpha_x + alpha_y) / 2 = -0.272, the paper's headline
// geometric-mean exponent; the paper's own fit gives -0.378), and the paper's 800 nm
// intensity relations c_x = 6.66 um, s_x = 1.14e-5 um/e-, c_y = 6.72 um, s_y = 1.12e-5 um/e-,
// with I0 = 157800 e- and lambda0 = 800 nm.
//
// JSON: {"reference_intensity_e":, "reference_wavelength_nm":, "alpha_x":, "alpha_y":,
//        "intensity_x": {"intercept_um":, "slope_um_per_e":}, "intensity_y": {...}}, every key
//        optional.
struct CampaignTruth {
  double reference_intensity_e = 157800.0;   // I0 [e-]
  double reference_wavelength_nm = 800.0;    // lambda0 [nm]
  double alpha_x = -0.237;
  double alpha_y = -0.307;
  IntensityRelation intensity_x{6.66, 1.14e-5};
  IntensityRelation intensity_y{6.72, 1.12e-5};

  // The derived wavelength-law amplitudes [um nm^-alpha].
  double AX() const;
  double AY() const;
  // The implied geometric-mean law FWHM(lambda) = GeometricA() lambda^GeometricAlpha() at I0.
  double GeometricA() const;
  double GeometricAlpha() const;

  // FWHM_x(I, lambda), FWHM_y(I, lambda) [um].
  double FwhmXUm(double intensity_e, double wavelength_nm) const;
  double FwhmYUm(double intensity_e, double wavelength_nm) const;

  // False with a reason unless I0, lambda0 > 0 and c + s I0 > 0 on both axes.
  bool IsValid(std::string* error) const;
};

// One (wavelength, intensity) setting: `exposures` exposures at one focus, with the
// campaign's defocus; or, with focus_position_um, at that stage position (FOCUSPOS written)
// with the Gaussian defocus that the first focus series at the same wavelength (within
// 0.5 nm) gives there, rate |z - z0| (required: such a series; the defocus of a
// pixel_centre campaign is floored as a series' is). A single-focus setting anchored by a
// series (trend/defocus_anchor.h) is made this way.
struct CampaignSetting {
  double wavelength_nm = 0.0;
  double peak_e = 0.0;       // nominal peak-pixel electrons: the I of the truth relations
  double exptime_s = 0.0;
  int exposures = 0;
  std::optional<double> focus_position_um;  // stage position z [um]
};

// A through-focus series at one (wavelength, intensity).
struct FocusSeries {
  double wavelength_nm = 0.0;
  double peak_e = 0.0;
  double exptime_s = 0.0;
  std::vector<double> focus_positions_um;  // stage positions z [um], in exposure order
  int exposures_per_position = 1;
  double best_focus_um = 0.0;              // z0 [um]
  double defocus_sigma_px_per_um = 0.0;    // d sigma_f / d|z - z0| [px / um]

  // The nominal Gaussian defocus at stage position z: rate |z - z0| [px].
  double DefocusSigmaPx(double focus_position_um) const;
};

struct CampaignConfig {
  uint64_t seed = 0;
  int nx = 21;
  int ny = 21;
  int prescan_x = 0;
  double gain_e_per_adu = 3.1;
  double read_noise_e = 4.5;
  double bias_adu = 1000.0;
  double pixel_um = 12.0;
  double saturation_adu = 65535.0;
  model::Sampling sampling = model::Sampling::kIntegrated;
  double airy_radius_px_at_800nm = 0.47;
  model::DefocusKind defocus_kind = model::DefocusKind::kGaussian;
  double defocus_px = 0.41;                 // Gaussian sigma or pillbox radius [px]
  double position_jitter_px = 0.1;
  CampaignTruth truth;
  std::vector<CampaignSetting> settings;    // Table1Settings() when the JSON has none
  std::vector<FocusSeries> focus_series;

  // Airy first-dark-ring radius at a wavelength [px]: airy_radius_px_at_800nm lambda / 800.
  double AiryRadiusPx(double wavelength_nm) const;
  // The first focus series within 0.5 nm of `wavelength_nm` (its defocus law), or null.
  const FocusSeries* FocusLawFor(double wavelength_nm) const;
  // The centre pixel, frame coordinates (see the file comment).
  double CentreXPx() const;
  double CentreYPx() const;
};

// The 13 settings (87 exposures) of the paper's Table 1.
std::vector<CampaignSetting> Table1Settings();

// True when `json_text` is a JSON object with a top-level key "campaign" (how `ccdpsf
// simulate` tells a campaign from a single simulation). False for anything else, including
// malformed JSON.
bool IsCampaignConfig(const std::string& json_text);

// Parses and validates a campaign configuration, including that every exposure it implies
// is inside the model's domain. Returns nullopt with a one-line reason otherwise.
std::optional<CampaignConfig> ParseCampaignConfig(const std::string& json_text,
                                                  std::string* error);
std::optional<CampaignConfig> LoadCampaignConfig(const std::string& path, std::string* error);

// One group of exposures of a campaign, ready to simulate.
struct CampaignGroup {
  std::string name;                // e.g. "g00_600nm_7900e", "f00_800nm_100000e_focus"
  bool focus_series = false;
  int source_index = 0;            // index into CampaignConfig::settings or ::focus_series
  double wavelength_nm = 0.0;
  double nominal_peak_e = 0.0;
  double exptime_s = 0.0;
  double ccd_sigma_x_px = 0.0;     // from the truth relations at (nominal_peak_e, wavelength)
  double ccd_sigma_y_px = 0.0;
  // flux_e (integrated) or m (pixel_centre): the same for every exposure of the group.
  double intensity_parameter_e = 0.0;
  // Nominal defocus per exposure (focus series: rate |z - z0|, before any floor; otherwise the
  // campaign's defocus) [px].
  std::vector<double> nominal_defocus_px;
  SimulationConfig simulation;     // seed, model and exposures of this group
};

// The groups of a campaign: settings first (g00, g01, ...), then focus series (f00, ...).
// Deterministic. `config` must come from ParseCampaignConfig (CHECKs otherwise).
std::vector<CampaignGroup> PlanCampaign(const CampaignConfig& config);

struct CampaignResult {
  int groups = 0;
  int exposures = 0;
  std::string manifest_path;
  std::string truth_path;
};

// Simulates every group into out_dir (see the file comment for the layout); with `noiseless`
// each group holds model_NNN.fits. On failure returns false with a one-line reason and
// leaves nothing of this run behind.
bool RunCampaign(const CampaignConfig& config, const std::string& out_dir, bool noiseless,
                 CampaignResult* result, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_CAMPAIGN_SIMULATION_H_
