#include "ccdpsf/simulate.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/model/renderer.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/random.h"
#include "ccdpsf/staged_output.h"
#include "glog/logging.h"
#include "internal/json_reader.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

using internal::JsonReader;
using nlohmann::json;

namespace {

// Largest frame the simulator renders (per axis) [px]: beyond this the integrated
// renderer's quadrature grid would need more memory than a workstation wants to spend.
constexpr int kMaxFrameSide = 2048;

bool ParseModel(const json& j, SimulationConfig* c, std::string* error) {
  JsonReader r(j, "model", error);
  std::string sampling = "integrated";
  r.String("sampling", &sampling);
  if (r.ok() && !model::ParseSampling(sampling, &c->model.sampling)) {
    r.Fail("'model.sampling' must be \"integrated\" or \"pixel_centre\" (got \"" + sampling +
           "\")");
  }
  r.Number("airy_radius_px", &c->airy_radius_px, true);
  r.Number("ccd_sigma_x_px", &c->ccd_sigma_x_px, true);
  r.Number("ccd_sigma_y_px", &c->ccd_sigma_y_px, true);
  long long stamp = c->stamp_size;
  r.Integer("stamp_size", &stamp);
  c->stamp_size = static_cast<int>(stamp);
  if (r.ok() && !r.Has("defocus")) r.Fail("'model.defocus' is required");
  if (r.ok()) {
    JsonReader d(r.Get("defocus"), "model.defocus", error);
    std::string kind;
    d.String("kind", &kind, true);
    if (d.ok() && !model::ParseDefocusKind(kind, &c->model.defocus)) {
      d.Fail("'model.defocus.kind' must be \"gaussian\" or \"pillbox\" (got \"" + kind + "\")");
    }
    if (d.ok()) {
      d.Number(c->model.defocus == model::DefocusKind::kGaussian ? "sigma_px" : "radius_px",
               &c->defocus_px, true);
    }
    d.RejectUnknownKeys();
    if (!d.ok()) return false;
  }
  r.RejectUnknownKeys();
  return r.ok();
}

bool ParseExposure(const json& j, int index, const SimulationConfig& c, double wavelength_nm,
                   double exptime_s, SimulatedExposure* e, std::string* error) {
  JsonReader r(j, "exposures[" + std::to_string(index) + "]", error);
  const bool peak = c.model.sampling == model::Sampling::kPixelCentre;
  // Each sampling has its own intensity parameter; the other name is an error.
  r.Number(peak ? "peak_e" : "flux_e", &e->flux_e, true);
  r.Number("x_px", &e->x_px, true);
  r.Number("y_px", &e->y_px, true);
  e->wavelength_nm = wavelength_nm;
  e->exptime_s = exptime_s;
  r.Number("wavelength_nm", &e->wavelength_nm);
  r.Number("exptime_s", &e->exptime_s);
  if (r.Has("focus_position_um")) {
    double focus = 0.0;
    r.Number("focus_position_um", &focus);
    e->focus_position_um = focus;
  }
  if (r.Has("defocus_px")) {
    double defocus = 0.0;
    r.Number("defocus_px", &defocus);
    e->defocus_px = defocus;
  }
  if (r.ok() && j.contains(peak ? "flux_e" : "peak_e")) {
    r.Fail("'" + r.Path(peak ? "flux_e" : "peak_e") + "' does not apply to " +
           model::ToString(c.model.sampling) + " sampling; use '" +
           (peak ? "peak_e" : "flux_e") + "'");
  }
  r.RejectUnknownKeys();
  if (!r.ok()) return false;
  std::ostringstream why;
  if (!(e->flux_e >= 0 && e->flux_e <= kMaxSimulatedIntensityE)) {
    why << r.Path(peak ? "peak_e" : "flux_e") << " = " << e->flux_e << " is outside 0 to "
        << kMaxSimulatedIntensityE << " e-";
  } else if (e->x_px < c.prescan_x - 0.5 || e->x_px > c.FrameNx() - 0.5 || e->y_px < -0.5 ||
           e->y_px > c.ny - 0.5) {
    why << "spot of exposures[" << index << "] at (" << e->x_px << ", " << e->y_px
        << ") is outside the image area";
  } else if (e->wavelength_nm <= 0) why << "wavelength_nm must be > 0";
  else if (e->exptime_s < 0) why << "exptime_s must be >= 0";
  if (!why.str().empty()) {
    *error = why.str();
    return false;
  }
  return true;
}

// Pixel-centre stamps: origin of the stamp (frame coordinates) holding exposure e, chosen
// so that its centre index c = int(n/2 - 0.5) is the pixel nearest the spot.
void PixelCentreStampOrigin(const SimulationConfig& c, const SimulatedExposure& e, int* ox,
                            int* oy, int* n) {
  *n = std::min({c.stamp_size, c.nx, c.ny});
  const int centre = static_cast<int>(*n / 2.0 - 0.5);
  *ox = static_cast<int>(std::lround(e.x_px)) - centre;
  *oy = static_cast<int>(std::lround(e.y_px)) - centre;
  *ox = std::clamp(*ox, c.prescan_x, c.FrameNx() - *n);
  *oy = std::clamp(*oy, 0, c.ny - *n);
}

FitsHeader ExposureHeader(const SimulationConfig& c, const SimulatedExposure& e, int index,
                          bool noiseless) {
  FitsHeader h;
  if (!noiseless) {
    h.push_back({"GAIN", c.gain_e_per_adu, "gain [e-/ADU]"});
    h.push_back({"RDNOISE", c.read_noise_e, "read noise [e-]"});
    h.push_back({"BIASLVL", c.bias_adu, "bias level [ADU]"});
    if (c.prescan_x > 0) {
      h.push_back({"BIASSEC", "[1:" + std::to_string(c.prescan_x) + ",1:" +
                                  std::to_string(c.ny) + "]",
                   "prescan (bias) region"});
    }
    h.push_back({"SATURATE", std::min(c.saturation_adu, 65535.0), "saturation [ADU]"});
  } else {
    h.push_back({"BUNIT", std::string("electron"), "expected photo-electrons, noiseless"});
  }
  h.push_back({"WAVELEN", e.wavelength_nm, "wavelength [nm]"});
  h.push_back({"EXPTIME", e.exptime_s, "exposure time [s]"});
  h.push_back({"PIXSIZE", c.pixel_um, "pixel size [um]"});
  if (e.focus_position_um) h.push_back({"FOCUSPOS", *e.focus_position_um, "focus stage [um]"});
  h.push_back({"SIMSEED", static_cast<long long>(c.seed & 0x7FFFFFFFFFFFFFFFULL),
               "ccdpsf simulate seed"});
  h.push_back({"SIMINDEX", static_cast<long long>(index), "exposure index in truth.json"});
  h.push_back({"SAMPLING", model::ToString(c.model.sampling), "model sampling"});
  FitsHeader kept;
  for (const FitsKey& k : h) {
    if (std::find(c.omit_keywords.begin(), c.omit_keywords.end(), k.name) ==
        c.omit_keywords.end()) {
      kept.push_back(k);
    }
  }
  return kept;
}

std::string IndexedName(const char* stem, int index) {
  char name[64];
  std::snprintf(name, sizeof(name), "%s_%03d.fits", stem, index);
  return name;
}

}  // namespace

model::SpotParams SimulationConfig::Params(const SimulatedExposure& e) const {
  model::SpotParams p;
  p[model::kFlux] = e.flux_e;
  p[model::kCentreX] = e.x_px;
  p[model::kCentreY] = e.y_px;
  p[model::kAiryRadius] = airy_radius_px;
  p[model::kDefocus] = e.defocus_px.value_or(defocus_px);
  p[model::kCcdSigmaX] = ccd_sigma_x_px;
  p[model::kCcdSigmaY] = ccd_sigma_y_px;
  return p;
}

model::ExposureEffects SimulationConfig::EffectsFor(const SimulatedExposure& e) const {
  model::ExposureEffects out = effects;
  if (e.jitter) out.jitter = *e.jitter;
  return out;
}

std::optional<SimulationConfig> ParseSimulationConfig(const std::string& text,
                                                      std::string* error) {
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false, /*ignore_comments=*/true);
  if (j.is_discarded()) {
    *error = "simulation config is not valid JSON";
    return std::nullopt;
  }
  SimulationConfig c;
  JsonReader r(j, "", error);
  long long seed = 0;
  r.Integer("seed", &seed, true);
  if (r.ok() && seed < 0) r.Fail("'seed' must be >= 0");
  c.seed = static_cast<uint64_t>(seed);
  if (r.ok() && r.Has("image")) {
    JsonReader im(r.Get("image"), "image", error);
    long long nx = c.nx, ny = c.ny, prescan = 0;
    im.Integer("nx", &nx, true);
    im.Integer("ny", &ny, true);
    im.Integer("prescan_x", &prescan);
    im.RejectUnknownKeys();
    if (!im.ok()) return std::nullopt;
    if (nx < 5 || ny < 5 || nx > kMaxFrameSide || ny > kMaxFrameSide || prescan < 0 ||
        prescan > kMaxFrameSide) {
      *error = "image.nx and image.ny must be within [5, " + std::to_string(kMaxFrameSide) +
               "] and image.prescan_x >= 0";
      return std::nullopt;
    }
    c.nx = static_cast<int>(nx);
    c.ny = static_cast<int>(ny);
    c.prescan_x = static_cast<int>(prescan);
  }
  if (r.ok() && r.Has("detector")) {
    JsonReader d(r.Get("detector"), "detector", error);
    d.Number("gain_e_per_adu", &c.gain_e_per_adu);
    d.Number("read_noise_e", &c.read_noise_e);
    d.Number("bias_adu", &c.bias_adu);
    d.Number("pixel_um", &c.pixel_um);
    d.Number("saturation_adu", &c.saturation_adu);
    d.RejectUnknownKeys();
    if (!d.ok()) return std::nullopt;
    if (c.gain_e_per_adu <= 0 || c.read_noise_e < 0 || c.bias_adu < 0 || c.pixel_um <= 0 ||
        c.saturation_adu <= 0) {
      *error = "detector: gain and pixel size must be > 0, read noise and bias >= 0, "
               "saturation > 0";
      return std::nullopt;
    }
  }
  if (r.ok() && !r.Has("model")) r.Fail("'model' is required");
  if (r.ok() && !ParseModel(r.Get("model"), &c, error)) return std::nullopt;
  // Effects are parsed after the exposures: per-exposure lists must match their number.
  const json* effects_json = nullptr;
  if (r.ok() && r.Has("effects")) effects_json = &r.Get("effects");
  if (r.ok() && r.Has("omit_keywords")) {
    const json& omit = r.Get("omit_keywords");
    if (!omit.is_array()) {
      r.Fail("'omit_keywords' must be a list of keyword names");
    } else {
      for (const json& k : omit) {
        if (!k.is_string()) {
          r.Fail("'omit_keywords' must be a list of keyword names");
          break;
        }
        c.omit_keywords.push_back(k.get<std::string>());
      }
    }
  }
  double wavelength_nm = 800.0, exptime_s = 1.0;
  r.Number("wavelength_nm", &wavelength_nm);
  r.Number("exptime_s", &exptime_s);
  if (r.ok() && !r.Has("exposures")) r.Fail("'exposures' is required");
  if (r.ok()) {
    const json& list = r.Get("exposures");
    if (!list.is_array() || list.empty()) {
      r.Fail("'exposures' must be a non-empty list");
    } else {
      for (size_t i = 0; i < list.size(); ++i) {
        SimulatedExposure e;
        if (!ParseExposure(list[i], static_cast<int>(i), c, wavelength_nm, exptime_s, &e,
                           error)) {
          return std::nullopt;
        }
        c.exposures.push_back(e);
      }
    }
  }
  r.RejectUnknownKeys();
  if (!r.ok()) return std::nullopt;
  if (effects_json != nullptr) {
    model::EffectsConfig effects;
    if (!model::ParseEffectsConfig(*effects_json, static_cast<int>(c.exposures.size()),
                                   c.model.sampling, &effects, error)) {
      return std::nullopt;
    }
    c.effects = effects.common;
    for (size_t k = 0; k < effects.jitter_per_exposure.size(); ++k) {
      c.exposures[k].jitter = effects.jitter_per_exposure[k];
    }
  }
  if (c.model.sampling == model::Sampling::kPixelCentre &&
      c.model.defocus != model::DefocusKind::kGaussian) {
    *error = "pixel_centre sampling has only the Gaussian defocus of the 2015 code";
    return std::nullopt;
  }
  if (c.model.sampling == model::Sampling::kPixelCentre && c.stamp_size < 5) {
    *error = "model.stamp_size must be >= 5";
    return std::nullopt;
  }
  for (const SimulatedExposure& e : c.exposures) {
    if (!model::ValidSpotParams(c.model, c.Params(e), error)) return std::nullopt;
  }
  return c;
}

std::optional<SimulationConfig> LoadSimulationConfig(const std::string& path,
                                                     std::string* error) {
  std::string text;
  if (!ReadTextInput(path, "simulation config", &text, error)) return std::nullopt;
  auto config = ParseSimulationConfig(text, error);
  if (!config) *error = "'" + path + "': " + *error;
  return config;
}

Image ExpectedElectrons(const SimulationConfig& c, const SimulatedExposure& e,
                        model::KernelEffectDetails* details) {
  Image frame(c.FrameNx(), c.ny, 0.0);
  const model::ExposureEffects effects = c.EffectsFor(e);
  model::SpotRenderer renderer(c.model);
  model::SpotParams p = c.Params(e);
  model::PixelGrid grid;
  int ox = c.prescan_x, oy = 0;
  if (c.model.sampling == model::Sampling::kPixelCentre) {
    int n;
    PixelCentreStampOrigin(c, e, &ox, &oy, &n);
    grid.nx = grid.ny = n;
    // The 2015 model works on stamp indices.
    p[model::kCentreX] -= ox;
    p[model::kCentreY] -= oy;
  } else {
    grid.nx = c.nx;
    grid.ny = c.ny;
    grid.x0 = c.prescan_x;
    grid.y0 = 0.0;
  }
  std::vector<double> model(grid.size());
  // Without kernel effects this is renderer.Render(p, ...) itself.
  model::RenderSpotWithEffects(renderer, effects, p, grid, model.data(), details);
  if (details != nullptr) {
    details->centre_x_px += c.model.sampling == model::Sampling::kPixelCentre ? ox : 0;
    details->centre_y_px += c.model.sampling == model::Sampling::kPixelCentre ? oy : 0;
    details->defocus_centre_x_px += c.model.sampling == model::Sampling::kPixelCentre ? ox : 0;
    details->defocus_centre_y_px += c.model.sampling == model::Sampling::kPixelCentre ? oy : 0;
  }
  for (int j = 0; j < grid.ny; ++j) {
    for (int i = 0; i < grid.nx; ++i) frame(ox + i, oy + j) = model[j * grid.nx + i];
  }
  if (effects.HasImageEffects()) {
    // On the image area (prescan columns hold no charge), in frame coordinates.
    const model::PixelGrid area{c.nx, c.ny, static_cast<double>(c.prescan_x), 0.0};
    std::vector<double> image(area.size());
    for (int j = 0; j < c.ny; ++j) {
      for (int i = 0; i < c.nx; ++i) image[j * c.nx + i] = frame(c.prescan_x + i, j);
    }
    model::SpotReference spot{e.flux_e, e.x_px, e.y_px};
    if (c.model.sampling == model::Sampling::kPixelCentre) {
      // m is not a flux: the halo takes its share of the stamp's electrons.
      spot.flux_e = 0.0;
      for (double v : model) spot.flux_e += v;
    }
    model::ApplyImageEffects(effects, area, spot, image.data());
    for (int j = 0; j < c.ny; ++j) {
      for (int i = 0; i < c.nx; ++i) frame(c.prescan_x + i, j) = image[j * c.nx + i];
    }
  }
  return frame;
}

std::mt19937_64 ExposureEngine(const SimulationConfig& c, int index) {
  return std::mt19937_64(DeriveSeed(c.seed, static_cast<uint64_t>(index)));
}

double ObservePixelAdu(double charge_e, double pedestal_e, double gain_e_per_adu,
                       double read_noise_e, double bias_adu, double saturation_adu,
                       std::mt19937_64& engine) {
  const double ceiling = std::floor(std::min(saturation_adu, 65535.0));
  const double photo_e =
      static_cast<double>(Poisson(std::max(charge_e, 0.0), engine)) + pedestal_e;  // step 5
  const double read_e = read_noise_e * StandardNormal(engine);                     // step 7
  const double value = bias_adu + (photo_e + read_e) / gain_e_per_adu;             // steps 6, 8
  return std::clamp(std::nearbyint(value), 0.0, ceiling);                          // step 9
}

Image ObserveAdu(const SimulationConfig& c, const Image& expected_e, std::mt19937_64& engine) {
  Image adu(expected_e.nx, expected_e.ny);
  const double pedestal_e = c.effects.background ? c.effects.background->pedestal_e : 0.0;
  if (pedestal_e != 0.0) {
    CHECK(expected_e.nx == c.FrameNx() && expected_e.ny == c.ny)
        << "ObserveAdu: the image is not the configured frame";
  }
  for (size_t q = 0; q < expected_e.size(); ++q) {
    // The pedestal sits in the image area only, like ExpectedElectrons'.
    const double bg =
        static_cast<int>(q % static_cast<size_t>(expected_e.nx)) >= c.prescan_x ? pedestal_e
                                                                                : 0.0;
    adu.data[q] = ObservePixelAdu(expected_e.data[q] - bg, bg, c.gain_e_per_adu, c.read_noise_e,
                                  c.bias_adu, c.saturation_adu, engine);
  }
  return adu;
}

bool RunSimulation(const SimulationConfig& c, const std::string& out_dir, bool noiseless,
                   SimulationResult* result, std::string* error) {
  // Everything is staged and moved into place at the end, truth.json last; on failure the
  // staging folder is removed and nothing is left behind.
  StagedOutput out;
  if (!out.Begin(out_dir, error)) return false;
  json truth;
  truth["seed"] = c.seed;
  truth["noiseless"] = noiseless;
  truth["sampling"] = model::ToString(c.model.sampling);
  truth["defocus_kind"] = model::ToString(c.model.defocus);
  truth["image"] = {{"nx", c.nx}, {"ny", c.ny}, {"prescan_x", c.prescan_x}};
  truth["detector"] = {{"gain_e_per_adu", c.gain_e_per_adu},
                       {"read_noise_e", c.read_noise_e},
                       {"bias_adu", c.bias_adu},
                       {"pixel_um", c.pixel_um},
                       {"saturation_adu", c.saturation_adu}};
  truth["parameters"] = {{"airy_radius_px", c.airy_radius_px},
                         {c.model.defocus == model::DefocusKind::kGaussian ? "defocus_sigma_px"
                                                                           : "defocus_radius_px",
                          c.defocus_px},
                         {"ccd_sigma_x_px", c.ccd_sigma_x_px},
                         {"ccd_sigma_y_px", c.ccd_sigma_y_px}};
  {
    // The injected effects as resolved (defaults filled in); jitter as lists when it varies
    // per exposure. Absent when nothing is injected, so that such a truth.json is the same,
    // byte for byte, as before effects existed.
    model::EffectsConfig effects;
    effects.common = c.effects;
    bool per_exposure = false;
    for (const SimulatedExposure& e : c.exposures) per_exposure |= e.jitter.has_value();
    if (per_exposure) {
      for (const SimulatedExposure& e : c.exposures) {
        // An exposure without jitter (only possible in a config built in code) records zeros.
        effects.jitter_per_exposure.push_back(c.EffectsFor(e).jitter.value_or(
            model::JitterParams{0.0, 0.0, 0.0, 0.0}));
      }
    }
    if (!effects.empty()) truth["effects"] = model::EffectsConfigToJson(effects);
  }
  truth["exposures"] = json::array();
  std::vector<std::string> names;
  for (size_t k = 0; k < c.exposures.size(); ++k) {
    const SimulatedExposure& e = c.exposures[k];
    model::KernelEffectDetails details;
    const Image expected = ExpectedElectrons(c, e, &details);
    const std::string name = IndexedName(noiseless ? "model" : "exposure", static_cast<int>(k));
    const FitsHeader header = ExposureHeader(c, e, static_cast<int>(k), noiseless);
    bool ok;
    if (noiseless) {
      ok = WriteFitsImageF64(out.Path(name), expected, header, error);
    } else {
      std::mt19937_64 engine = ExposureEngine(c, static_cast<int>(k));
      ok = WriteFitsImageU16(out.Path(name), ObserveAdu(c, expected, engine), header, error);
    }
    if (!ok) return false;
    names.push_back(name);
    double peak = 0.0;
    for (double v : expected.data) peak = std::max(peak, v);
    json ej = {{"file", name},
               {"x_px", e.x_px},
               {"y_px", e.y_px},
               {"wavelength_nm", e.wavelength_nm},
               {"exptime_s", e.exptime_s},
               {"expected_peak_pixel_e", peak}};
    ej[c.model.sampling == model::Sampling::kPixelCentre ? "peak_e" : "flux_e"] = e.flux_e;
    if (e.focus_position_um) ej["focus_position_um"] = *e.focus_position_um;
    if (e.defocus_px) ej["defocus_px"] = *e.defocus_px;
    const model::ExposureEffects effects = c.EffectsFor(e);
    if (!effects.empty()) {
      // What the effects did to this exposure.
      json applied = json::object();
      if (effects.brighter_fatter) {
        applied["brighter_fatter"] = {{"peak_e", details.peak_e},
                                      {"ccd_sigma_x_px", details.ccd_sigma_x_px},
                                      {"ccd_sigma_y_px", details.ccd_sigma_y_px}};
      }
      if (effects.jitter) {
        applied["jitter"] = {{"sigma_x_px", effects.jitter->sigma_x_px},
                             {"sigma_y_px", effects.jitter->sigma_y_px},
                             {"motion_length_px", effects.jitter->motion_length_px},
                             {"motion_angle_deg", effects.jitter->motion_angle_deg},
                             {"motion_nodes", details.motion_nodes}};
      }
      if (effects.defocus_offset) {
        applied["defocus_offset"] = {{"defocus_centre_x_px", details.defocus_centre_x_px},
                                     {"defocus_centre_y_px", details.defocus_centre_y_px}};
      }
      if (effects.HasKernelEffects()) {
        applied["rendered_ccd_sigma_x_px"] = details.rendered_sigma_x_px;
        applied["rendered_ccd_sigma_y_px"] = details.rendered_sigma_y_px;
      }
      ej["effects"] = applied;
    }
    truth["exposures"].push_back(ej);
  }
  truth["software"] = SoftwareVersions();
  if (!WriteTextFileAtomically(out.Path("truth.json"), truth.dump(2) + "\n", error)) {
    return false;
  }
  if (!out.Commit({"truth.json"}, error)) return false;
  result->files.clear();
  for (const std::string& name : names) result->files.push_back(out_dir + "/" + name);
  result->truth_path = out_dir + "/truth.json";
  return true;
}

}  // namespace ccdpsf
