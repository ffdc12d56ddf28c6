// The paper's 9-step simulator of spot-projection exposures (section 3.3):
//   1-4  render the expected electrons per pixel (Airy, defocus, CCD kernel, pixel grid);
//   5    Poisson noise;  6 bias;  7 Gaussian read noise;  8 gain (e- -> ADU);
//   9    round to whole ADU, clip to [0, min(65535, saturation)], store as 16-bit FITS.
//
// Injected effects ("effects", by catalogue name; model/effects.h has the catalogue, the
// parameters with units and their semantics) enter in this order:
//   render the spot with the kernel effects (brighter_fatter, jitter, defocus_offset)
//   -> halo -> nonlinearity -> ipc -> serial_cti -> parallel_cti      (expected electrons)
//   -> Poisson (step 5) -> background pedestal -> bias, read noise, gain, rounding (6-9).
// The charge effects act on the expected image, before the Poisson step, which keeps the mean
// exact (their correlation of the shot noise between neighbouring pixels is neglected). The
// image effects and the pedestal act on the image area only (not on prescan columns); in
// pixel_centre sampling they act on the whole image area around the stamp, so a halo or a
// trail may extend beyond it, and the halo holds a fraction of the stamp's summed electrons.
// Each jitter value is one number for every exposure or a list with one per exposure. The
// brighter-fatter signal of an exposure is the peak pixel of its spot rendered with the other
// kernel effects (model::BrighterFatterSignal, on the image area or the pixel_centre stamp).
// "defocus" is the model's own component ("model.defocus") and cannot be injected;
// "defocus_offset" in pixel_centre sampling centres the 2015 F kernel away from the Airy
// (model/effects.h). "effects": {} is the same as no "effects".
//
// The configuration is in docs/formats.md (Simulation config). Extensions beyond it:
//   "image": {"prescan_x": N}   N bias-only columns at the left of the frame (written as
//                               BIASSEC) so readers can be tested on realistic frames; spot
//                               positions are in frame coordinates, prescan included.
//   "model": {"stamp_size": n}  pixel_centre sampling only: the 2015 model lives on an n x n
//                               stamp (default 21, or the frame if smaller) whose centre pixel
//                               is the pixel nearest the spot; outside it the frame holds no
//                               signal.
//   "omit_keywords": [..]       header keywords not to write (e.g. "BIASLVL", "RDNOISE") so
//                               the reader's estimators can be exercised.
//   per exposure: "wavelength_nm", "exptime_s", "focus_position_um" override the top level,
//                 and "defocus_px" (Gaussian sigma or pillbox radius) overrides the model's
//                 defocus, for through-focus series.
// Unknown keys are errors, so a typo never silently falls back to a default.
#ifndef CCDPSF_SIMULATE_H_
#define CCDPSF_SIMULATE_H_

#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/image.h"
#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/spot_model.h"

namespace ccdpsf {

// The largest spot intensity (flux_e or peak_e) a simulation takes [e-]: a million times a
// CCD pixel's full well, far beyond any lab exposure; above it the electron counts leave the
// range the photon-noise draw is exact in, and the exposure would silently come out empty.
constexpr double kMaxSimulatedIntensityE = 1e12;

struct SimulatedExposure {
  // Total electrons of the continuous image (integrated sampling) or the peak meta-parameter
  // m [e-] (pixel_centre sampling; given as "peak_e" in the JSON).
  double flux_e = 0.0;
  double x_px = 0.0;  // spot centre, frame coordinates
  double y_px = 0.0;
  double wavelength_nm = 0.0;
  double exptime_s = 0.0;
  std::optional<double> focus_position_um;
  std::optional<double> defocus_px;  // overrides SimulationConfig::defocus_px
  // Overrides SimulationConfig::effects.jitter (set when the config gives jitter per exposure).
  std::optional<model::JitterParams> jitter;
};

struct SimulationConfig {
  uint64_t seed = 0;
  int nx = 21;         // image area [px], excluding prescan
  int ny = 21;
  int prescan_x = 0;   // bias-only columns left of the image area
  double gain_e_per_adu = 3.1;
  double read_noise_e = 4.5;
  double bias_adu = 1000.0;
  double pixel_um = 12.0;
  double saturation_adu = 65535.0;
  model::ModelOptions model;
  double airy_radius_px = 0.47;
  double defocus_px = 0.41;  // Gaussian sigma or pillbox radius
  double ccd_sigma_x_px = 0.291;
  double ccd_sigma_y_px = 0.335;
  int stamp_size = 21;       // pixel_centre only
  std::vector<std::string> omit_keywords;
  // Injected effects shared by every exposure (jitter may be overridden per exposure).
  model::ExposureEffects effects;
  std::vector<SimulatedExposure> exposures;

  int FrameNx() const { return nx + prescan_x; }
  model::SpotParams Params(const SimulatedExposure& exposure) const;
  // The effects injected into one exposure: `effects` with the exposure's jitter override.
  model::ExposureEffects EffectsFor(const SimulatedExposure& exposure) const;
};

// Parses and validates a configuration. Returns nullopt with a one-line reason on malformed
// JSON, unknown keys, wrong types or values outside their domain.
std::optional<SimulationConfig> ParseSimulationConfig(const std::string& json_text,
                                                      std::string* error);
std::optional<SimulationConfig> LoadSimulationConfig(const std::string& path,
                                                     std::string* error);

// Steps 1-4 with the injected effects: the expected electrons per pixel of one exposure over
// the whole frame (prescan columns are zero), background pedestal included: what --noiseless
// writes. `details` (may be null) receives what the kernel effects did, centres in frame
// coordinates.
Image ExpectedElectrons(const SimulationConfig& config, const SimulatedExposure& exposure,
                        model::KernelEffectDetails* details = nullptr);

// Steps 5-9 applied to an image of expected electrons as ExpectedElectrons returns it: the
// stored ADU values (whole numbers). The background pedestal (config.effects.background),
// which carries no shot noise, is taken out of the image area before the Poisson step and
// added back after it.
Image ObserveAdu(const SimulationConfig& config, const Image& expected_e,
                 std::mt19937_64& engine);
// The same steps for one pixel: Poisson shot noise on the charge [e-] (the pedestal [e-]
// added without it), Gaussian read noise [e-], the gain [e-/ADU] and bias [ADU], rounded to a
// whole ADU and clipped to [0, min(saturation, 65535)]. The stored ADU value.
double ObservePixelAdu(double charge_e, double pedestal_e, double gain_e_per_adu,
                       double read_noise_e, double bias_adu, double saturation_adu,
                       std::mt19937_64& engine);

// The random stream of exposure `index`: independent of the number of exposures.
std::mt19937_64 ExposureEngine(const SimulationConfig& config, int index);

struct SimulationResult {
  std::vector<std::string> files;  // in exposure order
  std::string truth_path;
};

// Writes DIR/exposure_NNN.fits (or model_NNN.fits with `noiseless`) and DIR/truth.json.
// truth.json records the injected effects with their resolved parameters ("effects", absent
// when nothing is injected) and, per exposure with effects, what they did: the brighter-fatter signal and widths,
// the jitter and motion-blur node count, the defocus-kernel centre and the CCD widths handed
// to the renderer (exposures[k].effects).
// All files are first written to a temporary folder inside DIR and moved into place only
// when every one succeeded, truth.json last; on failure nothing is left behind.
bool RunSimulation(const SimulationConfig& config, const std::string& out_dir, bool noiseless,
                   SimulationResult* result, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_SIMULATE_H_
