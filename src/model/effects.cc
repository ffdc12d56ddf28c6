#include "ccdpsf/model/effects.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "glog/logging.h"
#include "internal/gauss_legendre.h"
#include "internal/json_reader.h"

namespace ccdpsf::model {

using nlohmann::json;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

EffectParameterInfo Param(const std::string& name, const std::string& unit, double def,
                          double prior_lo, double prior_hi, double dom_lo, bool lo_open,
                          double dom_hi, bool hi_open, const std::string& description, double start,
                          bool null_on_boundary) {
  return {name,   unit,    def,     prior_lo,    prior_hi, dom_lo,
          dom_hi, lo_open, hi_open, description, start,    null_on_boundary};
}

// The catalogue. Defaults are "realistic" strengths for a CCD273 spot at 800 nm, chosen as
// follows (priors are a flat range a few times wider than the plausible values, containing 0
// wherever "no effect" is a value of the parameter):
//
// defocus: sigma 0.41 px, the paper's simulated value (docs/formats.md, Simulation config).
// brighter_fatter: paper section 4.3, 800 nm: FWHM = 6.61 um + 1.14e-5 um/e- x I, for both
//   axes (slopes agree within errors). In pixels of 12 um and with FWHM = 2.3548 sigma:
//   1.14e-5 / 12 / 2.3548 = 4.03e-7 px per e-, so sigma grows by 0.064 px at I = 160 ke-.
//   The prior reaches 5x the paper's slope.
// serial_cti / parallel_cti: f is the total fraction of a pixel's charge found in its trail
//   (for a linear CTI of c per transfer after n transfers, f ~ n c). A CCD273 quadrant has
//   ~2066 rows and ~2048 columns per output, so a spot in the middle of it is ~1000 parallel
//   and ~1000 serial transfers from its output. For a bright (1e5 e-) packet in an
//   unirradiated device, as the paper's, c is of order 1e-6 per transfer: f ~ 1e-3, the
//   default. After the Euclid end-of-life proton fluence c grows to ~1e-5 at such signals
//   (f ~ 1e-2, the prior's upper end). Both are orders of magnitude: c depends on the signal,
//   the temperature, the clocking and the background. Traps with release times of one to a
//   few transfer periods give trails of 1-2 px: 1.5 px (slower traps release their charge far
//   outside a 21 x 21 stamp, where it is a loss of flux, not a trail).
// ipc: interpixel coupling is ~0.5-2 % per neighbour in hybrid CMOS arrays; in a CCD the
//   analogous electrostatic coupling is expected to be smaller, so 1 % is a strong but
//   realistic test injection.
// jitter: the spot moves < 0.1 px between exposures (lab spot data); vibration of the projector
//   within a 2.5 s exposure of a comparable 0.1 px (1.2 um) rms is the assumed default. No
//   motion by default (a linear drift is the alternative).
// background: a bias-subtraction residual of 20 e- (about 6 ADU at 3.1 e-/ADU): a few times
//   the read noise, typical of a bias estimated from a drifting prescan.
// nonlinearity: a CCD output chain is typically linear to a few tenths of a percent up to
//   ~1 % near full well (~200 ke- for the CCD273). beta = 3e-8 / e- puts the response 0.48 %
//   low at the paper's brightest peaks (160 ke-) and 0.6 % at full well: mid-range. (The
//   previous default, 1e-7, was 1.6 % at 160 ke-: the pessimistic end.)
// halo: red light (800-900 nm) penetrates deep into the silicon and is partly reflected from
//   the back, spreading a few % of the light over 2-3 px: fraction 3 %, sigma 2.5 px.
// defocus_offset: a misaligned pinhole image (coma-like) shifting the defocus blur by a
//   fraction of its width: 0.1 px along x.
// boundary_shift: flat-field covariances of thick CCDs give a_00 ~ -1e-6 .. -2.5e-6 per e-
//   (Astier et al. 2019: the variance of flats at 1e5 e- 10-25 % below the Poisson line) with
//   the nearest neighbours holding most of the rest. The CCD273 (40 um of silicon, 12 um
//   pixels) is thinner and coarser than the 100 um, 10 um devices measured there, so its
//   coefficients sit at the lower end: a_10 = 1.5e-7, a_01 = 2e-7 (the parallel boundaries,
//   made by clock barriers, move more than the serial ones, made by channel stops), a_11 =
//   6e-8, a_far = 1.5e-8, so that a_00 = -1.2e-6 and flats at 1.5e5 e- lose ~17 % of their
//   Poisson variance. The priors reach about 5x these. anisotropy: 0 (the potential field);
//   the prior [-0.6, 0.6] lets one kind of boundary yield 4x as much as the other.
std::vector<EffectInfo> MakeCatalogue() {
  const DefocusEffectParams defocus;
  const BrighterFatterParams bf;
  const CtiParams cti;
  const IpcParams ipc;
  const JitterParams jitter;
  const BackgroundParams background;
  const NonlinearityParams nl;
  const HaloParams halo;
  const DefocusOffsetParams offset;
  std::vector<EffectInfo> c;
  c.push_back({EffectKind::kDefocus,
               "defocus",
               "Gaussian (or pillbox) blur of the spot projector out of focus; set in 'model', "
               "never injected",
               false,
               true,
               {Param("sigma_px", "px", defocus.sigma_px, 0.0, 1.5, 0.0, false, kInf, true,
                      "defocus Gaussian sigma (pillbox: radius)", 0.3, true)},
               {{0.2}, {0.5}},
               "defocus is the model's own component (set 'defocus', not an effect)",
               [](const ExposureEffects&) { return false; },
               [](const ExposureEffects&) { return std::vector<double>(); },
               [](const double*, ExposureEffects*) {
                 LOG(FATAL) << "defocus is a SpotParams component, not an effect";
               }});
  c.push_back(
      {EffectKind::kBrighterFatter,
       "brighter_fatter",
       "CCD widths grow linearly with the exposure's peak-pixel signal (paper 4.3)",
       true,
       true,
       {Param("slope_x_px_per_e", "px/e-", bf.slope_x_px_per_e, 0.0, 2.0e-6, 0.0, false, kInf, true,
              "growth of ccd_sigma_x per electron in the peak pixel", 1.0e-7, true),
        Param("slope_y_px_per_e", "px/e-", bf.slope_y_px_per_e, 0.0, 2.0e-6, 0.0, false, kInf, true,
              "growth of ccd_sigma_y per electron in the peak pixel", 1.0e-7, true)},
       {{1.0e-7, 1.0e-7}, {5.0e-7, 5.0e-7}},
       "",
       [](const ExposureEffects& e) { return e.brighter_fatter.has_value(); },
       [](const ExposureEffects& e) {
         return std::vector<double>{e.brighter_fatter->slope_x_px_per_e,
                                    e.brighter_fatter->slope_y_px_per_e};
       },
       [](const double* v, ExposureEffects* e) {
         e->brighter_fatter = BrighterFatterParams{v[0], v[1]};
       }});
  const auto cti_params = [&cti] {
    return std::vector<EffectParameterInfo>{
        Param("trail_fraction", "", cti.trail_fraction, 0.0, 1.0e-2, 0.0, false, 1.0, false,
              "fraction of each pixel's charge moved into its trail", 1.0e-3, true),
        Param("trail_length_px", "px", cti.trail_length_px, 0.2, 10.0, 0.0, true, kInf, true,
              "e-folding length of the trail", 1.5, false)};
  };
  const std::vector<std::vector<double>> cti_starts = {{1.0e-3, 0.6}, {1.0e-3, 1.5}, {1.0e-3, 4.0}};
  c.push_back(
      {EffectKind::kSerialCti, "serial_cti",
       "charge left behind in serial transfer: exponential trail along +x", true, false,
       cti_params(), cti_starts, "",
       [](const ExposureEffects& e) { return e.serial_cti.has_value(); },
       [](const ExposureEffects& e) {
         return std::vector<double>{e.serial_cti->trail_fraction, e.serial_cti->trail_length_px};
       },
       [](const double* v, ExposureEffects* e) {
         e->serial_cti = CtiParams{v[0], v[1]};
       }});
  c.push_back({EffectKind::kParallelCti, "parallel_cti",
               "charge left behind in parallel transfer: exponential trail along +y", true, false,
               cti_params(), cti_starts, "",
               [](const ExposureEffects& e) { return e.parallel_cti.has_value(); },
               [](const ExposureEffects& e) {
                 return std::vector<double>{e.parallel_cti->trail_fraction,
                                            e.parallel_cti->trail_length_px};
               },
               [](const double* v, ExposureEffects* e) {
                 e->parallel_cti = CtiParams{v[0], v[1]};
               }});
  c.push_back({EffectKind::kIpc,
               "ipc",
               "coupling of each pixel to its four edge neighbours (3x3 kernel)",
               true,
               false,
               {Param("alpha", "", ipc.alpha, 0.0, 0.05, 0.0, false, 0.25, true,
                      "fraction of a pixel's charge seen by each edge neighbour", 0.003, true)},
               {{0.002}, {0.01}},
               "",
               [](const ExposureEffects& e) { return e.ipc.has_value(); },
               [](const ExposureEffects& e) { return std::vector<double>{e.ipc->alpha}; },
               [](const double* v, ExposureEffects* e) { e->ipc = IpcParams{v[0]}; }});
  // Jitter's starts: diagnose fits the variances sigma^2 of each exposure's Gaussian part
  // (effect_fit.h), starting at sigma^2 = 0.005, 0.0025 and 0.02 px^2.
  c.push_back(
      {EffectKind::kJitter,
       "jitter",
       "extra blur per exposure: axis-aligned Gaussian and/or linear motion",
       true,
       true,
       {Param("sigma_x_px", "px", jitter.sigma_x_px, 0.0, 1.0, 0.0, false, kInf, true,
              "Gaussian blur sigma along x", std::sqrt(0.005), true),
        Param("sigma_y_px", "px", jitter.sigma_y_px, 0.0, 1.0, 0.0, false, kInf, true,
              "Gaussian blur sigma along y", std::sqrt(0.005), true),
        Param("motion_length_px", "px", jitter.motion_length_px, 0.0, 2.0, 0.0, false, 20.0, false,
              "length of a linear motion during the exposure", 0.0, true),
        Param("motion_angle_deg", "deg", jitter.motion_angle_deg, -90.0, 90.0, -360.0, false, 360.0,
              false, "direction of the motion, from +x towards +y", 0.0, false)},
       {{std::sqrt(0.0025), std::sqrt(0.0025), 0.0, 0.0},
        {std::sqrt(0.02), std::sqrt(0.02), 0.0, 0.0}},
       // Fittable per exposure (fit_model.h): shared, it would be the CCD widths.
       "",
       [](const ExposureEffects& e) { return e.jitter.has_value(); },
       [](const ExposureEffects& e) {
         return std::vector<double>{e.jitter->sigma_x_px, e.jitter->sigma_y_px,
                                    e.jitter->motion_length_px, e.jitter->motion_angle_deg};
       },
       [](const double* v, ExposureEffects* e) {
         e->jitter = JitterParams{v[0], v[1], v[2], v[3]};
       }});
  c.push_back(
      {EffectKind::kBackground,
       "background",
       "pedestal left after bias subtraction (no shot noise)",
       true,
       false,
       {Param("pedestal_e", "e-", background.pedestal_e, -100.0, 100.0, -kInf, true, kInf, true,
              "electrons added to every pixel", 0.0, false)},
       {{0.0}},
       "",
       [](const ExposureEffects& e) { return e.background.has_value(); },
       [](const ExposureEffects& e) { return std::vector<double>{e.background->pedestal_e}; },
       [](const double* v, ExposureEffects* e) { e->background = BackgroundParams{v[0]}; }});
  c.push_back(
      {EffectKind::kNonlinearity,
       "nonlinearity",
       "quadratic response near full well: out = in (1 - beta in)",
       true,
       false,
       {Param("beta_per_e", "1/e-", nl.beta_per_e, 0.0, 5.0e-7, 0.0, false, kInf, true,
              "fractional loss per electron", 3.0e-8, true)},
       {{2.0e-8}, {1.0e-7}},
       "",
       [](const ExposureEffects& e) { return e.nonlinearity.has_value(); },
       [](const ExposureEffects& e) { return std::vector<double>{e.nonlinearity->beta_per_e}; },
       [](const double* v, ExposureEffects* e) { e->nonlinearity = NonlinearityParams{v[0]}; }});
  c.push_back({EffectKind::kHalo,
               "halo",
               "broad Gaussian holding a fraction of the light (red-light diffusion tail)",
               true,
               false,
               {Param("fraction", "", halo.fraction, 0.0, 0.2, 0.0, false, 1.0, false,
                      "fraction of the spot's light moved into the halo", 0.01, true),
                Param("sigma_px", "px", halo.sigma_px, 1.0, 8.0, 0.0, true, kInf, true,
                      "halo Gaussian sigma", 2.5, false)},
               {{0.01, 1.5}, {0.01, 3.0}, {0.01, 5.0}},
               "",
               [](const ExposureEffects& e) { return e.halo.has_value(); },
               [](const ExposureEffects& e) {
                 return std::vector<double>{e.halo->fraction, e.halo->sigma_px};
               },
               [](const double* v, ExposureEffects* e) {
                 e->halo = HaloParams{v[0], v[1]};
               }});
  c.push_back({EffectKind::kDefocusOffset,
               "defocus_offset",
               "defocus kernel centred away from the Airy centre (integrated: exactly a shift)",
               true,
               true,
               {Param("dx_px", "px", offset.dx_px, -0.5, 0.5, -5.0, false, 5.0, false,
                      "defocus-kernel centre minus Airy centre along x", 0.0, false),
                Param("dy_px", "px", offset.dy_px, -0.5, 0.5, -5.0, false, 5.0, false,
                      "defocus-kernel centre minus Airy centre along y", 0.0, false)},
               {{0.0, 0.0}, {0.1, 0.1}, {-0.1, -0.1}},
               "",
               [](const ExposureEffects& e) { return e.defocus_offset.has_value(); },
               [](const ExposureEffects& e) {
                 return std::vector<double>{e.defocus_offset->dx_px, e.defocus_offset->dy_px};
               },
               [](const double* v, ExposureEffects* e) {
                 e->defocus_offset = DefocusOffsetParams{v[0], v[1]};
               }});
  const BoundaryShiftParams shift;
  c.push_back(
      {EffectKind::kBoundaryShift,
       "boundary_shift",
       "brighter-fatter: pixel boundaries moved by the charge already collected (a_ij)",
       true,
       true,
       {Param("a_10", "1/e-", shift.a_10, 0.0, 1.5e-6, -1.0e-4, false, 1.0e-4, false,
              "area gain of the pixel one column over per electron (x lag 1)", 1.0e-7, true),
        Param("a_01", "1/e-", shift.a_01, 0.0, 1.5e-6, -1.0e-4, false, 1.0e-4, false,
              "area gain of the pixel one row over per electron (y lag 1)", 1.0e-7, true),
        Param("a_11", "1/e-", shift.a_11, 0.0, 6.0e-7, -1.0e-4, false, 1.0e-4, false,
              "area gain of the diagonal pixel per electron", 3.0e-8, true),
        Param("a_far", "1/e-", shift.a_far, 0.0, 1.5e-7, -1.0e-4, false, 1.0e-4, false,
              "area gain at lag distance 2 per electron, falling as (2/r)^4 to lag 5", 1.0e-8,
              true),
        Param("anisotropy", "", shift.anisotropy, -0.6, 0.6, -1.0, true, 1.0, true,
              "column boundaries yield (1 + eta), row boundaries (1 - eta); moves no area",
              0.0, false)},
       {{1.0e-7, 1.0e-7, 3.0e-8, 1.0e-8, 0.0}, {3.0e-7, 3.0e-7, 1.0e-7, 3.0e-8, 0.0}},
       "",
       [](const ExposureEffects& e) { return e.boundary_shift.has_value(); },
       [](const ExposureEffects& e) {
         return std::vector<double>{e.boundary_shift->a_10, e.boundary_shift->a_01,
                                    e.boundary_shift->a_11, e.boundary_shift->a_far,
                                    e.boundary_shift->anisotropy};
       },
       [](const double* v, ExposureEffects* e) {
         e->boundary_shift = BoundaryShiftParams{v[0], v[1], v[2], v[3], v[4]};
       }});
  for (size_t i = 0; i < c.size(); ++i) {
    // DescribeEffect indexes the catalogue by kind.
    CHECK_EQ(static_cast<int>(c[i].kind), static_cast<int>(i)) << c[i].name;
    CHECK_LE(static_cast<int>(c[i].parameters.size()), kMaxEffectParameters) << c[i].name;
    for (const std::vector<double>& start : c[i].search_starts) {
      CHECK_EQ(start.size(), c[i].parameters.size()) << c[i].name;
    }
  }
  return c;
}

std::string FormatNumber(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  std::ostringstream s;
  s << v;
  return s.str();
}

std::string DomainText(const EffectParameterInfo& p) {
  return std::string(p.lower_open ? "(" : "[") + FormatNumber(p.domain_lower) + ", " +
         FormatNumber(p.domain_upper) + (p.upper_open ? ")" : "]");
}

// d_{n} = log of the motion-blur error bound of MotionBlurNodeCount (without the flux).
double LogMotionBound(int n, double l_su, double sx, double sy) {
  const double dn = n;
  return 2.0 * dn * std::log(l_su) + 3.0 * std::lgamma(dn + 1.0) -
         2.0 * std::lgamma(2.0 * dn + 1.0) - dn * std::log(2.0) - std::log(2.0 * dn + 1.0) -
         std::log(2.0 * M_PI * sx * sy);
}

}  // namespace

std::string ToString(EffectKind kind) { return DescribeEffect(kind).name; }

bool ParseEffectKind(const std::string& text, EffectKind* kind) {
  for (const EffectInfo& e : EffectCatalogue()) {
    if (text == e.name) {
      *kind = e.kind;
      return true;
    }
  }
  return false;
}

const std::vector<EffectKind>& AllEffectKinds() {
  static const std::vector<EffectKind> kinds = [] {
    std::vector<EffectKind> v;
    for (const EffectInfo& e : EffectCatalogue()) v.push_back(e.kind);
    return v;
  }();
  return kinds;
}

bool ExposureEffects::Has(EffectKind kind) const { return DescribeEffect(kind).present(*this); }

bool ExposureEffects::HasKernelEffects() const {
  for (const EffectInfo& e : EffectCatalogue()) {
    if (e.kernel_effect && e.present(*this)) return true;
  }
  return false;
}

bool ExposureEffects::HasImageEffects() const {
  for (const EffectInfo& e : EffectCatalogue()) {
    if (!e.kernel_effect && e.present(*this)) return true;
  }
  return false;
}

std::vector<EffectKind> ExposureEffects::Kinds() const {
  std::vector<EffectKind> kinds;
  for (EffectKind k : AllEffectKinds()) {
    if (Has(k)) kinds.push_back(k);
  }
  return kinds;
}

const std::vector<EffectInfo>& EffectCatalogue() {
  static const std::vector<EffectInfo> catalogue = MakeCatalogue();
  return catalogue;
}

const EffectInfo& DescribeEffect(EffectKind kind) {
  const int i = static_cast<int>(kind);
  CHECK(i >= 0 && i < kNumEffectKinds) << "unknown EffectKind " << i;
  return EffectCatalogue()[i];
}

std::string FormatEffectCatalogue() {
  std::ostringstream s;
  for (const EffectInfo& e : EffectCatalogue()) {
    s << e.name << " (" << (e.kernel_effect ? "kernel" : "image")
      << (e.injectable ? "" : ", not injectable") << "): " << e.description << "\n";
    for (const EffectParameterInfo& p : e.parameters) {
      s << "    " << p.name << (p.unit.empty() ? "" : " [" + p.unit + "]")
        << "  default " << FormatNumber(p.default_value) << ", prior ["
        << FormatNumber(p.prior_lower) << ", " << FormatNumber(p.prior_upper) << "], domain "
        << DomainText(p) << ": " << p.description << "\n";
    }
  }
  return s.str();
}

json EffectCatalogueJson() {
  json list = json::array();
  for (const EffectInfo& e : EffectCatalogue()) {
    json params = json::array();
    for (const EffectParameterInfo& p : e.parameters) {
      // JSON has no infinity: open-ended domains are given as text only.
      params.push_back({{"name", p.name},
                        {"unit", p.unit},
                        {"default", p.default_value},
                        {"prior", {p.prior_lower, p.prior_upper}},
                        {"domain", DomainText(p)},
                        {"description", p.description}});
    }
    list.push_back({{"name", e.name},
                    {"description", e.description},
                    {"injectable", e.injectable},
                    {"kind", e.kernel_effect ? "kernel" : "image"},
                    {"parameters", params}});
  }
  return list;
}

bool InsideEffectDomain(const EffectParameterInfo& p, double value) {
  const bool low_ok = p.lower_open ? value > p.domain_lower : value >= p.domain_lower;
  const bool high_ok = p.upper_open ? value < p.domain_upper : value <= p.domain_upper;
  return std::isfinite(value) && low_ok && high_ok;
}

bool CheckEffectParameter(EffectKind kind, int index, double value, const std::string& path,
                          std::string* error) {
  const EffectInfo& info = DescribeEffect(kind);
  CHECK_GE(index, 0);
  CHECK_LT(index, static_cast<int>(info.parameters.size()));
  const EffectParameterInfo& p = info.parameters[index];
  if (InsideEffectDomain(p, value)) return true;
  *error = "'" + path + "' must be in " + DomainText(p) + " (got " + FormatNumber(value) + ")";
  return false;
}

std::vector<double> GetEffectParameters(const ExposureEffects& e, EffectKind kind) {
  CHECK(kind == EffectKind::kDefocus || e.Has(kind))
      << "effect " << ToString(kind) << " is not present";
  return DescribeEffect(kind).get(e);
}

bool SetEffectParameters(EffectKind kind, const std::vector<double>& v, ExposureEffects* e,
                         std::string* error) {
  CHECK(kind != EffectKind::kDefocus) << "defocus is a SpotParams component, not an effect";
  const EffectInfo& info = DescribeEffect(kind);
  if (v.size() != info.parameters.size()) {
    *error = "effect '" + info.name + "' has " + std::to_string(info.parameters.size()) +
             " parameters (got " + std::to_string(v.size()) + ")";
    return false;
  }
  for (size_t i = 0; i < v.size(); ++i) {
    if (!CheckEffectParameter(kind, static_cast<int>(i), v[i],
                              info.name + "." + info.parameters[i].name, error)) {
      return false;
    }
  }
  SetEffectParametersUnchecked(kind, v.data(), e);
  return true;
}

void SetEffectParametersUnchecked(EffectKind kind, const double* v, ExposureEffects* e) {
  DescribeEffect(kind).set(v, e);
}

void AddDefaultEffect(EffectKind kind, ExposureEffects* effects) {
  std::vector<double> defaults;
  for (const EffectParameterInfo& p : DescribeEffect(kind).parameters) {
    defaults.push_back(p.default_value);
  }
  std::string error;
  CHECK(SetEffectParameters(kind, defaults, effects, &error)) << error;
}

// ---------------------------------------------------------------------------------------
// Kernel effects.

SpotParams AdjustSpotParams(const ModelOptions& options, const ExposureEffects& effects,
                            const SpotParams& params, double peak_e) {
  SpotParams p = params;
  if (effects.brighter_fatter) {
    p[kCcdSigmaX] += effects.brighter_fatter->slope_x_px_per_e * peak_e;
    p[kCcdSigmaY] += effects.brighter_fatter->slope_y_px_per_e * peak_e;
  }
  if (effects.jitter) {
    p[kCcdSigmaX] = std::hypot(p[kCcdSigmaX], effects.jitter->sigma_x_px);
    p[kCcdSigmaY] = std::hypot(p[kCcdSigmaY], effects.jitter->sigma_y_px);
  }
  if (effects.defocus_offset && options.sampling == Sampling::kIntegrated) {
    // A convolution with a shifted kernel is the unshifted convolution, shifted. (In
    // pixel_centre sampling the renderer centres its F kernel away from the Airy instead:
    // RenderSpotWithKernelEffects.)
    p[kCentreX] += effects.defocus_offset->dx_px;
    p[kCentreY] += effects.defocus_offset->dy_px;
  }
  return p;
}

int MotionBlurNodeCount(double length_px, double angle_deg, double sx_px, double sy_px,
                        double tolerance) {
  CHECK_GE(length_px, 0.0);
  CHECK_GT(sx_px, 0.0);
  CHECK_GT(sy_px, 0.0);
  CHECK_GT(tolerance, 0.0);
  constexpr int kMaxNodes = 4096;
  if (length_px == 0.0) return 1;
  const double theta = angle_deg * M_PI / 180.0;
  const double c = std::cos(theta), s = std::sin(theta);
  const double s_u = std::sqrt(c * c / (sx_px * sx_px) + s * s / (sy_px * sy_px));
  const double l_su = length_px * s_u;
  const double log_tol = std::log(tolerance);
  for (int n = 1; n < kMaxNodes; ++n) {
    if (LogMotionBound(n, l_su, sx_px, sy_px) <= log_tol) return n;
  }
  return kMaxNodes;
}

std::vector<MotionNode> MotionBlurNodes(const JitterParams& jitter, int n) {
  CHECK_GE(n, 1);
  const internal::GaussLegendreRule& rule = internal::GaussLegendre(n);
  const double theta = jitter.motion_angle_deg * M_PI / 180.0;
  const double half = 0.5 * jitter.motion_length_px;
  std::vector<MotionNode> nodes(n);
  for (int i = 0; i < n; ++i) {
    const double t = half * rule.nodes[i];
    nodes[i] = {t * std::cos(theta), t * std::sin(theta), 0.5 * rule.weights[i]};
  }
  if (n == 1) nodes[0].weight = 1.0;  // 0.5 * 2, exactly; stated so it is visibly exact
  return nodes;
}

double BrighterFatterSignal(const SpotRenderer& renderer, const ExposureEffects& effects,
                            const SpotParams& params, const PixelGrid& grid) {
  ExposureEffects without = effects;
  without.brighter_fatter.reset();
  std::vector<double> model(grid.size());
  RenderSpotWithKernelEffects(renderer, without, params, grid, 0.0, model.data());
  return *std::max_element(model.begin(), model.end());
}

void RenderSpotWithKernelEffects(const SpotRenderer& renderer, const ExposureEffects& effects,
                                 const SpotParams& params, const PixelGrid& grid,
                                 double peak_e, double* model, KernelEffectDetails* details,
                                 int motion_nodes) {
  const ModelOptions& options = renderer.options();
  const SpotParams centre = AdjustSpotParams(options, effects, params, peak_e);
  const bool motion = effects.jitter && effects.jitter->motion_length_px > 0.0;
  int n = 1;
  if (motion) {
    n = motion_nodes;
    if (n <= 0) {
      // Total Gaussian smoothing per axis: the Gaussian defocus merges with the CCD kernel
      // (and pixel_centre sampling only has the Gaussian defocus).
      const bool gaussian_defocus = options.defocus == DefocusKind::kGaussian;
      const double f = gaussian_defocus ? centre[kDefocus] : 0.0;
      n = MotionBlurNodeCount(effects.jitter->motion_length_px,
                              effects.jitter->motion_angle_deg,
                              std::hypot(f, centre[kCcdSigmaX]),
                              std::hypot(f, centre[kCcdSigmaY]), options.relative_tolerance);
    }
  }
  // pixel_centre: the defocus offset goes to the renderer (AdjustSpotParams left it out).
  const bool pc_offset = effects.defocus_offset && options.sampling == Sampling::kPixelCentre;
  const double odx = pc_offset ? effects.defocus_offset->dx_px : 0.0;
  const double ody = pc_offset ? effects.defocus_offset->dy_px : 0.0;
  // With boundary_shift, the light along the pixel boundaries and at their corners too, on
  // the grid grown by one pixel below on their axes (ApplyBoundaryShift's layout).
  const bool shift = effects.boundary_shift.has_value();
  const PixelGrid grid_x{grid.nx + 1, grid.ny, grid.x0 - 1.0, grid.y0};
  const PixelGrid grid_y{grid.nx, grid.ny + 1, grid.x0, grid.y0 - 1.0};
  const PixelGrid grid_corner{grid.nx + 1, grid.ny + 1, grid.x0 - 1.0, grid.y0 - 1.0};
  BoundaryDensities densities;
  if (shift) {
    densities.x = {grid_x.nx, grid_x.ny, 0, std::vector<double>(grid_x.size(), 0.0)};
    densities.y = {grid_y.nx, grid_y.ny, 0, std::vector<double>(grid_y.size(), 0.0)};
    densities.corner = {grid_corner.nx, grid_corner.ny, 0,
                        std::vector<double>(grid_corner.size(), 0.0)};
  }
  std::vector<double> one(shift ? grid_corner.size() : grid.size());
  auto add_densities = [&](const SpotParams& p, double weight) {
    renderer.RenderBoundaryDensity(p, grid_x, 0, one.data(), nullptr);
    for (int q = 0; q < grid_x.size(); ++q) densities.x.data[q] += weight * one[q];
    renderer.RenderBoundaryDensity(p, grid_y, 1, one.data(), nullptr);
    for (int q = 0; q < grid_y.size(); ++q) densities.y.data[q] += weight * one[q];
    renderer.RenderCornerDensity(p, grid_corner, one.data(), nullptr);
    for (int q = 0; q < grid_corner.size(); ++q) densities.corner.data[q] += weight * one[q];
  };
  if (n == 1) {
    if (pc_offset) {
      renderer.RenderWithDefocusOffset(centre, odx, ody, grid, model, nullptr);
    } else {
      renderer.Render(centre, grid, model, nullptr);
    }
    if (shift) add_densities(centre, 1.0);
  } else {
    std::fill(model, model + grid.size(), 0.0);
    for (const MotionNode& node : MotionBlurNodes(*effects.jitter, n)) {
      SpotParams p = centre;
      p[kCentreX] += node.dx_px;
      p[kCentreY] += node.dy_px;
      if (pc_offset) {
        renderer.RenderWithDefocusOffset(p, odx, ody, grid, one.data(), nullptr);
      } else {
        renderer.Render(p, grid, one.data(), nullptr);
      }
      for (int q = 0; q < grid.size(); ++q) model[q] += node.weight * one[q];
      if (shift) add_densities(p, node.weight);
    }
  }
  if (shift) {
    DualImage image{grid.nx, grid.ny, 0, std::vector<double>(model, model + grid.size())};
    const int peak = static_cast<int>(std::max_element(model, model + grid.size()) - model);
    ApplyBoundaryShift(*effects.boundary_shift, densities,
                       BoundaryShiftWindow(peak % grid.nx, peak / grid.nx, grid.nx, grid.ny),
                       EffectChannels(), &image);
    std::copy(image.data.begin(), image.data.end(), model);
  }
  if (details != nullptr) {
    details->peak_e = effects.brighter_fatter ? peak_e : 0.0;
    ExposureEffects bf_only;
    bf_only.brighter_fatter = effects.brighter_fatter;
    const SpotParams bf = AdjustSpotParams(options, bf_only, params, peak_e);
    details->ccd_sigma_x_px = bf[kCcdSigmaX];
    details->ccd_sigma_y_px = bf[kCcdSigmaY];
    details->rendered_sigma_x_px = centre[kCcdSigmaX];
    details->rendered_sigma_y_px = centre[kCcdSigmaY];
    details->centre_x_px = centre[kCentreX];
    details->centre_y_px = centre[kCentreY];
    details->defocus_centre_x_px = centre[kCentreX] + odx;
    details->defocus_centre_y_px = centre[kCentreY] + ody;
    details->motion_nodes = n;
  }
}

void RenderSpotWithEffects(const SpotRenderer& renderer, const ExposureEffects& effects,
                           const SpotParams& params, const PixelGrid& grid, double* model,
                           KernelEffectDetails* details) {
  const double peak =
      effects.brighter_fatter ? BrighterFatterSignal(renderer, effects, params, grid) : 0.0;
  RenderSpotWithKernelEffects(renderer, effects, params, grid, peak, model, details);
}

// ---------------------------------------------------------------------------------------
// Configuration.

ExposureEffects EffectsConfig::ForExposure(int k) const {
  ExposureEffects e = common;
  if (!jitter_per_exposure.empty()) {
    CHECK_GE(k, 0);
    CHECK_LT(k, static_cast<int>(jitter_per_exposure.size()));
    e.jitter = jitter_per_exposure[k];
  }
  return e;
}

namespace {

// Reads jitter, whose values may be numbers or per-exposure lists.
bool ParseJitter(const json& object, int num_exposures, EffectsConfig* out,
                 std::string* error) {
  const EffectInfo& info = DescribeEffect(EffectKind::kJitter);
  const int np = static_cast<int>(info.parameters.size());
  // values[p] holds one number (shared) or num_exposures numbers.
  std::vector<std::vector<double>> values(np);
  bool any_list = false, any_motion = false;
  for (int p = 0; p < np; ++p) {
    const EffectParameterInfo& pi = info.parameters[p];
    const std::string path = "effects.jitter." + pi.name;
    if (!object.contains(pi.name)) continue;
    const json& v = object.at(pi.name);
    auto finite = [](const json& x) { return x.is_number() && std::isfinite(x.get<double>()); };
    if (finite(v)) {
      values[p] = {v.get<double>()};
    } else if (v.is_array() && static_cast<int>(v.size()) == num_exposures &&
               std::all_of(v.begin(), v.end(), finite)) {
      for (const json& x : v) values[p].push_back(x.get<double>());
      any_list = true;
    } else {
      *error = "'" + path + "' must be a finite number or a list of " +
               std::to_string(num_exposures) + " finite numbers (one per exposure)";
      return false;
    }
    for (double x : values[p]) {
      if (!CheckEffectParameter(EffectKind::kJitter, p, x, path, error)) return false;
    }
    if (p >= 2) any_motion = true;
  }
  for (auto it = object.begin(); it != object.end(); ++it) {
    bool known = false;
    for (const EffectParameterInfo& pi : info.parameters) known |= pi.name == it.key();
    if (!known) {
      *error = "unknown key 'effects.jitter." + it.key() + "'";
      return false;
    }
  }
  if (object.contains("motion_angle_deg") && !object.contains("motion_length_px")) {
    *error = "'effects.jitter.motion_angle_deg' needs 'effects.jitter.motion_length_px'";
    return false;
  }
  // With a motion, a Gaussian width is only there when asked for.
  const double sigma_default = any_motion ? 0.0 : info.parameters[0].default_value;
  const int count = any_list ? num_exposures : 1;
  std::vector<JitterParams> list(count);
  for (int k = 0; k < count; ++k) {
    double x[4];
    for (int p = 0; p < np; ++p) {
      const double def = p < 2 ? sigma_default : info.parameters[p].default_value;
      x[p] = values[p].empty() ? def : values[p][values[p].size() == 1 ? 0 : k];
    }
    list[k] = JitterParams{x[0], x[1], x[2], x[3]};
  }
  if (any_list) {
    out->jitter_per_exposure = list;
    out->common.jitter.reset();
  } else {
    out->common.jitter = list[0];
  }
  return true;
}

}  // namespace

bool ParseEffectsConfig(const json& effects, int num_exposures, Sampling sampling,
                        EffectsConfig* out, std::string* error) {
  if (!effects.is_object()) {
    *error = "'effects' must be a JSON object of effects by catalogue name";
    return false;
  }
  EffectsConfig config;
  for (auto it = effects.begin(); it != effects.end(); ++it) {
    const std::string path = "effects." + it.key();
    EffectKind kind;
    if (!ParseEffectKind(it.key(), &kind)) {
      std::string names;
      for (const EffectInfo& e : EffectCatalogue()) {
        if (e.injectable) names += (names.empty() ? "" : ", ") + e.name;
      }
      *error = "unknown effect '" + path + "' (injectable effects: " + names + ")";
      return false;
    }
    if (kind == EffectKind::kDefocus) {
      *error = "'effects.defocus' cannot be injected: the simulated defocus is the model's own, "
               "set in 'model.defocus' (and per exposure with 'defocus_px')";
      return false;
    }
    if (!it.value().is_object()) {
      *error = "'" + path + "' must be a JSON object of parameters ({} for the defaults)";
      return false;
    }
    if (kind == EffectKind::kBoundaryShift && sampling != Sampling::kIntegrated) {
      *error = "'" + path + "' needs \"sampling\": \"integrated\": boundaries move in the pixel "
               "integral, and the 2015 pixel_centre model samples points";
      return false;
    }
    if (kind == EffectKind::kBoundaryShift && config.common.brighter_fatter) {
      *error = "'" + path + "' and 'effects.brighter_fatter' are two descriptions of one effect: "
               "inject one";
      return false;
    }
    if (kind == EffectKind::kBrighterFatter && config.common.boundary_shift) {
      *error = "'" + path + "' and 'effects.boundary_shift' are two descriptions of one effect: "
               "inject one";
      return false;
    }

    if (kind == EffectKind::kJitter) {
      if (!ParseJitter(it.value(), num_exposures, &config, error)) return false;
      continue;
    }
    const EffectInfo& info = DescribeEffect(kind);
    internal::JsonReader r(it.value(), path, error);
    std::vector<double> values;
    for (const EffectParameterInfo& p : info.parameters) {
      double v = p.default_value;
      r.Number(p.name, &v);
      values.push_back(v);
    }
    r.RejectUnknownKeys();
    if (!r.ok()) return false;
    for (size_t p = 0; p < values.size(); ++p) {
      if (!CheckEffectParameter(kind, static_cast<int>(p), values[p],
                                path + "." + info.parameters[p].name, error)) {
        return false;
      }
    }
    CHECK(SetEffectParameters(kind, values, &config.common, error)) << *error;
  }
  *out = std::move(config);
  return true;
}

json EffectsConfigToJson(const EffectsConfig& config) {
  json out = json::object();
  ExposureEffects e = config.common;
  if (!config.jitter_per_exposure.empty()) e.jitter = config.jitter_per_exposure.front();
  for (EffectKind kind : e.Kinds()) {
    const EffectInfo& info = DescribeEffect(kind);
    const std::vector<double> values = GetEffectParameters(e, kind);
    json params = json::object();
    for (size_t p = 0; p < values.size(); ++p) {
      if (kind == EffectKind::kJitter && !config.jitter_per_exposure.empty()) {
        json list = json::array();
        for (const JitterParams& j : config.jitter_per_exposure) {
          ExposureEffects one;
          one.jitter = j;
          list.push_back(GetEffectParameters(one, kind)[p]);
        }
        params[info.parameters[p].name] = list;
      } else {
        params[info.parameters[p].name] = values[p];
      }
    }
    out[info.name] = params;
  }
  return out;
}

}  // namespace ccdpsf::model
