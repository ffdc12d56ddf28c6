#include "ccdpsf/campaign_simulation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/metrics.h"
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

// Same frame limit as the single simulation (simulate.cc): beyond it the integrated
// renderer's quadrature grid would need more memory than a workstation wants to spend.
constexpr int kMaxFrameSide = 2048;
// Guards against a typo turning into hours of rendering.
constexpr long long kMaxExposuresPerGroup = 10000;

// Seed streams of DeriveSeed (see the header).
constexpr uint64_t kSettingsStream = 0;
constexpr uint64_t kFocusSeriesStream = 1;
constexpr uint64_t kNoiseStream = 0;
constexpr uint64_t kJitterStream = 1;

// FWHM [um] -> sigma [px]: FWHM = 2 sqrt(2 ln 2) sigma pixel_um.
double SigmaPx(double fwhm_um, double pixel_um) {
  return fwhm_um / (2.0 * std::sqrt(2.0 * std::log(2.0)) * pixel_um);
}

// 600 -> "600", 632.8 -> "632.8": for group names.
std::string CompactNumber(double v) {
  char text[64];
  if (v == std::floor(v) && std::fabs(v) < 1e15) {
    std::snprintf(text, sizeof(text), "%lld", static_cast<long long>(v));
  } else {
    std::snprintf(text, sizeof(text), "%.10g", v);
  }
  return text;
}

bool ParseImage(const json& j, CampaignConfig* c, std::string* error) {
  JsonReader r(j, "campaign.image", error);
  long long nx = c->nx, ny = c->ny, prescan = c->prescan_x;
  r.Integer("nx", &nx);
  r.Integer("ny", &ny);
  r.Integer("prescan_x", &prescan);
  r.RejectUnknownKeys();
  if (!r.ok()) return false;
  if (nx < 5 || ny < 5 || nx > kMaxFrameSide || ny > kMaxFrameSide) {
    *error = "'campaign.image.nx' and 'campaign.image.ny' must be within [5, " +
             std::to_string(kMaxFrameSide) + "]";
    return false;
  }
  if (prescan < 0 || prescan > kMaxFrameSide) {
    *error = "'campaign.image.prescan_x' must be within [0, " + std::to_string(kMaxFrameSide) + "]";
    return false;
  }
  c->nx = static_cast<int>(nx);
  c->ny = static_cast<int>(ny);
  c->prescan_x = static_cast<int>(prescan);
  return true;
}

bool ParseDetector(const json& j, CampaignConfig* c, std::string* error) {
  JsonReader r(j, "campaign.detector", error);
  r.Number("gain_e_per_adu", &c->gain_e_per_adu);
  r.Number("read_noise_e", &c->read_noise_e);
  r.Number("bias_adu", &c->bias_adu);
  r.Number("pixel_um", &c->pixel_um);
  r.Number("saturation_adu", &c->saturation_adu);
  r.RejectUnknownKeys();
  if (!r.ok()) return false;
  if (c->gain_e_per_adu <= 0) r.Fail("'campaign.detector.gain_e_per_adu' must be > 0");
  if (c->read_noise_e < 0) r.Fail("'campaign.detector.read_noise_e' must be >= 0");
  if (c->bias_adu < 0) r.Fail("'campaign.detector.bias_adu' must be >= 0");
  if (c->pixel_um <= 0) r.Fail("'campaign.detector.pixel_um' must be > 0");
  if (c->saturation_adu <= 0) r.Fail("'campaign.detector.saturation_adu' must be > 0");
  return r.ok();
}

bool ParseDefocus(const json& j, CampaignConfig* c, std::string* error) {
  JsonReader r(j, "campaign.defocus", error);
  std::string kind;
  r.String("kind", &kind, true);
  if (r.ok() && !model::ParseDefocusKind(kind, &c->defocus_kind)) {
    r.Fail("'campaign.defocus.kind' must be \"gaussian\" or \"pillbox\" (got \"" + kind + "\")");
  }
  const char* key = c->defocus_kind == model::DefocusKind::kGaussian ? "sigma_px" : "radius_px";
  r.Number(key, &c->defocus_px, true);
  r.RejectUnknownKeys();
  if (r.ok() && c->defocus_px < 0) r.Fail("'" + r.Path(key) + "' must be >= 0");
  return r.ok();
}

bool ParseIntensityRelation(const json& j, const std::string& path, IntensityRelation* rel,
                            std::string* error) {
  JsonReader r(j, path, error);
  r.Number("intercept_um", &rel->intercept_um);
  r.Number("slope_um_per_e", &rel->slope_um_per_e);
  r.RejectUnknownKeys();
  return r.ok();
}

bool ParseTruth(const json& j, CampaignTruth* t, std::string* error) {
  JsonReader r(j, "campaign.truth", error);
  r.Number("reference_intensity_e", &t->reference_intensity_e);
  r.Number("reference_wavelength_nm", &t->reference_wavelength_nm);
  r.Number("alpha_x", &t->alpha_x);
  r.Number("alpha_y", &t->alpha_y);
  if (r.Has("intensity_x") &&
      !ParseIntensityRelation(r.Get("intensity_x"), "campaign.truth.intensity_x", &t->intensity_x,
                              error)) {
    return false;
  }
  if (r.Has("intensity_y") &&
      !ParseIntensityRelation(r.Get("intensity_y"), "campaign.truth.intensity_y", &t->intensity_y,
                              error)) {
    return false;
  }
  r.RejectUnknownKeys();
  if (!r.ok()) return false;
  std::string why;
  if (!t->IsValid(&why)) {
    *error = "campaign.truth: " + why;
    return false;
  }
  return true;
}

// The keys shared by a setting and a focus series.
void ReadWavelengthPeakExptime(JsonReader* r, double* wavelength_nm, double* peak_e,
                               double* exptime_s) {
  r->Number("wavelength_nm", wavelength_nm, true);
  r->Number("peak_e", peak_e, true);
  r->Number("exptime_s", exptime_s, true);
  if (!r->ok()) return;
  if (*wavelength_nm <= 0) {
    r->Fail("'" + r->Path("wavelength_nm") + "' must be > 0");
  } else if (!(*peak_e > 0 && *peak_e <= kMaxSimulatedIntensityE)) {
    r->Fail("'" + r->Path("peak_e") + "' must be > 0 and at most 1e12 e-");
  } else if (*exptime_s < 0) {
    r->Fail("'" + r->Path("exptime_s") + "' must be >= 0");
  }
}

bool ParseSetting(const json& j, const std::string& path, CampaignSetting* s, std::string* error) {
  JsonReader r(j, path, error);
  ReadWavelengthPeakExptime(&r, &s->wavelength_nm, &s->peak_e, &s->exptime_s);
  long long n = 0;
  r.Integer("exposures", &n, true);
  if (r.Has("focus_position_um")) {
    double z = 0.0;
    r.Number("focus_position_um", &z, true);
    s->focus_position_um = z;
  }
  r.RejectUnknownKeys();
  if (r.ok() && (n < 1 || n > kMaxExposuresPerGroup)) {
    r.Fail("'" + r.Path("exposures") + "' must be within [1, " +
           std::to_string(kMaxExposuresPerGroup) + "]");
  }
  s->exposures = static_cast<int>(n);
  return r.ok();
}

bool ParseFocusSeries(const json& j, const std::string& path, FocusSeries* f, std::string* error) {
  JsonReader r(j, path, error);
  ReadWavelengthPeakExptime(&r, &f->wavelength_nm, &f->peak_e, &f->exptime_s);
  if (r.ok() && !r.Has("focus_positions_um")) {
    r.Fail("'" + r.Path("focus_positions_um") + "' is required");
  }
  if (r.ok()) {
    const json& list = r.Get("focus_positions_um");
    if (!list.is_array() || list.empty()) {
      r.Fail("'" + r.Path("focus_positions_um") + "' must be a non-empty list of numbers");
    } else {
      for (const json& z : list) {
        if (!z.is_number() || !std::isfinite(z.get<double>())) {
          r.Fail("'" + r.Path("focus_positions_um") +
                 "' must be a non-empty list of finite "
                 "numbers");
          break;
        }
        f->focus_positions_um.push_back(z.get<double>());
      }
    }
  }
  long long per = f->exposures_per_position;
  r.Integer("exposures_per_position", &per);
  r.Number("best_focus_um", &f->best_focus_um);
  r.Number("defocus_sigma_px_per_um", &f->defocus_sigma_px_per_um, true);
  r.RejectUnknownKeys();
  if (!r.ok()) return false;
  if (per < 1 ||
      per * static_cast<long long>(f->focus_positions_um.size()) > kMaxExposuresPerGroup) {
    r.Fail("'" + r.Path("exposures_per_position") + "' must be >= 1, with at most " +
           std::to_string(kMaxExposuresPerGroup) + " exposures in the series");
  } else if (f->defocus_sigma_px_per_um < 0) {
    r.Fail("'" + r.Path("defocus_sigma_px_per_um") + "' must be >= 0");
  }
  f->exposures_per_position = static_cast<int>(per);
  return r.ok();
}

// A list-valued key of `r`: each element parsed by `parse` with path "<key>[i]".
template <typename T, typename Parse>
bool ParseList(JsonReader* r, const std::string& key, bool allow_empty, Parse parse,
               std::vector<T>* out, std::string* error) {
  const json& list = r->Get(key);
  if (!list.is_array() || (!allow_empty && list.empty())) {
    r->Fail("'" + r->Path(key) + "' must be a " + (allow_empty ? "" : "non-empty ") + "list");
    return false;
  }
  out->clear();
  for (size_t i = 0; i < list.size(); ++i) {
    T item;
    if (!parse(list[i], r->Path(key) + "[" + std::to_string(i) + "]", &item, error)) {
      return false;
    }
    out->push_back(item);
  }
  return true;
}

// The model parameters of the centred spot of one group, for the domain check.
bool CheckGroupDomain(const CampaignConfig& c, const std::string& path, double wavelength_nm,
                      double peak_e, model::DefocusKind kind,
                      const std::vector<double>& defocus_values_px, std::string* error) {
  const double fx = c.truth.FwhmXUm(peak_e, wavelength_nm);
  const double fy = c.truth.FwhmYUm(peak_e, wavelength_nm);
  if (!(fx > 0) || !(fy > 0) || !std::isfinite(fx) || !std::isfinite(fy)) {
    std::ostringstream why;
    why << "campaign.truth gives FWHM_x = " << fx << " um, FWHM_y = " << fy << " um at " << path
        << " (" << wavelength_nm << " nm, " << peak_e << " e-): both must be finite and > 0";
    *error = why.str();
    return false;
  }
  model::ModelOptions options;
  options.sampling = c.sampling;
  options.defocus = kind;
  for (double d : defocus_values_px) {
    model::SpotParams p;
    p[model::kFlux] = 1.0;
    p[model::kCentreX] = c.CentreXPx();
    p[model::kCentreY] = c.CentreYPx();
    p[model::kAiryRadius] = c.AiryRadiusPx(wavelength_nm);
    p[model::kDefocus] = d;
    p[model::kCcdSigmaX] = SigmaPx(fx, c.pixel_um);
    p[model::kCcdSigmaY] = SigmaPx(fy, c.pixel_um);
    std::string why;
    if (!model::ValidSpotParams(options, p, &why)) {
      *error = path + ": " + why;
      return false;
    }
  }
  return true;
}

// The defocus actually rendered for a focus series' nominal sigma_f (see the header).
double RenderedFocusDefocusPx(const CampaignConfig& c, double nominal_px) {
  return c.sampling == model::Sampling::kPixelCentre
             ? std::max(nominal_px, kPixelCentreMinDefocusPx)
             : nominal_px;
}

// Common part of a group's simulation config.
SimulationConfig GroupSimulation(const CampaignConfig& c, uint64_t group_seed, double wavelength_nm,
                                 double peak_e) {
  SimulationConfig s;
  s.seed = DeriveSeed(group_seed, kNoiseStream);
  s.nx = c.nx;
  s.ny = c.ny;
  s.prescan_x = c.prescan_x;
  s.gain_e_per_adu = c.gain_e_per_adu;
  s.read_noise_e = c.read_noise_e;
  s.bias_adu = c.bias_adu;
  s.pixel_um = c.pixel_um;
  s.saturation_adu = c.saturation_adu;
  s.model.sampling = c.sampling;
  s.model.defocus = c.defocus_kind;
  s.airy_radius_px = c.AiryRadiusPx(wavelength_nm);
  s.defocus_px = c.defocus_px;
  s.ccd_sigma_x_px = SigmaPx(c.truth.FwhmXUm(peak_e, wavelength_nm), c.pixel_um);
  s.ccd_sigma_y_px = SigmaPx(c.truth.FwhmYUm(peak_e, wavelength_nm), c.pixel_um);
  s.exposures.clear();
  return s;
}

// The intensity parameter giving the centred, noiseless spot a maximum pixel of peak_e: the
// model is linear in it, so render once with 1 and scale.
double CalibrateIntensity(const SimulationConfig& s, const CampaignConfig& c, double wavelength_nm,
                          double exptime_s, double peak_e) {
  SimulatedExposure unit;
  unit.flux_e = 1.0;
  unit.x_px = c.CentreXPx();
  unit.y_px = c.CentreYPx();
  unit.wavelength_nm = wavelength_nm;
  unit.exptime_s = exptime_s;
  const Image m = ExpectedElectrons(s, unit);
  double peak = 0.0;
  for (double v : m.data) peak = std::max(peak, v);
  CHECK_GT(peak, 0.0) << "a unit-intensity spot renders to nothing";
  return peak_e / peak;
}

// A jittered exposure of a group.
SimulatedExposure JitteredExposure(const CampaignConfig& c, double intensity, double wavelength_nm,
                                   double exptime_s, std::mt19937_64& jitter) {
  SimulatedExposure e;
  e.flux_e = intensity;
  const double j = c.position_jitter_px;
  const double dx = j * (2.0 * Uniform01(jitter) - 1.0);
  const double dy = j * (2.0 * Uniform01(jitter) - 1.0);
  e.x_px = c.CentreXPx() + dx;
  e.y_px = c.CentreYPx() + dy;
  e.wavelength_nm = wavelength_nm;
  e.exptime_s = exptime_s;
  return e;
}

// Total (defocus-included) widths: Gaussian defocus adds sigma_f^2, a pillbox of radius R
// its second moment R^2 / 4, on each axis (as fit.cc's derived total widths).
json TotalWidths(model::DefocusKind kind, double defocus_px, double sx, double sy,
                 double pixel_um) {
  const double d2 = kind == model::DefocusKind::kGaussian ? defocus_px * defocus_px
                                                          : defocus_px * defocus_px / 4.0;
  const double tx = std::sqrt(d2 + sx * sx);
  const double ty = std::sqrt(d2 + sy * sy);
  const PsfMetrics total = GaussianMetrics(tx, ty, pixel_um);
  return {{"total_sigma_x_px", tx}, {"total_sigma_y_px", ty}, {"total_fwhm_um", total.fwhm_um}};
}

json RelationsJson(const CampaignTruth& t) {
  json r;
  r["model"] =
      "FWHM_x(I, lambda) = a_x lambda^alpha_x (c_x + s_x I) / (c_x + s_x I0), a_x = (c_x + s_x "
      "I0) / lambda0^alpha_x, same for y; FWHM(lambda) = sqrt(a_x a_y) lambda^((alpha_x + "
      "alpha_y) / 2) at I0; sigma [px] = FWHM / (2 sqrt(2 ln 2) pixel_um); FWHM in um, lambda "
      "in nm, I in peak-pixel e-";
  r["reference_intensity_e"] = t.reference_intensity_e;
  r["reference_wavelength_nm"] = t.reference_wavelength_nm;
  r["fwhm_x_um_vs_wavelength"] = {{"a", t.AX()}, {"alpha", t.alpha_x}};
  r["fwhm_y_um_vs_wavelength"] = {{"a", t.AY()}, {"alpha", t.alpha_y}};
  r["fwhm_um_vs_wavelength"] = {{"a", t.GeometricA()}, {"alpha", t.GeometricAlpha()}};
  r["fwhm_x_um_vs_intensity"] = {{"intercept", t.intensity_x.intercept_um},
                                 {"slope", t.intensity_x.slope_um_per_e}};
  r["fwhm_y_um_vs_intensity"] = {{"intercept", t.intensity_y.intercept_um},
                                 {"slope", t.intensity_y.slope_um_per_e}};
  return r;
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Truth relations.

double CampaignTruth::AX() const {
  return intensity_x.FwhmUm(reference_intensity_e) / std::pow(reference_wavelength_nm, alpha_x);
}

double CampaignTruth::AY() const {
  return intensity_y.FwhmUm(reference_intensity_e) / std::pow(reference_wavelength_nm, alpha_y);
}

double CampaignTruth::GeometricA() const { return std::sqrt(AX() * AY()); }

double CampaignTruth::GeometricAlpha() const { return 0.5 * (alpha_x + alpha_y); }

double CampaignTruth::FwhmXUm(double intensity_e, double wavelength_nm) const {
  return AX() * std::pow(wavelength_nm, alpha_x) * intensity_x.FwhmUm(intensity_e) /
         intensity_x.FwhmUm(reference_intensity_e);
}

double CampaignTruth::FwhmYUm(double intensity_e, double wavelength_nm) const {
  return AY() * std::pow(wavelength_nm, alpha_y) * intensity_y.FwhmUm(intensity_e) /
         intensity_y.FwhmUm(reference_intensity_e);
}

bool CampaignTruth::IsValid(std::string* error) const {
  std::ostringstream why;
  if (!(reference_intensity_e > 0)) {
    why << "'reference_intensity_e' must be > 0";
  } else if (!(reference_wavelength_nm > 0)) {
    why << "'reference_wavelength_nm' must be > 0";
  } else if (!(intensity_x.FwhmUm(reference_intensity_e) > 0)) {
    why << "'intensity_x' gives FWHM_x(I0) = " << intensity_x.FwhmUm(reference_intensity_e)
        << " um; it must be > 0";
  } else if (!(intensity_y.FwhmUm(reference_intensity_e) > 0)) {
    why << "'intensity_y' gives FWHM_y(I0) = " << intensity_y.FwhmUm(reference_intensity_e)
        << " um; it must be > 0";
  } else if (!std::isfinite(AX()) || !std::isfinite(AY())) {
    why << "the wavelength laws' amplitudes a_x, a_y are not finite";
  }
  if (why.str().empty()) return true;
  *error = why.str();
  return false;
}

const FocusSeries* CampaignConfig::FocusLawFor(double wavelength_nm) const {
  for (const FocusSeries& f : focus_series) {
    if (std::fabs(f.wavelength_nm - wavelength_nm) <= 0.5) return &f;
  }
  return nullptr;
}

double FocusSeries::DefocusSigmaPx(double focus_position_um) const {
  return defocus_sigma_px_per_um * std::fabs(focus_position_um - best_focus_um);
}

double CampaignConfig::AiryRadiusPx(double wavelength_nm) const {
  return airy_radius_px_at_800nm * wavelength_nm / 800.0;
}

double CampaignConfig::CentreXPx() const { return prescan_x + static_cast<int>(nx / 2.0 - 0.5); }

double CampaignConfig::CentreYPx() const { return static_cast<int>(ny / 2.0 - 0.5); }

std::vector<CampaignSetting> Table1Settings() {
  // Paper Table 1: wavelength [nm], peak intensity [e-], exposure time [s], exposures.
  const double table[][4] = {{600, 7900, 0.1, 12},  {600, 21400, 0.3, 12}, {600, 160200, 2.5, 6},
                             {700, 151700, 2.5, 6}, {800, 7100, 0.1, 10},  {800, 23400, 0.4, 8},
                             {800, 50200, 1.0, 7},  {800, 82800, 1.8, 6},  {800, 109300, 2.6, 5},
                             {800, 145300, 3.6, 3}, {800, 157800, 4.1, 5}, {800, 159400, 4.2, 3},
                             {890, 143000, 2.8, 4}};
  std::vector<CampaignSetting> settings;
  for (const auto& row : table) {
    CampaignSetting s;
    s.wavelength_nm = row[0];
    s.peak_e = row[1];
    s.exptime_s = row[2];
    s.exposures = static_cast<int>(row[3]);
    settings.push_back(s);
  }
  return settings;
}

// ---------------------------------------------------------------------------------------
// Configuration.

bool IsCampaignConfig(const std::string& json_text) {
  const json j = json::parse(json_text, nullptr, /*allow_exceptions=*/false,
                             /*ignore_comments=*/true);
  return !j.is_discarded() && j.is_object() && j.contains("campaign");
}

std::optional<CampaignConfig> ParseCampaignConfig(const std::string& text, std::string* error) {
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false, /*ignore_comments=*/true);
  if (j.is_discarded()) {
    *error = "campaign config is not valid JSON";
    return std::nullopt;
  }
  JsonReader top(j, "", error);
  if (top.ok() && !top.Has("campaign")) top.Fail("'campaign' is required");
  if (!top.ok()) return std::nullopt;
  const json& body = top.Get("campaign");
  top.RejectUnknownKeys();
  if (!top.ok()) return std::nullopt;

  CampaignConfig c;
  JsonReader r(body, "campaign", error);
  long long seed = 0;
  r.Integer("seed", &seed, true);
  if (r.ok() && seed < 0) r.Fail("'campaign.seed' must be >= 0");
  c.seed = static_cast<uint64_t>(seed);
  if (r.Has("image") && !ParseImage(r.Get("image"), &c, error)) return std::nullopt;
  if (r.Has("detector") && !ParseDetector(r.Get("detector"), &c, error)) return std::nullopt;
  std::string sampling = model::ToString(c.sampling);
  r.String("sampling", &sampling);
  if (r.ok() && !model::ParseSampling(sampling, &c.sampling)) {
    r.Fail("'campaign.sampling' must be \"integrated\" or \"pixel_centre\" (got \"" + sampling +
           "\")");
  }
  r.Number("airy_radius_px_at_800nm", &c.airy_radius_px_at_800nm);
  if (r.ok() && !(c.airy_radius_px_at_800nm > 0)) {
    r.Fail("'campaign.airy_radius_px_at_800nm' must be > 0");
  }
  if (r.Has("defocus") && !ParseDefocus(r.Get("defocus"), &c, error)) return std::nullopt;
  r.Number("position_jitter_px", &c.position_jitter_px);
  if (r.ok() && !(c.position_jitter_px >= 0 && c.position_jitter_px < 0.5)) {
    r.Fail(
        "'campaign.position_jitter_px' must be within [0, 0.5) (the spot stays on its "
        "pixel)");
  }
  if (r.Has("truth") && !ParseTruth(r.Get("truth"), &c.truth, error)) return std::nullopt;
  c.settings = Table1Settings();
  if (r.Has("settings") && !ParseList<CampaignSetting>(&r, "settings", /*allow_empty=*/false,
                                                       ParseSetting, &c.settings, error)) {
    return std::nullopt;
  }
  if (r.Has("focus_series") && !ParseList<FocusSeries>(&r, "focus_series", /*allow_empty=*/true,
                                                       ParseFocusSeries, &c.focus_series, error)) {
    return std::nullopt;
  }
  r.RejectUnknownKeys();
  if (!r.ok()) return std::nullopt;

  // Cross-key checks.
  if (c.sampling == model::Sampling::kPixelCentre) {
    if (c.defocus_kind != model::DefocusKind::kGaussian) {
      *error =
          "'campaign.defocus.kind' must be \"gaussian\" in pixel_centre sampling (the "
          "2015 code has only a Gaussian defocus)";
      return std::nullopt;
    }
    if (!(c.defocus_px > 0)) {
      *error = "'campaign.defocus.sigma_px' must be > 0 in pixel_centre sampling";
      return std::nullopt;
    }
  }
  for (size_t k = 0; k < c.settings.size(); ++k) {
    const CampaignSetting& s = c.settings[k];
    const std::string path = "campaign.settings[" + std::to_string(k) + "]";
    const FocusSeries* law = nullptr;
    if (s.focus_position_um) {
      law = c.FocusLawFor(s.wavelength_nm);
      if (law == nullptr) {
        *error = "'" + path + ".focus_position_um' needs a focus series at " +
                 CompactNumber(s.wavelength_nm) + " nm, whose law sets the defocus there";
        return std::nullopt;
      }
    }
    if (!CheckGroupDomain(
            c, path, s.wavelength_nm, s.peak_e,
            law ? model::DefocusKind::kGaussian : c.defocus_kind,
            {law ? RenderedFocusDefocusPx(c, law->DefocusSigmaPx(*s.focus_position_um))
                 : c.defocus_px},
            error)) {
      return std::nullopt;
    }
  }
  for (size_t k = 0; k < c.focus_series.size(); ++k) {
    const FocusSeries& f = c.focus_series[k];
    std::vector<double> defocus = {RenderedFocusDefocusPx(c, 0.0)};  // calibration
    for (double z : f.focus_positions_um) {
      defocus.push_back(RenderedFocusDefocusPx(c, f.DefocusSigmaPx(z)));
    }
    if (!CheckGroupDomain(c, "campaign.focus_series[" + std::to_string(k) + "]", f.wavelength_nm,
                          f.peak_e, model::DefocusKind::kGaussian, defocus, error)) {
      return std::nullopt;
    }
  }
  return c;
}

std::optional<CampaignConfig> LoadCampaignConfig(const std::string& path, std::string* error) {
  std::string text;
  if (!ReadTextInput(path, "campaign config", &text, error)) return std::nullopt;
  auto config = ParseCampaignConfig(text, error);
  if (!config) *error = "'" + path + "': " + *error;
  return config;
}

// ---------------------------------------------------------------------------------------
// Planning and running.

std::vector<CampaignGroup> PlanCampaign(const CampaignConfig& c) {
  std::vector<CampaignGroup> groups;
  char index[32];
  for (size_t k = 0; k < c.settings.size(); ++k) {
    const CampaignSetting& s = c.settings[k];
    CHECK_GE(s.exposures, 1);
    const uint64_t group_seed = DeriveSeed(DeriveSeed(c.seed, kSettingsStream), k);
    CampaignGroup g;
    std::snprintf(index, sizeof(index), "g%02zu", k);
    g.name = std::string(index) + "_" + CompactNumber(s.wavelength_nm) + "nm_" +
             CompactNumber(s.peak_e) + "e";
    g.focus_series = false;
    g.source_index = static_cast<int>(k);
    g.wavelength_nm = s.wavelength_nm;
    g.nominal_peak_e = s.peak_e;
    g.exptime_s = s.exptime_s;
    g.simulation = GroupSimulation(c, group_seed, s.wavelength_nm, s.peak_e);
    g.ccd_sigma_x_px = g.simulation.ccd_sigma_x_px;
    g.ccd_sigma_y_px = g.simulation.ccd_sigma_y_px;
    // At a stage position: the Gaussian defocus of the series' law there, for the
    // calibration as for the exposures.
    double nominal = c.defocus_px;
    if (s.focus_position_um) {
      nominal = c.FocusLawFor(s.wavelength_nm)->DefocusSigmaPx(*s.focus_position_um);
      g.simulation.model.defocus = model::DefocusKind::kGaussian;
      g.simulation.defocus_px = RenderedFocusDefocusPx(c, nominal);
    }
    g.intensity_parameter_e =
        CalibrateIntensity(g.simulation, c, s.wavelength_nm, s.exptime_s, s.peak_e);
    std::mt19937_64 jitter(DeriveSeed(group_seed, kJitterStream));
    for (int i = 0; i < s.exposures; ++i) {
      SimulatedExposure e =
          JitteredExposure(c, g.intensity_parameter_e, s.wavelength_nm, s.exptime_s, jitter);
      if (s.focus_position_um) {
        e.focus_position_um = *s.focus_position_um;
        e.defocus_px = g.simulation.defocus_px;
      }
      g.simulation.exposures.push_back(e);
      g.nominal_defocus_px.push_back(nominal);
    }
    groups.push_back(std::move(g));
  }
  for (size_t k = 0; k < c.focus_series.size(); ++k) {
    const FocusSeries& f = c.focus_series[k];
    const uint64_t group_seed = DeriveSeed(DeriveSeed(c.seed, kFocusSeriesStream), k);
    CampaignGroup g;
    std::snprintf(index, sizeof(index), "f%02zu", k);
    g.name = std::string(index) + "_" + CompactNumber(f.wavelength_nm) + "nm_" +
             CompactNumber(f.peak_e) + "e_focus";
    g.focus_series = true;
    g.source_index = static_cast<int>(k);
    g.wavelength_nm = f.wavelength_nm;
    g.nominal_peak_e = f.peak_e;
    g.exptime_s = f.exptime_s;
    g.simulation = GroupSimulation(c, group_seed, f.wavelength_nm, f.peak_e);
    // The series' defocus is Gaussian whatever the campaign's kind; the group default (used
    // for the calibration) is the best focus.
    g.simulation.model.defocus = model::DefocusKind::kGaussian;
    g.simulation.defocus_px = RenderedFocusDefocusPx(c, 0.0);
    g.ccd_sigma_x_px = g.simulation.ccd_sigma_x_px;
    g.ccd_sigma_y_px = g.simulation.ccd_sigma_y_px;
    g.intensity_parameter_e =
        CalibrateIntensity(g.simulation, c, f.wavelength_nm, f.exptime_s, f.peak_e);
    std::mt19937_64 jitter(DeriveSeed(group_seed, kJitterStream));
    for (double z : f.focus_positions_um) {
      for (int i = 0; i < f.exposures_per_position; ++i) {
        SimulatedExposure e =
            JitteredExposure(c, g.intensity_parameter_e, f.wavelength_nm, f.exptime_s, jitter);
        const double nominal = f.DefocusSigmaPx(z);
        e.focus_position_um = z;
        e.defocus_px = RenderedFocusDefocusPx(c, nominal);
        g.simulation.exposures.push_back(e);
        g.nominal_defocus_px.push_back(nominal);
      }
    }
    groups.push_back(std::move(g));
  }
  return groups;
}

bool RunCampaign(const CampaignConfig& c, const std::string& out_dir, bool noiseless,
                 CampaignResult* result, std::string* error) {
  const std::vector<CampaignGroup> groups = PlanCampaign(c);
  // Everything goes to a staging folder first (each group is itself staged by RunSimulation
  // inside it) and is moved into place only when every group succeeded; manifest.json and
  // truth.json last. On failure the staging folder is removed with all it holds.
  StagedOutput out;
  if (!out.Begin(out_dir, error)) return false;
  const bool gaussian = c.defocus_kind == model::DefocusKind::kGaussian;
  json manifest = {{"groups", json::array()}};
  json truth;
  truth["seed"] = c.seed;
  truth["noiseless"] = noiseless;
  truth["sampling"] = model::ToString(c.sampling);
  truth["image"] = {{"nx", c.nx}, {"ny", c.ny}, {"prescan_x", c.prescan_x}};
  truth["detector"] = {{"gain_e_per_adu", c.gain_e_per_adu},
                       {"read_noise_e", c.read_noise_e},
                       {"bias_adu", c.bias_adu},
                       {"pixel_um", c.pixel_um},
                       {"saturation_adu", c.saturation_adu}};
  truth["airy_radius_px_at_800nm"] = c.airy_radius_px_at_800nm;
  truth["defocus"] = {{"kind", model::ToString(c.defocus_kind)},
                      {gaussian ? "sigma_px" : "radius_px", c.defocus_px}};
  truth["position_jitter_px"] = c.position_jitter_px;
  truth["centre_px"] = {c.CentreXPx(), c.CentreYPx()};
  truth["relations"] = RelationsJson(c.truth);
  truth["groups"] = json::array();
  int exposures = 0;
  for (const CampaignGroup& g : groups) {
    SimulationResult sim;
    std::string why;
    if (!RunSimulation(g.simulation, out.Path(g.name), noiseless, &sim, &why)) {
      *error = "campaign group " + g.name + ": " + why;
      return false;
    }
    json files = json::array();
    for (const std::string& path : sim.files) {
      const size_t slash = path.find_last_of('/');
      files.push_back(g.name + "/" + (slash == std::string::npos ? path : path.substr(slash + 1)));
    }
    exposures += static_cast<int>(files.size());
    manifest["groups"].push_back({{"name", g.name},
                                  {"wavelength_nm", g.wavelength_nm},
                                  {"nominal_peak_e", g.nominal_peak_e},
                                  {"exptime_s", g.exptime_s},
                                  {"focus_series", g.focus_series},
                                  {"files", files}});
    const PsfMetrics ccd = GaussianMetrics(g.ccd_sigma_x_px, g.ccd_sigma_y_px, c.pixel_um);
    json gj = {
        {"name", g.name},
        {"focus_series", g.focus_series},
        {"wavelength_nm", g.wavelength_nm},
        {"nominal_peak_e", g.nominal_peak_e},
        {"exptime_s", g.exptime_s},
        {"simulation_seed", g.simulation.seed},
        {"intensity_parameter", c.sampling == model::Sampling::kPixelCentre ? "peak_e" : "flux_e"},
        {"intensity_parameter_e", g.intensity_parameter_e},
        {"airy_radius_px", g.simulation.airy_radius_px},
        {"ccd_sigma_x_px", g.ccd_sigma_x_px},
        {"ccd_sigma_y_px", g.ccd_sigma_y_px},
        {"fwhm_um", ccd.fwhm_um},
        {"fwhm_x_um", ccd.fwhm_x_um},
        {"fwhm_y_um", ccd.fwhm_y_um},
        {"r2_px2", ccd.r2_px2},
        {"ellipticity", ccd.ellipticity}};
    if (!g.focus_series && c.settings[g.source_index].focus_position_um) {
      // At a stage position: the series' Gaussian law gave the defocus.
      gj["defocus_kind"] = "gaussian";
      gj["focus_position_um"] = *c.settings[g.source_index].focus_position_um;
      gj["defocus_sigma_nominal_px"] = g.nominal_defocus_px[0];
      gj["defocus_sigma_px"] = g.simulation.defocus_px;
      gj.update(TotalWidths(model::DefocusKind::kGaussian, g.simulation.defocus_px,
                            g.ccd_sigma_x_px, g.ccd_sigma_y_px, c.pixel_um));
    } else if (!g.focus_series) {
      gj["defocus_kind"] = model::ToString(c.defocus_kind);
      gj[gaussian ? "defocus_sigma_px" : "defocus_radius_px"] = c.defocus_px;
      gj.update(TotalWidths(c.defocus_kind, c.defocus_px, g.ccd_sigma_x_px, g.ccd_sigma_y_px,
                            c.pixel_um));
    } else {
      const FocusSeries& f = c.focus_series[g.source_index];
      gj["defocus_kind"] = "gaussian";
      gj["best_focus_um"] = f.best_focus_um;
      gj["defocus_sigma_px_per_um"] = f.defocus_sigma_px_per_um;
      json ex = json::array();
      for (size_t k = 0; k < g.simulation.exposures.size(); ++k) {
        const SimulatedExposure& e = g.simulation.exposures[k];
        json ej = {{"file", files[k]},
                   {"focus_position_um", e.focus_position_um.value()},
                   {"defocus_sigma_nominal_px", g.nominal_defocus_px[k]},
                   {"defocus_sigma_px", e.defocus_px.value()}};
        ej.update(TotalWidths(model::DefocusKind::kGaussian, e.defocus_px.value(), g.ccd_sigma_x_px,
                              g.ccd_sigma_y_px, c.pixel_um));
        ex.push_back(ej);
      }
      gj["exposures"] = ex;
    }
    truth["groups"].push_back(gj);
  }
  truth["software"] = SoftwareVersions();
  if (!WriteTextFileAtomically(out.Path("manifest.json"), manifest.dump(2) + "\n", error) ||
      !WriteTextFileAtomically(out.Path("truth.json"), truth.dump(2) + "\n", error) ||
      !out.Commit({"manifest.json", "truth.json"}, error)) {
    return false;
  }
  result->groups = static_cast<int>(groups.size());
  result->exposures = exposures;
  result->manifest_path = out_dir + "/manifest.json";
  result->truth_path = out_dir + "/truth.json";
  return true;
}

}  // namespace ccdpsf
