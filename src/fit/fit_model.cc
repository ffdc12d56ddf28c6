#include "ccdpsf/fit/fit_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <sstream>

#include "glog/logging.h"

namespace ccdpsf::fit {
namespace {

using model::SpotParam;

CcdNoise NoiseOf(const Stamp& s) {
  CcdNoise noise;
  noise.gain_e_per_adu = s.gain_e_per_adu;
  noise.read_noise_e = s.read_noise_e;
  return noise;
}

}  // namespace

bool ParseFluxMode(const std::string& text, FluxMode* mode) {
  if (text == "shared") {
    *mode = FluxMode::kShared;
  } else if (text == "per_exposure") {
    *mode = FluxMode::kPerExposure;
  } else if (text == "exptime_scaled") {
    *mode = FluxMode::kExptimeScaled;
  } else {
    return false;
  }
  return true;
}

std::string ToString(FluxMode mode) {
  switch (mode) {
    case FluxMode::kShared:
      return "shared";
    case FluxMode::kPerExposure:
      return "per_exposure";
    case FluxMode::kExptimeScaled:
      return "exptime_scaled";
  }
  return "shared";
}

bool IsFittableEffect(model::EffectKind kind, std::string* why) {
  *why = model::DescribeEffect(kind).not_fittable;
  return why->empty();
}

std::string FittableEffectNames(const std::string& separator,
                                const std::vector<model::EffectKind>& except) {
  std::string names;
  for (model::EffectKind kind : model::AllEffectKinds()) {
    std::string why;
    if (!IsFittableEffect(kind, &why)) continue;
    if (std::find(except.begin(), except.end(), kind) != except.end()) continue;
    names += (names.empty() ? "" : separator) + model::ToString(kind);
  }
  return names;
}

bool EffectsFitInSampling(const FitModelOptions& options, std::string* error) {
  if (options.HasEffect(model::EffectKind::kDefocusOffset) &&
      options.model.sampling != model::Sampling::kPixelCentre) {
    *error = "effect 'defocus_offset' cannot be fitted in " +
             model::ToString(options.model.sampling) +
             " sampling: there it is exactly a shift of the spot (the positions absorb it); it "
             "is a component of the 2015 pixel_centre model only";
    return false;
  }
  if (options.HasEffect(model::EffectKind::kBoundaryShift)) {
    if (options.model.sampling != model::Sampling::kIntegrated ||
        options.model.pixel_response_width != 1.0) {
      *error = "effect 'boundary_shift' needs integrated sampling with the whole pixel "
               "collecting: boundaries move in the pixel integral, and the 2015 pixel_centre "
               "model samples points";
      return false;
    }
    if (options.HasEffect(model::EffectKind::kBrighterFatter)) {
      *error = "effects 'boundary_shift' and 'brighter_fatter' are two descriptions of one "
               "effect (the physics and the paper's empirical law): fit one";
      return false;
    }
  }
  return true;
}

bool FitModelOptions::HasEffect(model::EffectKind kind) const {
  for (const FitEffect& e : effects) {
    if (e.kind == kind) return true;
  }
  return false;
}

std::string SignalDependenceModelled(const FitModelOptions& options) {
  std::string names;
  for (const model::EffectKind kind :
       {model::EffectKind::kBrighterFatter, model::EffectKind::kNonlinearity,
        model::EffectKind::kBoundaryShift}) {
    if (!options.HasEffect(kind)) continue;
    names += (names.empty() ? "" : " and ") + model::ToString(kind);
  }
  return names.empty() ? "" : "the model fits " + names;
}

FitModelOptions SingleExposureOptions(const FitModelOptions& options) {
  FitModelOptions single = options;
  single.effects.erase(
      std::remove_if(single.effects.begin(), single.effects.end(),
                     [](const FitEffect& e) { return e.kind == model::EffectKind::kJitter; }),
      single.effects.end());
  single.jitter_reference = -1;
  return single;
}

bool CcdSplitUnidentified(const FitModelOptions& options) {
  return options.model.sampling == model::Sampling::kIntegrated &&
         options.model.defocus == model::DefocusKind::kGaussian && !options.through_focus;
}

bool IsFocusSeries(const std::vector<Stamp>& stamps, std::string* why) {
  for (size_t k = 0; k < stamps.size(); ++k) {
    if (!std::isfinite(stamps[k].info.focus_position_um)) {
      *why = "exposure " + std::to_string(k) +
             (stamps[k].info.source.empty() ? "" : " ('" + stamps[k].info.source + "')") +
             " has no focus position (FOCUSPOS keyword)";
      return false;
    }
  }
  const int distinct = static_cast<int>(DistinctFocusPositions(stamps).size());
  if (distinct < 3) {
    *why = "the exposures have " + std::to_string(distinct) +
           " distinct focus position(s) (FOCUSPOS); a through-focus series needs at least 3";
    return false;
  }
  return true;
}

std::unique_ptr<FitModel> FitModel::Create(std::vector<Stamp> stamps,
                                           const FitModelOptions& options, std::string* error) {
  if (stamps.empty()) {
    *error = "no exposures to fit";
    return nullptr;
  }
  if (options.model.sampling == model::Sampling::kPixelCentre &&
      options.model.defocus != model::DefocusKind::kGaussian) {
    *error = "pixel_centre sampling has only the Gaussian defocus of the 2015 code";
    return nullptr;
  }
  if (options.model.pixel_response_width != 1.0 &&
      options.model.sampling != model::Sampling::kIntegrated) {
    *error =
        "pixel_response_width < 1 (a window narrower than the pixel) needs integrated sampling";
    return nullptr;
  }
  if (options.through_focus &&
      (options.model.sampling != model::Sampling::kIntegrated ||
       options.model.defocus != model::DefocusKind::kGaussian)) {
    *error = "through_focus needs integrated sampling and a Gaussian defocus (got " +
             model::ToString(options.model.sampling) + " sampling, " +
             model::ToString(options.model.defocus) + " defocus)";
    return nullptr;
  }
  if (options.through_focus) {
    std::string why;
    if (!IsFocusSeries(stamps, &why)) {
      *error = "through_focus: " + why;
      return nullptr;
    }
  }
  for (size_t k = 0; k < stamps.size(); ++k) {
    const Stamp& s = stamps[k];
    const std::string what = "exposure " + std::to_string(k) +
                             (s.info.source.empty() ? "" : " ('" + s.info.source + "')");
    if (s.nx() != stamps[0].nx() || s.ny() != stamps[0].ny()) {
      std::ostringstream m;
      m << what << " has a " << s.nx() << "x" << s.ny() << " stamp, exposure 0 has "
        << stamps[0].nx() << "x" << stamps[0].ny() << ": a joint fit needs one stamp size";
      *error = m.str();
      return nullptr;
    }
    if (s.valid.size() != s.electrons.size()) {
      *error = what + ": mask and image sizes differ";
      return nullptr;
    }
    if (s.NumValid() == 0) {
      *error = what + ": every pixel of the stamp is masked";
      return nullptr;
    }
    if (!(s.gain_e_per_adu > 0) || !(s.read_noise_e >= 0)) {
      *error = what + ": gain must be > 0 and read noise >= 0";
      return nullptr;
    }
  }
  std::unique_ptr<FitModel> m(new FitModel());
  m->stamps_ = std::move(stamps);
  m->options_ = options;
  const PriorRanges& pr = options.priors;
  const bool peak = options.model.sampling == model::Sampling::kPixelCentre;
  const bool pillbox = options.model.defocus == model::DefocusKind::kPillbox;
  const bool focus = options.through_focus;
  m->names_ = {peak ? "peak_e" : "flux_e", "airy_radius_px",
               focus     ? "defocus_rate_px_per_um"
               : pillbox ? "defocus_radius_px"
                         : "defocus_sigma_px",
               "ccd_sigma_x_px", "ccd_sigma_y_px"};

  // Signal and centroid of each stamp: first moments of the positive signal in a 5 x 5 box
  // around the brightest valid pixel.
  double signal_sum = 0.0;
  for (size_t k = 0; k < m->stamps_.size(); ++k) {
    const Stamp& s = m->stamps_[k];
    int bx = -1, by = -1;
    double best = -INFINITY, total = 0.0;
    for (int y = 0; y < s.ny(); ++y) {
      for (int x = 0; x < s.nx(); ++x) {
        if (!s.valid[y * s.nx() + x]) continue;
        const double v = s.electrons(x, y);
        total += v;
        if (v > best) {
          best = v;
          bx = x;
          by = y;
        }
      }
    }
    const double noise_e = std::sqrt(NoiseOf(s).VarianceE2(0.0));
    if (!(best > 5.0 * noise_e) || !(total > 0)) {
      std::ostringstream msg;
      msg << "exposure " << k << (s.info.source.empty() ? "" : " ('" + s.info.source + "')")
          << " has no spot to fit: brightest pixel " << best << " e- against " << noise_e
          << " e- of noise";
      *error = msg.str();
      return nullptr;
    }
    double w = 0, wx = 0, wy = 0;
    for (int y = std::max(0, by - 2); y <= std::min(s.ny() - 1, by + 2); ++y) {
      for (int x = std::max(0, bx - 2); x <= std::min(s.nx() - 1, bx + 2); ++x) {
        if (!s.valid[y * s.nx() + x]) continue;
        const double v = std::max(0.0, s.electrons(x, y));
        w += v;
        wx += v * x;
        wy += v * y;
      }
    }
    m->centroid_x_.push_back(s.origin_x + wx / w);
    m->centroid_y_.push_back(s.origin_y + wy / w);
    // boundary_shift's window around the spot, fixed per exposure so that the model stays
    // smooth in theta (model/boundary_shift.h).
    m->shift_window_.push_back(model::BoundaryShiftWindow(
        static_cast<int>(std::lround(wx / w)), static_cast<int>(std::lround(wy / w)), s.nx(),
        s.ny()));
    m->signal_per_stamp_e_.push_back(total);
    signal_sum += total;
  }
  m->signal_e_ = signal_sum / m->stamps_.size();

  // Fixed flux scales: exposure-time ratios when the flux follows the exposure time.
  m->fixed_flux_scale_.assign(m->stamps_.size(), 1.0);
  if (options.flux == FluxMode::kExptimeScaled) {
    const double t0 = m->stamps_[0].info.exptime_s;
    for (size_t k = 0; k < m->stamps_.size(); ++k) {
      const double t = m->stamps_[k].info.exptime_s;
      if (!(std::isfinite(t) && t > 0 && std::isfinite(t0) && t0 > 0)) {
        *error = "flux scaled by exposure time needs a positive exposure time on every "
                 "exposure; exposure " + std::to_string(k) +
                 (m->stamps_[k].info.source.empty() ? "" : " ('" + m->stamps_[k].info.source + "')") +
                 " has none (give --exptime_s, a manifest column exptime_s or EXPTIME)";
        return nullptr;
      }
      m->fixed_flux_scale_[k] = t / t0;
    }
  }

  // Flux bounds: around the summed signal for the total flux; the 2015 meta-parameter m has
  // no simple relation to it (the model is unnormalised), so its range is wide. flux_e is
  // exposure 0's flux when the fluxes differ between exposures.
  const double s_e = options.flux == FluxMode::kShared ? m->signal_e_ : m->signal_per_stamp_e_[0];
  m->lower_ = {peak ? 1e-4 * s_e : pr.flux_lower_fraction * s_e, pr.airy_radius_px[0],
               pr.defocus_px[0], pr.ccd_sigma_x_px[0], pr.ccd_sigma_y_px[0]};
  m->upper_ = {peak ? 1e4 * s_e : pr.flux_upper_fraction * s_e, pr.airy_radius_px[1],
               pr.defocus_px[1], pr.ccd_sigma_x_px[1], pr.ccd_sigma_y_px[1]};
  // The 2015 model divides by sigma_f: keep it away from zero.
  if (peak) m->lower_[kDefocusPx] = std::max(m->lower_[kDefocusPx], 0.02);
  for (int k = 0; k < m->num_exposures(); ++k) {
    m->names_.push_back("x_px_" + std::to_string(k));
    m->names_.push_back("y_px_" + std::to_string(k));
    m->lower_.push_back(m->centroid_x_[k] - pr.position_halfwidth_px);
    m->upper_.push_back(m->centroid_x_[k] + pr.position_halfwidth_px);
    m->lower_.push_back(m->centroid_y_[k] - pr.position_halfwidth_px);
    m->upper_.push_back(m->centroid_y_[k] + pr.position_halfwidth_px);
  }
  if (focus) {
    // Rate: the prior's largest defocus reached half the scanned range from best focus;
    // best focus inside the scanned range (fit_model.h).
    double z_min = INFINITY, z_max = -INFINITY;
    for (const Stamp& s : m->stamps_) {
      z_min = std::min(z_min, s.info.focus_position_um);
      z_max = std::max(z_max, s.info.focus_position_um);
    }
    m->lower_[kDefocusPx] = 0.0;
    m->upper_[kDefocusPx] = pr.defocus_px[1] / (0.5 * (z_max - z_min));
    m->names_.push_back("best_focus_um");
    m->lower_.push_back(z_min);
    m->upper_.push_back(z_max);
  }
  if (options.flux == FluxMode::kPerExposure) {
    // flux_ratio_k: exposure k's flux over exposure 0's, within the flux prior's factors of
    // the ratio of their summed signals.
    for (int k = 1; k < m->num_exposures(); ++k) {
      const double ratio = m->signal_per_stamp_e_[k] / m->signal_per_stamp_e_[0];
      m->names_.push_back("flux_ratio_" + std::to_string(k));
      m->lower_.push_back(pr.flux_lower_fraction * ratio);
      m->upper_.push_back(pr.flux_upper_fraction * ratio);
    }
  }
  m->effect_index_.fill(-1);
  if (!EffectsFitInSampling(options, error)) return nullptr;
  for (const FitEffect& e : options.effects) {
    std::string why;
    if (!IsFittableEffect(e.kind, &why)) {
      *error = "effect '" + model::ToString(e.kind) + "' cannot be fitted: " + why;
      return nullptr;
    }
    if (std::count_if(options.effects.begin(), options.effects.end(),
                      [&](const FitEffect& o) { return o.kind == e.kind; }) > 1) {
      *error = "effect '" + model::ToString(e.kind) + "' is given twice";
      return nullptr;
    }
    const int np = static_cast<int>(model::DescribeEffect(e.kind).parameters.size());
    if (!e.priors.empty() && static_cast<int>(e.priors.size()) != np) {
      *error = "effect '" + model::ToString(e.kind) + "' has " + std::to_string(np) +
               " parameters, its priors give " + std::to_string(e.priors.size());
      return nullptr;
    }
  }
  if (options.HasEffect(model::EffectKind::kJitter)) {
    if (m->num_exposures() < 2) {
      *error =
          "jitter needs two or more exposures: one exposure's jitter is exactly a change of "
          "its CCD widths";
      return nullptr;
    }
    if (options.jitter_reference >= m->num_exposures()) {
      *error = "jitter reference exposure " + std::to_string(options.jitter_reference) +
               " is out of range";
      return nullptr;
    }
    m->jitter_reference_ =
        options.jitter_reference >= 0 ? options.jitter_reference : SharpestExposure(*m);
    m->jitter_index_.assign(m->num_exposures(), -1);
  }
  for (model::EffectKind kind : model::AllEffectKinds()) {
    const auto it = std::find_if(options.effects.begin(), options.effects.end(),
                                 [&](const FitEffect& e) { return e.kind == kind; });
    if (it == options.effects.end()) continue;
    const model::EffectInfo& info = model::DescribeEffect(kind);
    m->effect_index_[static_cast<int>(kind)] = m->dim();
    if (kind == model::EffectKind::kJitter) {
      // Per exposure but the reference: the variances of the Gaussian part (sigma_x_px,
      // sigma_y_px; motion is not fitted), on the sigmas' prior ranges squared, starting at the
      // catalogue's start squared.
      double lo[2], hi[2], start[2];
      for (int axis = 0; axis < 2; ++axis) {
        const model::EffectParameterInfo& pi = info.parameters[axis];
        lo[axis] = it->priors.empty() ? pi.prior_lower : it->priors[axis][0];
        hi[axis] = it->priors.empty() ? pi.prior_upper : it->priors[axis][1];
        for (const double v : {lo[axis], hi[axis]}) {
          if (!model::CheckEffectParameter(kind, axis, v, "prior of jitter." + pi.name, error)) {
            return nullptr;
          }
        }
        start[axis] = std::clamp(pi.start, lo[axis], hi[axis]);
      }
      for (int k = 0; k < m->num_exposures(); ++k) {
        if (k == m->jitter_reference_) continue;
        m->jitter_index_[k] = m->dim();
        for (int axis = 0; axis < 2; ++axis) {
          m->names_.push_back(std::string("jitter.var_") + (axis == 0 ? "x" : "y") + "_px2." +
                              std::to_string(k));
          m->lower_.push_back(lo[axis] * lo[axis]);
          m->upper_.push_back(hi[axis] * hi[axis]);
          m->effect_start_.push_back(start[axis] * start[axis]);
        }
      }
      continue;
    }
    for (size_t p = 0; p < info.parameters.size(); ++p) {
      const model::EffectParameterInfo& pi = info.parameters[p];
      const double lo = it->priors.empty() ? pi.prior_lower : it->priors[p][0];
      const double hi = it->priors.empty() ? pi.prior_upper : it->priors[p][1];
      const std::string name = info.name + "." + pi.name;
      for (const double v : {lo, hi}) {
        if (!model::CheckEffectParameter(kind, static_cast<int>(p), v, "prior of " + name, error)) {
          return nullptr;
        }
      }
      m->names_.push_back(name);
      m->lower_.push_back(lo);
      m->upper_.push_back(hi);
      // "No effect" where the prior holds it; else the realistic strength, clamped.
      const double start = lo <= 0.0 && hi >= 0.0 && pi.domain_lower <= 0.0 && !pi.lower_open
                               ? 0.0
                               : std::clamp(pi.default_value, lo, hi);
      m->effect_start_.push_back(start);
    }
  }
  for (int i = 0; i < m->dim(); ++i) {
    if (!(m->lower_[i] < m->upper_[i])) {
      *error = "empty prior range for " + m->names_[i];
      return nullptr;
    }
  }
  if (!m->gaussian_prior_.Bind(options.gaussian_prior, m->names_, error)) return nullptr;
  return m;
}

std::vector<double> FitModel::PosteriorInformation(std::vector<double> fisher) const {
  if (gaussian_prior_.active()) gaussian_prior_.AddPrecision(&fisher, dim());
  return fisher;
}

int FitModel::NumValidPixels() const {
  int n = 0;
  for (const Stamp& s : stamps_) n += s.NumValid();
  return n;
}

int FitModel::NumMeasuredPixels() const {
  int n = 0;
  for (const Stamp& s : stamps_) n += s.NumValid() - s.NumCensored();
  return n;
}

bool EffectsIdentifiable(const FitModel& model, std::string* why) {
  if (model.EffectIndex(model::EffectKind::kBrighterFatter) < 0) return true;
  double lo = INFINITY, hi = 0.0;
  for (int k = 0; k < model.num_exposures(); ++k) {
    const double s = model.StartFluxRatio(k);  // summed signal over exposure 0's
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  }
  if (hi > 1.25 * lo) return true;
  char text[300];
  std::snprintf(text, sizeof text,
                "brighter_fatter needs exposures at two or more intensities (the summed signals "
                "here span x%.3g, at most x1.25): at one intensity its slope is exactly a change "
                "of the CCD widths",
                hi / lo);
  *why = text;
  return false;
}

int FitModel::EffectSize(model::EffectKind kind) const {
  if (EffectIndex(kind) < 0) return 0;
  if (kind == model::EffectKind::kJitter) return 2 * (num_exposures() - 1);
  return static_cast<int>(model::DescribeEffect(kind).parameters.size());
}

int SharpestExposure(const FitModel& model) {
  const std::vector<double> v = model.MomentGaussianVariances(0.5);
  return static_cast<int>(std::min_element(v.begin(), v.end()) - v.begin());
}

bool FitModel::EffectsAt(const double* theta, model::ExposureEffects* effects) const {
  *effects = model::ExposureEffects();
  for (const FitEffect& e : options_.effects) {
    // Jitter differs per exposure: ModelImageColumns draws it into the CCD widths.
    if (e.kind == model::EffectKind::kJitter) continue;
    const int first = EffectIndex(e.kind);
    const std::vector<model::EffectParameterInfo>& parameters =
        model::DescribeEffect(e.kind).parameters;
    // The domain check without building the error message a full check would (this runs on
    // every evaluation; theta is normally inside the prior box, which lies in the domain).
    for (size_t j = 0; j < parameters.size(); ++j) {
      if (!model::InsideEffectDomain(parameters[j], theta[first + j])) return false;
    }
    model::SetEffectParametersUnchecked(e.kind, theta + first, effects);
  }
  return true;
}

void FitModel::SetEffectStart(double* theta) const {
  if (effect_start_.empty()) return;
  const int first = dim() - static_cast<int>(effect_start_.size());
  std::copy(effect_start_.begin(), effect_start_.end(), theta + first);
}

double FitModel::FluxScale(const double* theta, int k) const {
  const int r = RatioIndex(k);
  return fixed_flux_scale_[k] * (r >= 0 ? theta[r] : 1.0);
}

bool FitModel::InsidePrior(const double* theta) const {
  for (int i = 0; i < dim(); ++i) {
    if (!(theta[i] >= lower_[i] && theta[i] <= upper_[i])) return false;
  }
  return true;
}

std::vector<int> FitModel::SharedIndices() const {
  std::vector<int> out;
  for (int i = 0; i < kNumShared; ++i) out.push_back(i);
  for (int i = kNumShared + 2 * num_exposures(); i < dim(); ++i) out.push_back(i);
  return out;
}

double FitModel::DefocusFor(const double* theta, int k, double* d_rate, double* d_z0) const {
  if (!through_focus()) {
    if (d_rate != nullptr) *d_rate = 0.0;
    if (d_z0 != nullptr) *d_z0 = 0.0;
    return theta[kDefocusPx];
  }
  const double rate = theta[kDefocusPx];
  const double dz = FocusPositionUm(k) - theta[FocusIndex()];
  // sigma_f = rate |dz|: d/d rate = |dz|, d/d z0 = -rate sign(dz) (sign(0) = 0).
  if (d_rate != nullptr) *d_rate = std::fabs(dz);
  if (d_z0 != nullptr) *d_z0 = dz > 0 ? -rate : dz < 0 ? rate : 0.0;
  return rate * std::fabs(dz);
}

model::SpotParams FitModel::SpotFor(const double* theta, int k) const {
  model::SpotParams p;
  p[model::kFlux] = theta[kFluxE] * FluxScale(theta, k);
  p[model::kAiryRadius] = theta[kAiryRadiusPx];
  p[model::kDefocus] = DefocusFor(theta, k);
  p[model::kCcdSigmaX] = theta[kCcdSigmaXPx];
  p[model::kCcdSigmaY] = theta[kCcdSigmaYPx];
  p[model::kCentreX] = theta[XIndex(k)];
  p[model::kCentreY] = theta[YIndex(k)];
  if (options_.model.sampling == model::Sampling::kPixelCentre) {
    p[model::kCentreX] -= stamps_[k].origin_x;
    p[model::kCentreY] -= stamps_[k].origin_y;
  }
  return p;
}

model::PixelGrid FitModel::GridFor(int k) const {
  model::PixelGrid g;
  g.nx = stamps_[k].nx();
  g.ny = stamps_[k].ny();
  if (options_.model.sampling == model::Sampling::kIntegrated) {
    g.x0 = stamps_[k].origin_x;
    g.y0 = stamps_[k].origin_y;
  }
  return g;
}

std::vector<double> FitModel::MomentGaussianVariances(double airy_radius_px) const {
  // Width of the signal from second moments in a 5 x 5 box about the centroid, less the
  // pixel (1/12 px^2) and the Airy core (a Gaussian of sigma ~ 0.34 r has the same FWHM).
  const double airy_sigma = 0.34 * airy_radius_px;
  std::vector<double> out;
  for (int k = 0; k < num_exposures(); ++k) {
    const Stamp& s = stamps_[k];
    const double cx = centroid_x_[k] - s.origin_x, cy = centroid_y_[k] - s.origin_y;
    double w = 0, wxx = 0, wyy = 0;
    const int x0 = static_cast<int>(std::lround(cx)), y0 = static_cast<int>(std::lround(cy));
    for (int y = std::max(0, y0 - 2); y <= std::min(s.ny() - 1, y0 + 2); ++y) {
      for (int x = std::max(0, x0 - 2); x <= std::min(s.nx() - 1, x0 + 2); ++x) {
        if (!s.valid[y * s.nx() + x]) continue;
        const double v = std::max(0.0, s.electrons(x, y));
        w += v;
        wxx += v * (x - cx) * (x - cx);
        wyy += v * (y - cy) * (y - cy);
      }
    }
    out.push_back(0.5 * (wxx + wyy) / w - 1.0 / 12.0 - airy_sigma * airy_sigma);
  }
  return out;
}

std::vector<double> FitModel::MomentStart(double airy_radius_px, double defocus_share) const {
  const std::vector<double> variances = MomentGaussianVariances(airy_radius_px);
  double gauss_var = 0.0;
  for (double v : variances) gauss_var += v / num_exposures();
  gauss_var = std::clamp(gauss_var, 0.15 * 0.15, 1.2 * 1.2);
  const double sg = std::sqrt(gauss_var);
  std::vector<double> theta(dim());
  theta[kAiryRadiusPx] = airy_radius_px;
  theta[kDefocusPx] = std::sqrt(defocus_share) * sg;
  theta[kCcdSigmaXPx] = theta[kCcdSigmaYPx] = std::max(0.06, std::sqrt(1 - defocus_share) * sg);
  for (int k = 0; k < num_exposures(); ++k) {
    theta[XIndex(k)] = centroid_x_[k];
    theta[YIndex(k)] = centroid_y_[k];
  }
  if (through_focus()) {
    // A crude focus start (map_fit.cc builds better ones): best focus mid-range, the mean
    // defocus reached at the mean distance from it, a quarter of the range.
    const int f = FocusIndex();
    theta[f] = 0.5 * (lower_[f] + upper_[f]);
    theta[kDefocusPx] /= 0.25 * (upper_[f] - lower_[f]);
  }
  // Per-exposure flux ratios: those of the summed signals.
  for (int k = 1; k < num_exposures(); ++k) {
    if (RatioIndex(k) >= 0) {
      theta[RatioIndex(k)] = StartFluxRatio(k);
    }
  }
  SetEffectStart(theta.data());
  // Flux: the least-squares scale of the model to the data, clamped into the prior (the
  // mean summed signal where that fails).
  theta[kFluxE] = signal_e_;
  for (int i : SharedIndices()) theta[i] = std::clamp(theta[i], lower_[i], upper_[i]);
  FitEvaluator(*this).BestFluxLogLikelihood(theta.data(), 0, num_exposures());
  return theta;
}

std::unique_ptr<FitEvaluator> FitModel::NewEvaluator() const {
  return std::make_unique<FitEvaluator>(*this);
}

FitEvaluator::FitEvaluator(const FitModel& model)
    : fit_model_(model), renderer_(model.options().model) {}

int FitEvaluator::RenderWithoutGrowth(const model::SpotParams& spot, const model::PixelGrid& grid,
                                      const model::ExposureEffects& effects, bool want) {
  std::string why;
  if (!model::ValidSpotParams(renderer_.options(), spot, &why)) return -1;
  plain_.resize(grid.size());
  if (want) spot_jacobian_.resize(static_cast<size_t>(grid.size()) * model::kNumSpotParams);
  if (effects.defocus_offset) {
    if (want) plain_offset_jacobian_.resize(2 * static_cast<size_t>(grid.size()));
    renderer_.RenderWithDefocusOffset(
        spot, effects.defocus_offset->dx_px, effects.defocus_offset->dy_px, grid, plain_.data(),
        want ? spot_jacobian_.data() : nullptr, want ? plain_offset_jacobian_.data() : nullptr);
  } else {
    renderer_.Render(spot, grid, plain_.data(), want ? spot_jacobian_.data() : nullptr);
  }
  return static_cast<int>(std::max_element(plain_.begin(), plain_.end()) - plain_.begin());
}

bool FitEvaluator::KernelWidths(const double* theta, int k, double* sigma_x_px,
                                double* sigma_y_px) {
  const FitModel& fm = fit_model_;
  const model::SpotParams spot = fm.SpotFor(theta, k);
  *sigma_x_px = spot[model::kCcdSigmaX];
  *sigma_y_px = spot[model::kCcdSigmaY];
  model::ExposureEffects effects;
  if (fm.HasEffects() && !fm.EffectsAt(theta, &effects)) return false;
  if (!effects.brighter_fatter) return true;
  model::SpotParams plain = spot;  // drawn with exposure k's jitter, as ModelImageColumns
  const int jitter = fm.JitterIndex(k);
  for (int axis = 0; jitter >= 0 && axis < 2; ++axis) {
    const int sp = axis == 0 ? model::kCcdSigmaX : model::kCcdSigmaY;
    plain[sp] = std::sqrt(plain[sp] * plain[sp] + std::max(theta[jitter + axis], 0.0));
  }
  const int peak = RenderWithoutGrowth(plain, fm.GridFor(k), effects, false);
  if (peak < 0) return false;
  *sigma_x_px += effects.brighter_fatter->slope_x_px_per_e * plain_[peak];
  *sigma_y_px += effects.brighter_fatter->slope_y_px_per_e * plain_[peak];
  return true;
}

bool FitEvaluator::ModelImageColumns(const double* theta, int k, std::vector<double>* model,
                                     std::vector<double>* jacobian, std::vector<int>* columns) {
  const FitModel& fm = fit_model_;
  const model::PixelGrid grid = fm.GridFor(k);
  const int n = grid.size();
  const bool want = jacobian != nullptr;
  model::SpotParams spot = fm.SpotFor(theta, k);
  if (!want && !fm.HasEffects()) {  // the sampler's hot path: one render
    model->resize(n);
    renderer_.Render(spot, grid, model->data(), nullptr);
    return true;
  }
  model::ExposureEffects effects;
  if (fm.HasEffects() && !fm.EffectsAt(theta, &effects)) return false;
  model->resize(n);

  // The theta indices exposure k depends on, and the chain from them to the renderer's
  // parameters: chain[p][c] = d spot_p / d theta_{columns[c]}. Values alone (an MCMC's
  // proposals) need neither: no columns then.
  const int focus = fm.FocusIndex(), ratio = fm.RatioIndex(k);
  const int jitter = fm.JitterIndex(k);
  const int offset = fm.EffectIndex(model::EffectKind::kDefocusOffset);  // pixel_centre only
  columns->clear();
  if (want) {
    columns->assign({kFluxE, kAiryRadiusPx, kDefocusPx, kCcdSigmaXPx, kCcdSigmaYPx,
                     FitModel::XIndex(k), FitModel::YIndex(k)});
    if (focus >= 0) columns->push_back(focus);
    if (ratio >= 0) columns->push_back(ratio);
    for (const FitEffect& e : fm.options().effects) {
      if (e.kind == model::EffectKind::kJitter) {
        if (jitter >= 0) columns->insert(columns->end(), {jitter, jitter + 1});
        continue;
      }
      const int np = fm.EffectSize(e.kind);
      for (int p = 0; p < np; ++p) columns->push_back(fm.EffectIndex(e.kind) + p);
    }
  }
  const int nc = static_cast<int>(columns->size());
  auto column_of = [&](int theta_index) {
    return static_cast<int>(std::find(columns->begin(), columns->end(), theta_index) -
                            columns->begin());
  };
  std::vector<double>& chain = chain_;
  chain.assign(static_cast<size_t>(model::kNumSpotParams) * nc, 0.0);
  auto link = [&](int p, int theta_index) -> double& {
    return chain[static_cast<size_t>(p) * nc + column_of(theta_index)];
  };
  // The renderer's flux is flux_e x scale; in focus mode the defocus is rate |z_k - z0|.
  if (want) {
    double d_rate = 1.0, d_z0 = 0.0;
    if (focus >= 0) fm.DefocusFor(theta, k, &d_rate, &d_z0);
    link(model::kFlux, kFluxE) = fm.FluxScale(theta, k);
    if (ratio >= 0) link(model::kFlux, ratio) = theta[kFluxE] * fm.FixedFluxScale(k);
    link(model::kCentreX, FitModel::XIndex(k)) = 1.0;
    link(model::kCentreY, FitModel::YIndex(k)) = 1.0;
    link(model::kAiryRadius, kAiryRadiusPx) = 1.0;
    link(model::kDefocus, kDefocusPx) = d_rate;
    if (focus >= 0) link(model::kDefocus, focus) = d_z0;
    link(model::kCcdSigmaX, kCcdSigmaXPx) = 1.0;
    link(model::kCcdSigmaY, kCcdSigmaYPx) = 1.0;
  }

  if (want) spot_jacobian_.resize(static_cast<size_t>(n) * model::kNumSpotParams);
  std::string why;
  // Exposure k's jitter variance v adds to the kernel's (as model::AdjustSpotParams, after
  // the brighter-fatter growth): s' = sqrt(s^2 + v), ds'/ds = s / s', ds'/dv = 1 / (2 s')
  // (v >= 0 inside the prior); applied to a spot and its chain.
  auto add_jitter = [&](model::SpotParams* s, std::vector<double>* rows) {
    for (int axis = 0; axis < 2; ++axis) {
      const int sp = axis == 0 ? model::kCcdSigmaX : model::kCcdSigmaY;
      const double w = (*s)[sp], v = std::max(theta[jitter + axis], 0.0);
      const double total = std::sqrt(w * w + v);
      if (!(total > 0.0)) return false;
      for (int c = 0; c < nc; ++c) (*rows)[static_cast<size_t>(sp) * nc + c] *= w / total;
      if (want) (*rows)[static_cast<size_t>(sp) * nc + column_of(jitter + axis)] += 0.5 / total;
      (*s)[sp] = total;
    }
    return true;
  };
  if (effects.brighter_fatter) {
    // The widths grow with the peak pixel I of the spot drawn without the growth but with
    // the jitter (model/effects.h, BrighterFatterSignal); I depends on theta through that
    // render's own derivatives at its brightest pixel.
    model::SpotParams plain_spot = spot;
    const std::vector<double>* plain_chain = &chain;
    if (jitter >= 0) {
      plain_chain_ = chain;
      if (!add_jitter(&plain_spot, &plain_chain_)) return false;
      plain_chain = &plain_chain_;
    }
    const int peak = RenderWithoutGrowth(plain_spot, grid, effects, want);
    if (peak < 0) return false;
    const double signal = plain_[peak];
    const model::BrighterFatterParams& bf = *effects.brighter_fatter;
    if (want) {
      std::vector<double> d_signal(nc, 0.0);
      const double* g = &spot_jacobian_[static_cast<size_t>(peak) * model::kNumSpotParams];
      for (int p = 0; p < model::kNumSpotParams; ++p) {
        for (int c = 0; c < nc; ++c) {
          d_signal[c] += g[p] * (*plain_chain)[static_cast<size_t>(p) * nc + c];
        }
      }
      if (offset >= 0) {
        d_signal[column_of(offset)] += plain_offset_jacobian_[2 * static_cast<size_t>(peak)];
        d_signal[column_of(offset + 1)] +=
            plain_offset_jacobian_[2 * static_cast<size_t>(peak) + 1];
      }
      for (int c = 0; c < nc; ++c) {
        chain[static_cast<size_t>(model::kCcdSigmaX) * nc + c] += bf.slope_x_px_per_e * d_signal[c];
        chain[static_cast<size_t>(model::kCcdSigmaY) * nc + c] += bf.slope_y_px_per_e * d_signal[c];
      }
      const int slope = fm.EffectIndex(model::EffectKind::kBrighterFatter);
      link(model::kCcdSigmaX, slope) += signal;
      link(model::kCcdSigmaY, slope + 1) += signal;
    }
    spot[model::kCcdSigmaX] += bf.slope_x_px_per_e * signal;
    spot[model::kCcdSigmaY] += bf.slope_y_px_per_e * signal;
  }
  if (jitter >= 0 && !add_jitter(&spot, &chain)) return false;
  if (!model::ValidSpotParams(renderer_.options(), spot, &why)) return false;
  // boundary_shift reads the line densities along the pixel boundaries and the light at
  // their corners, only on the exposure's window (ApplyBoundaryShift): the window's rows' x
  // boundaries from its first pixel's lower edge to its last's upper edge, likewise along y,
  // and the corners of both. They are drawn with the spot's parameters in the image's render.
  const bool shift = effects.boundary_shift.has_value();
  const model::PixelWindow* shift_window = shift ? &fm.ShiftWindow(k) : nullptr;
  model::PixelGrid part[3];
  if (shift) {
    const model::PixelWindow& w = *shift_window;
    const int wx = w.i1 - w.i0 + 1, wy = w.j1 - w.j0 + 1;
    part[0] = {wx + 1, wy, grid.x0 - 1.0 + w.i0, grid.y0 + w.j0};
    part[1] = {wx, wy + 1, grid.x0 + w.i0, grid.y0 - 1.0 + w.j0};
    part[2] = {wx + 1, wy + 1, grid.x0 - 1.0 + w.i0, grid.y0 - 1.0 + w.j0};
  }
  if (offset >= 0) {
    offset_jacobian_.resize(2 * static_cast<size_t>(n));
    renderer_.RenderWithDefocusOffset(
        spot, effects.defocus_offset->dx_px, effects.defocus_offset->dy_px, grid, model->data(),
        want ? spot_jacobian_.data() : nullptr, want ? offset_jacobian_.data() : nullptr);
  } else if (shift) {
    model::SpotRenderer::DensityImage images[3];
    for (int kind = 0; kind < 3; ++kind) {
      density_values_[kind].resize(part[kind].size());
      if (want) {
        density_jacobian_[kind].resize(static_cast<size_t>(part[kind].size()) *
                                       model::kNumSpotParams);
      }
      images[kind] = {part[kind], density_values_[kind].data(),
                      want ? density_jacobian_[kind].data() : nullptr};
    }
    renderer_.RenderWithDensities(spot, grid, model->data(),
                                  want ? spot_jacobian_.data() : nullptr, images[0], images[1],
                                  images[2]);
  } else {
    renderer_.Render(spot, grid, model->data(), want ? spot_jacobian_.data() : nullptr);
  }

  // d image / d theta_column = sum_p d image / d spot_p x chain[p][column]; written into
  // the derivative channels of the image effects' dual image, or straight into the
  // Jacobian. boundary_shift works on that dual image too.
  const bool image_effects = effects.HasImageEffects() || shift;
  const int stride = image_effects ? (want ? nc + 1 : 1) : nc;
  double* out = nullptr;
  if (image_effects) {
    dual_.nx = grid.nx;
    dual_.ny = grid.ny;
    dual_.num_derivatives = want ? nc : 0;
    dual_.data.assign(static_cast<size_t>(n) * dual_.stride(), 0.0);
    for (int q = 0; q < n; ++q) dual_.data[static_cast<size_t>(q) * dual_.stride()] = (*model)[q];
    out = dual_.data.data() + 1;
  } else if (want) {
    jacobian->assign(static_cast<size_t>(n) * nc, 0.0);
    out = jacobian->data();
  }
  if (want) {
    // The chain's nonzero entries (one or two per renderer parameter without the
    // brighter-fatter growth): the product at a few multiply-adds a pixel.
    links_.clear();
    for (int p = 0; p < model::kNumSpotParams; ++p) {
      for (int c = 0; c < nc; ++c) {
        const double v = chain[static_cast<size_t>(p) * nc + c];
        if (v != 0.0) links_.push_back({p, c, v});
      }
    }
    for (int q = 0; q < n; ++q) {
      const double* g = &spot_jacobian_[static_cast<size_t>(q) * model::kNumSpotParams];
      double* row = out + static_cast<size_t>(q) * stride;
      for (const Link& l : links_) row[l.column] += g[l.spot_param] * l.value;
    }
    if (offset >= 0) {  // the offset is no renderer parameter: its own columns
      const int cx = column_of(offset), cy = column_of(offset + 1);
      for (int q = 0; q < n; ++q) {
        double* row = out + static_cast<size_t>(q) * stride;
        row[cx] += offset_jacobian_[2 * static_cast<size_t>(q)];
        row[cy] += offset_jacobian_[2 * static_cast<size_t>(q) + 1];
      }
    }
  }
  if (!image_effects) return true;
  if (shift) {
    // The densities into dual images on the full boundary and corner grids, with their
    // derivatives chained to theta as the image's.
    const model::PixelWindow& w = *shift_window;
    const model::PixelGrid full[3] = {{grid.nx + 1, grid.ny, grid.x0 - 1.0, grid.y0},
                                      {grid.nx, grid.ny + 1, grid.x0, grid.y0 - 1.0},
                                      {grid.nx + 1, grid.ny + 1, grid.x0 - 1.0, grid.y0 - 1.0}};
    model::DualImage* const densities[3] = {&boundary_densities_.x, &boundary_densities_.y,
                                            &boundary_densities_.corner};
    for (int kind = 0; kind < 3; ++kind) {
      const model::PixelGrid& g = part[kind];
      model::DualImage& d = *densities[kind];
      d.nx = full[kind].nx;
      d.ny = full[kind].ny;
      d.num_derivatives = want ? nc : 0;
      d.data.assign(static_cast<size_t>(full[kind].size()) * d.stride(), 0.0);
      for (int q = 0; q < g.size(); ++q) {
        // Entry (qi, qj) of the window's grid is (w.i0 + qi, w.j0 + qj) of the full one.
        const int qi = q % g.nx, qj = q / g.nx;
        const size_t at = static_cast<size_t>(w.j0 + qj) * d.nx + (w.i0 + qi);
        double* row = d.data.data() + at * d.stride();
        row[0] = density_values_[kind][q];
        if (!want) continue;
        const double* gq =
            &density_jacobian_[kind][static_cast<size_t>(q) * model::kNumSpotParams];
        for (const Link& l : links_) row[1 + l.column] += gq[l.spot_param] * l.value;
      }
    }
  }

  // The halo's reference: the spot's flux and centre, with their derivatives. In
  // pixel_centre sampling the flux parameter is the 2015 peak meta-parameter m, not a flux:
  // the reference is the stamp's summed charge (as the simulator takes it).
  const bool peak_flux = renderer_.options().sampling == model::Sampling::kPixelCentre;
  model::SpotReference reference{spot[model::kFlux], spot[model::kCentreX], spot[model::kCentreY]};
  if (peak_flux) reference.flux_e = std::accumulate(model->begin(), model->end(), 0.0);
  model::SpotReferenceDerivatives reference_d;
  model::EffectChannels channels;
  if (want) {
    auto row_of = [&](int p) {
      return std::vector<double>(chain.begin() + static_cast<size_t>(p) * nc,
                                 chain.begin() + static_cast<size_t>(p + 1) * nc);
    };
    reference_d = {row_of(model::kFlux), row_of(model::kCentreX), row_of(model::kCentreY)};
    if (peak_flux) {
      std::fill(reference_d.flux_e.begin(), reference_d.flux_e.end(), 0.0);
      for (int q = 0; q < n; ++q) {
        const double* row = out + static_cast<size_t>(q) * stride;
        for (int c = 0; c < nc; ++c) reference_d.flux_e[c] += row[c];
      }
    }
    for (const FitEffect& e : fm.options().effects) {
      if (e.kind == model::EffectKind::kJitter) continue;  // a kernel effect, drawn above
      const int np = fm.EffectSize(e.kind);
      for (int p = 0; p < np; ++p) {
        channels.Set(e.kind, p, 1 + column_of(fm.EffectIndex(e.kind) + p));
      }
    }
  }
  if (shift) {
    model::ApplyBoundaryShift(*effects.boundary_shift, boundary_densities_, *shift_window,
                              channels, &dual_);
  }
  model::ApplyImageEffects(effects, grid, reference, want ? &reference_d : nullptr, channels,
                           &dual_);
  const int ds = dual_.stride();
  for (int q = 0; q < n; ++q) (*model)[q] = dual_.data[static_cast<size_t>(q) * ds];
  if (want) {
    jacobian->resize(static_cast<size_t>(n) * nc);
    for (int q = 0; q < n; ++q) {
      std::copy_n(dual_.data.data() + static_cast<size_t>(q) * ds + 1, nc,
                  jacobian->data() + static_cast<size_t>(q) * nc);
    }
  }
  return true;
}

bool FitEvaluator::ModelImage(const double* theta, int k, std::vector<double>* model,
                              std::vector<double>* jacobian) {
  if (jacobian == nullptr) return ModelImageColumns(theta, k, model, nullptr, &columns_);
  if (!ModelImageColumns(theta, k, model, &local_jacobian_, &columns_)) return false;
  const int n = static_cast<int>(model->size()), dim = fit_model_.dim();
  const int nc = static_cast<int>(columns_.size());
  jacobian->assign(static_cast<size_t>(n) * dim, 0.0);
  for (int q = 0; q < n; ++q) {
    for (int c = 0; c < nc; ++c) {
      (*jacobian)[static_cast<size_t>(q) * dim + columns_[c]] =
          local_jacobian_[static_cast<size_t>(q) * nc + c];
    }
  }
  return true;
}

double FitEvaluator::ExposureLogLikelihood(const double* theta, int k) {
  const LikelihoodKind kind = fit_model_.options().likelihood;
  const Stamp& stamp = fit_model_.stamps()[k];
  const PixelNoise stamp_noise = StampNoise(stamp);
  if (kind == LikelihoodKind::kGaussian && !stamp_noise.interval) {
    // The common case on the MCMC's hot path: uncensored pixels summed by
    // GaussianLogLikelihoodSum (a log per 16 pixels, not per pixel), censored ones as below.
    if (!ModelImage(theta, k, &pixels_, nullptr)) return -INFINITY;
    GaussianLogLikelihoodSum gaussian(stamp_noise.ccd);
    double censored = 0.0;
    PixelValue v;
    const double pedestal = fit_model_.PedestalAt(theta);
    for (size_t q = 0; q < pixels_.size(); ++q) {
      if (!stamp.valid[q]) continue;
      const Censor censor = stamp.CensorAt(q);
      if (censor == Censor::kNone) {
        gaussian.Add(stamp.electrons.data[q] - pedestal, pixels_[q] - pedestal);
      } else {
        EvaluatePixelWithPedestal(kind, stamp.electrons.data[q], censor, pixels_[q], pedestal,
                                  stamp_noise, false, &v);
        censored += v.log_p;
      }
    }
    return gaussian.Total() + censored;
  }
  double log_likelihood, chi2;
  return ExposureScore(theta, k, nullptr, &log_likelihood, &chi2) ? log_likelihood : -INFINITY;
}

double FitEvaluator::LogLikelihood(const double* theta) {
  double total = 0.0;
  for (int k = 0; k < fit_model_.num_exposures(); ++k) total += ExposureLogLikelihood(theta, k);
  return total;
}

double FitEvaluator::BestFluxLogLikelihood(double* theta, int first, int last) {
  const double saved_flux = theta[kFluxE];
  theta[kFluxE] = 1.0;
  unit_models_.resize(fit_model_.num_exposures());
  double num = 0.0, den = 0.0;
  for (int k = first; k < last; ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    if (!ModelImage(theta, k, &unit_models_[k], nullptr)) {
      theta[kFluxE] = saved_flux;
      return -INFINITY;
    }
    for (size_t q = 0; q < unit_models_[k].size(); ++q) {
      if (!s.valid[q] || s.CensorAt(q) != Censor::kNone) continue;
      num += unit_models_[k][q] * s.electrons.data[q];
      den += unit_models_[k][q] * unit_models_[k][q];
    }
  }
  if (!(den > 0) || !std::isfinite(num / den)) {
    theta[kFluxE] = saved_flux;
    return -INFINITY;
  }
  const double flux =
      std::clamp(num / den, fit_model_.lower()[kFluxE], fit_model_.upper()[kFluxE]);
  theta[kFluxE] = flux;
  if (fit_model_.HasEffects()) {
    // A background, a nonlinear response or the brighter-fatter growth make the model affine
    // or nonlinear in the flux: the flux above is a least-squares guess, and the likelihood
    // is evaluated afresh at it.
    double total = 0.0;
    for (int k = first; k < last; ++k) total += ExposureLogLikelihood(theta, k);
    return std::isfinite(total) ? total : -INFINITY;
  }
  const LikelihoodKind kind = fit_model_.options().likelihood;
  double total = 0.0;
  PixelValue v;
  for (int k = first; k < last; ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    const PixelNoise noise = StampNoise(s);
    for (size_t q = 0; q < unit_models_[k].size(); ++q) {
      if (!s.valid[q]) continue;
      EvaluatePixel(kind, s.electrons.data[q], s.CensorAt(q), flux * unit_models_[k][q], noise,
                    false, &v);
      total += v.log_p;
    }
  }
  return std::isfinite(total) ? total : -INFINITY;
}

double FitEvaluator::ChiSquare(const double* theta) {
  double chi2 = 0.0, log_likelihood, exposure_chi2;
  for (int k = 0; k < fit_model_.num_exposures(); ++k) {
    if (!ExposureScore(theta, k, nullptr, &log_likelihood, &exposure_chi2)) return NAN;
    chi2 += exposure_chi2;
  }
  return chi2;
}

bool FitEvaluator::ExposureScore(const double* theta, int k, const Image* data_e,
                                 double* log_likelihood, double* chi2) {
  *log_likelihood = 0.0;
  *chi2 = 0.0;
  std::string why;
  if (!model::ValidSpotParams(renderer_options(), fit_model_.SpotFor(theta, k), &why) ||
      !ModelImage(theta, k, &pixels_, nullptr)) {
    return false;
  }
  const Stamp& s = fit_model_.stamps()[k];
  const std::vector<double>& data = data_e != nullptr ? data_e->data : s.electrons.data;
  const PixelNoise noise = StampNoise(s);
  const double pedestal = fit_model_.PedestalAt(theta);
  PixelValue v;
  for (size_t q = 0; q < pixels_.size(); ++q) {
    if (!std::isfinite(pixels_[q])) return false;
    if (!s.valid[q]) continue;
    EvaluatePixelWithPedestal(fit_model_.options().likelihood, data[q], s.CensorAt(q), pixels_[q],
                              pedestal, noise, false, &v);
    *log_likelihood += v.log_p;
    *chi2 += v.chi2;
  }
  return true;
}

int FitEvaluator::CensoredViolations(const double* theta, double sd, double* worst_sd) {
  int count = 0;
  *worst_sd = INFINITY;
  PixelValue v;
  const double pedestal = fit_model_.PedestalAt(theta);
  for (int k = 0; k < fit_model_.num_exposures(); ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    if (!ModelImage(theta, k, &pixels_, nullptr)) return count;
    for (size_t q = 0; q < pixels_.size(); ++q) {
      if (!s.valid[q] || s.CensorAt(q) == Censor::kNone) continue;
      EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, s.electrons.data[q], s.CensorAt(q),
                                pixels_[q], pedestal, StampNoise(s), false, &v);
      *worst_sd = std::min(*worst_sd, v.censored_sd);
      count += v.censored_sd < -sd;
    }
  }
  return count;
}

namespace {

// The gradients of a pixel's two residuals by theta, from its model Jacobian row g.
void ResidualGradients(const PixelValue& v, const double* g, int dim, int pedestal_index,
                       double* r0_d, double* r1_d) {
  // dr/dtheta = dr/dm d charge/dtheta - dr/dd d pedestal/dtheta: the pedestal moves the
  // expectation and the datum's reference alike (EvaluatePixelWithPedestal).
  for (int a = 0; a < dim; ++a) {
    const double e = a == pedestal_index ? 1.0 : 0.0;
    r0_d[a] = v.dr_dm[0] * (g[a] - e) - v.dr_dd[0] * e;
    r1_d[a] = v.dr_dm[1] * (g[a] - e) - v.dr_dd[1] * e;
  }
}

}  // namespace

std::vector<double> FitEvaluator::FisherInformation(const double* theta,
                                                    std::vector<double>* scores) {
  const int dim = fit_model_.dim();
  const size_t size = static_cast<size_t>(dim) * dim;
  std::vector<double> fisher(size, 0.0);
  if (scores != nullptr) scores->assign(size, 0.0);
  for (int k = 0; k < fit_model_.num_exposures(); ++k) {
    if (!AddExposureFisherInformation(theta, k, nullptr, &fisher, scores)) {
      if (scores != nullptr) scores->assign(size, NAN);
      return std::vector<double>(size, NAN);
    }
  }
  return fisher;
}

std::vector<double> FitEvaluator::ScoreOuterProducts(const double* theta) {
  std::vector<double> scores;
  FisherInformation(theta, &scores);
  return scores;
}

bool FitEvaluator::AddExposureFisherInformation(const double* theta, int k, const Image* data_e,
                                                std::vector<double>* fisher,
                                                std::vector<double>* scores) {
  const int dim = fit_model_.dim();
  std::vector<double> jac, mean_d(dim), var_d(dim), r0_d(dim), r1_d(dim), score(dim);
  PixelValue v;
  // The pedestal moves the mean but not the variance (it has no shot noise).
  const int pedestal_index = fit_model_.EffectIndex(model::EffectKind::kBackground);
  const double pedestal = fit_model_.PedestalAt(theta);
  auto add_outer = [&](const std::vector<double>& u, const std::vector<double>& w, double scale) {
    for (int a = 0; a < dim; ++a) {
      if (u[a] == 0.0) continue;
      for (int b = 0; b < dim; ++b) (*fisher)[a * dim + b] += scale * u[a] * w[b];
    }
  };
  const Stamp& s = fit_model_.stamps()[k];
  const std::vector<double>& data = data_e != nullptr ? data_e->data : s.electrons.data;
  const PixelNoise noise = StampNoise(s);
  if (!ModelImage(theta, k, &pixels_, &jac)) return false;
  for (size_t q = 0; q < pixels_.size(); ++q) {
    if (!s.valid[q]) continue;
    const double* g = &jac[q * dim];
    const double charge = pixels_[q] - pedestal;
    if (s.CensorAt(q) == Censor::kNone && !noise.interval) {
      const double var = noise.ccd.VarianceE2(charge);
      // g = dm/dtheta; dvar/dtheta = d charge/dtheta where the charge is positive
      // (VarianceE2 clamps at 0).
      for (int a = 0; a < dim; ++a) {
        mean_d[a] = g[a];
        var_d[a] = charge > 0 ? g[a] - (a == pedestal_index ? 1.0 : 0.0) : 0.0;
      }
      add_outer(mean_d, mean_d, 1.0 / var);
      add_outer(var_d, var_d, 0.5 / (var * var));
    } else {
      // Interval and censored pixels: the Gauss-Newton information of their residuals
      // (observed, not expected: a censored pixel informs only where the model nears its
      // level).
      EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, data[q], s.CensorAt(q), pixels_[q],
                                pedestal, noise, true, &v);
      ResidualGradients(v, g, dim, pedestal_index, r0_d.data(), r1_d.data());
      add_outer(r0_d, r0_d, 1.0);
      add_outer(r1_d, r1_d, 1.0);
    }
    if (scores == nullptr) continue;
    // The pixel's score, d log p / d theta = -(r0 dr0 + r1 dr1) (1/2 (r0^2 + r1^2) = -log p
    // + c), from the same residuals at the data.
    EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, data[q], s.CensorAt(q), pixels_[q],
                              pedestal, noise, true, &v);
    ResidualGradients(v, g, dim, pedestal_index, r0_d.data(), r1_d.data());
    for (int a = 0; a < dim; ++a) score[a] = -(v.r[0] * r0_d[a] + v.r[1] * r1_d[a]);
    for (int a = 0; a < dim; ++a) {
      if (score[a] == 0.0) continue;
      for (int b = 0; b < dim; ++b) (*scores)[a * dim + b] += score[a] * score[b];
    }
  }
  return true;
}


}  // namespace ccdpsf::fit
