#include "ccdpsf/fit/fit_model.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "glog/logging.h"

namespace ccdpsf::fit {
namespace {

using model::SpotParam;

// theta index of each renderer parameter for exposure k.
int ThetaIndex(int spot_param, int k) {
  switch (spot_param) {
    case model::kFlux:
      return kFluxE;
    case model::kCentreX:
      return FitModel::XIndex(k);
    case model::kCentreY:
      return FitModel::YIndex(k);
    case model::kAiryRadius:
      return kAiryRadiusPx;
    case model::kDefocus:
      return kDefocusPx;
    case model::kCcdSigmaX:
      return kCcdSigmaXPx;
    case model::kCcdSigmaY:
      return kCcdSigmaYPx;
  }
  LOG(FATAL) << "bad spot parameter " << spot_param;
  return -1;
}

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

bool CcdSplitUnidentified(const FitModelOptions& options) {
  return options.model.sampling == model::Sampling::kIntegrated &&
         options.model.defocus == model::DefocusKind::kGaussian && !options.through_focus;
}

bool IsFocusSeries(const std::vector<Stamp>& stamps, std::string* why) {
  std::vector<double> z;
  for (size_t k = 0; k < stamps.size(); ++k) {
    const double v = stamps[k].info.focus_position_um;
    if (!std::isfinite(v)) {
      *why = "exposure " + std::to_string(k) +
             (stamps[k].info.source.empty() ? "" : " ('" + stamps[k].info.source + "')") +
             " has no focus position (FOCUSPOS keyword)";
      return false;
    }
    z.push_back(v);
  }
  std::sort(z.begin(), z.end());
  const int distinct = static_cast<int>(std::unique(z.begin(), z.end()) - z.begin());
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
  for (int i = 0; i < m->dim(); ++i) {
    if (!(m->lower_[i] < m->upper_[i])) {
      *error = "empty prior range for " + m->names_[i];
      return nullptr;
    }
  }
  return m;
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
  // Flux: the least-squares scale of the model to the data.
  for (int i : SharedIndices()) theta[i] = std::clamp(theta[i], lower_[i], upper_[i]);
  FitEvaluator ev(*this);
  const double flux = ev.LeastSquaresFlux(theta.data());
  theta[kFluxE] =
      std::clamp(std::isfinite(flux) ? flux : signal_e_, lower_[kFluxE], upper_[kFluxE]);
  return theta;
}

std::unique_ptr<FitEvaluator> FitModel::NewEvaluator() const {
  return std::make_unique<FitEvaluator>(*this);
}

FitEvaluator::FitEvaluator(const FitModel& model)
    : fit_model_(model), renderer_(model.options().model) {}

void FitEvaluator::ModelImage(const double* theta, int k, std::vector<double>* model,
                              std::vector<double>* jacobian) {
  const model::PixelGrid grid = fit_model_.GridFor(k);
  const int n = grid.size();
  model->resize(n);
  if (jacobian == nullptr) {
    renderer_.Render(fit_model_.SpotFor(theta, k), grid, model->data(), nullptr);
    return;
  }
  spot_jacobian_.resize(static_cast<size_t>(n) * model::kNumSpotParams);
  renderer_.Render(fit_model_.SpotFor(theta, k), grid, model->data(), spot_jacobian_.data());
  const int dim = fit_model_.dim();
  jacobian->assign(static_cast<size_t>(n) * dim, 0.0);
  // Focus mode: the defocus column is split by the chain rule into the rate (theta index
  // kDefocusPx) and best-focus columns.
  const int focus = fit_model_.FocusIndex();
  double d_rate = 1.0, d_z0 = 0.0;
  if (focus >= 0) fit_model_.DefocusFor(theta, k, &d_rate, &d_z0);
  // The renderer's flux is flux_e x scale: chain rule into flux_e and the ratio.
  const double scale = fit_model_.FluxScale(theta, k);
  const int ratio = fit_model_.RatioIndex(k);
  const double d_ratio = theta[kFluxE] * fit_model_.FixedFluxScale(k);
  for (int q = 0; q < n; ++q) {
    const double* g = &spot_jacobian_[static_cast<size_t>(q) * model::kNumSpotParams];
    double* row = &(*jacobian)[static_cast<size_t>(q) * dim];
    for (int p = 0; p < model::kNumSpotParams; ++p) row[ThetaIndex(p, k)] = g[p];
    row[kFluxE] = g[model::kFlux] * scale;
    if (ratio >= 0) row[ratio] = g[model::kFlux] * d_ratio;
    if (focus >= 0) {
      row[kDefocusPx] = g[model::kDefocus] * d_rate;
      row[focus] = g[model::kDefocus] * d_z0;
    }
  }
}

template <typename Visit>
void FitEvaluator::ForEachValidPixel(const double* theta, int first, int last, Visit visit) {
  for (int k = first; k < last; ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    const PixelNoise noise = StampNoise(s);
    ModelImage(theta, k, &pixels_, nullptr);
    for (size_t q = 0; q < pixels_.size(); ++q) {
      if (s.valid[q]) visit(s.electrons.data[q], s.CensorAt(q), pixels_[q], noise);
    }
  }
}

double FitEvaluator::ExposureLogLikelihood(const double* theta, int k) {
  const LikelihoodKind kind = fit_model_.options().likelihood;
  const Stamp& stamp = fit_model_.stamps()[k];
  const PixelNoise stamp_noise = StampNoise(stamp);
  if (kind == LikelihoodKind::kGaussian && !stamp_noise.interval) {
    // The common case on the MCMC's hot path: uncensored pixels summed by
    // GaussianLogLikelihoodSum (a log per 16 pixels, not per pixel), censored ones as below.
    ModelImage(theta, k, &pixels_, nullptr);
    GaussianLogLikelihoodSum gaussian(stamp_noise.ccd);
    double censored = 0.0;
    PixelValue v;
    for (size_t q = 0; q < pixels_.size(); ++q) {
      if (!stamp.valid[q]) continue;
      const Censor censor = stamp.CensorAt(q);
      if (censor == Censor::kNone) {
        gaussian.Add(stamp.electrons.data[q], pixels_[q]);
      } else {
        EvaluatePixel(kind, stamp.electrons.data[q], censor, pixels_[q], stamp_noise, false, &v);
        censored += v.log_p;
      }
    }
    return gaussian.Total() + censored;
  }
  double total = 0.0;
  PixelValue v;
  ForEachValidPixel(theta, k, k + 1,
                    [&](double data_e, Censor censor, double model_e, const PixelNoise& noise) {
                      EvaluatePixel(kind, data_e, censor, model_e, noise, false, &v);
                      total += v.log_p;
                    });
  return total;
}

double FitEvaluator::LogLikelihood(const double* theta) {
  double total = 0.0;
  for (int k = 0; k < fit_model_.num_exposures(); ++k) total += ExposureLogLikelihood(theta, k);
  return total;
}

double FitEvaluator::LogPosterior(const double* theta) {
  if (!fit_model_.InsidePrior(theta)) return -INFINITY;
  const double ll = LogLikelihood(theta);
  return std::isfinite(ll) ? ll : -INFINITY;
}

double FitEvaluator::BestFluxLogLikelihood(double* theta, int first, int last) {
  const double saved_flux = theta[kFluxE];
  theta[kFluxE] = 1.0;
  unit_models_.resize(fit_model_.num_exposures());
  double num = 0.0, den = 0.0;
  for (int k = first; k < last; ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    ModelImage(theta, k, &unit_models_[k], nullptr);
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

double FitEvaluator::LeastSquaresFlux(const double* theta) {
  std::vector<double> unit(theta, theta + fit_model_.dim());
  unit[kFluxE] = 1.0;
  double num = 0.0, den = 0.0;
  ForEachValidPixel(unit.data(), 0, fit_model_.num_exposures(),
                    [&](double data_e, Censor censor, double model_e, const PixelNoise&) {
                      if (censor != Censor::kNone) return;  // their values are bounds
                      num += model_e * data_e;
                      den += model_e * model_e;
                    });
  return den > 0 ? num / den : NAN;
}

double FitEvaluator::ChiSquare(const double* theta) {
  double chi2 = 0.0;
  PixelValue v;
  ForEachValidPixel(theta, 0, fit_model_.num_exposures(),
                    [&](double data_e, Censor censor, double model_e, const PixelNoise& noise) {
                      EvaluatePixel(LikelihoodKind::kGaussian, data_e, censor, model_e, noise,
                                    false, &v);
                      chi2 += v.chi2;
                    });
  return chi2;
}

int FitEvaluator::CensoredViolations(const double* theta, double sd, double* worst_sd) {
  int count = 0;
  *worst_sd = INFINITY;
  PixelValue v;
  ForEachValidPixel(theta, 0, fit_model_.num_exposures(),
                    [&](double data_e, Censor censor, double model_e, const PixelNoise& noise) {
                      if (censor == Censor::kNone) return;
                      EvaluatePixel(LikelihoodKind::kGaussian, data_e, censor, model_e, noise,
                                    false, &v);
                      *worst_sd = std::min(*worst_sd, v.censored_sd);
                      count += v.censored_sd < -sd;
                    });
  return count;
}

std::vector<double> FitEvaluator::FisherInformation(const double* theta) {
  const int dim = fit_model_.dim();
  std::vector<double> fisher(static_cast<size_t>(dim) * dim, 0.0);
  std::vector<double> jac;
  PixelValue v;
  for (int k = 0; k < fit_model_.num_exposures(); ++k) {
    const Stamp& s = fit_model_.stamps()[k];
    const PixelNoise noise = StampNoise(s);
    ModelImage(theta, k, &pixels_, &jac);
    for (size_t q = 0; q < pixels_.size(); ++q) {
      if (!s.valid[q]) continue;
      double w = 0.0;
      if (s.CensorAt(q) == Censor::kNone && !noise.interval) {
        const double var = noise.ccd.VarianceE2(pixels_[q]);
        // dvar/dtheta = dm/dtheta where the signal is positive (VarianceE2 clamps at 0).
        w = 1.0 / var + (pixels_[q] > 0 ? 0.5 / (var * var) : 0.0);
      } else {
        // Interval and censored pixels: the Gauss-Newton information of their residuals
        // (observed, not expected: a censored pixel informs only where the model nears
        // its level).
        EvaluatePixel(LikelihoodKind::kGaussian, s.electrons.data[q], s.CensorAt(q), pixels_[q],
                      noise, true, &v);
        w = v.dr_dm[0] * v.dr_dm[0] + v.dr_dm[1] * v.dr_dm[1];
      }
      if (!(w > 0)) continue;
      const double* g = &jac[q * dim];
      for (int a = 0; a < dim; ++a) {
        if (g[a] == 0.0) continue;
        for (int b = 0; b < dim; ++b) fisher[a * dim + b] += w * g[a] * g[b];
      }
    }
  }
  return fisher;
}

}  // namespace ccdpsf::fit
