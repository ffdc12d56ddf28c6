#include "ccdpsf/diagnose/effect_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/random.h"
#include "glog/logging.h"

namespace ccdpsf::diagnose {

using model::EffectKind;

namespace {

double StampSum(const Stamp& s) {
  double sum = 0.0;
  for (size_t q = 0; q < s.valid.size(); ++q) {
    if (s.valid[q]) sum += s.electrons.data[q];
  }
  return sum;
}

// The twin's theta indices exposure k depends on: the shared ones, its position, the effects.
std::vector<int> TwinIndicesOf(const fit::FitModel& twin, int k) {
  std::vector<int> indices = {fit::FitModel::XIndex(k), fit::FitModel::YIndex(k)};
  for (int t = 0; t < fit::kNumShared; ++t) indices.push_back(t);
  const int effects = twin.EffectsFirstIndex();  // -1 without effects
  for (int t = effects; t >= 0 && t < twin.dim(); ++t) indices.push_back(t);
  return indices;
}

}  // namespace

std::string ToString(FluxMode mode) {
  return mode == FluxMode::kShared ? "shared" : "per_exposure";
}

bool ModelSpec::Has(EffectKind kind) const {
  if (kind == EffectKind::kDefocus) return defocus;
  return std::find(effects.begin(), effects.end(), kind) != effects.end();
}

std::string ModelSpec::Describe() const {
  std::string s = defocus ? "baseline" : "baseline without defocus";
  for (EffectKind k : effects) s += " + " + model::ToString(k);
  return s;
}

void EffectModel::Add(const std::string& name, double lower, double upper, double start) {
  names_.push_back(name);
  lower_.push_back(lower);
  upper_.push_back(upper);
  start_.push_back(std::clamp(start, lower, upper));
}

std::unique_ptr<EffectModel> EffectModel::Create(const fit::FitModel& base, const ModelSpec& spec,
                                                 std::string* error) {
  if (base.through_focus()) {
    *error = "diagnose does not handle through-focus series (fit them with 'ccdpsf fit')";
    return nullptr;
  }
  if (base.options().likelihood != fit::LikelihoodKind::kGaussian) {
    *error = "diagnose uses the Gaussian likelihood (the paper's); poisson_normal is not supported";
    return nullptr;
  }
  const int n = base.num_exposures();
  for (EffectKind kind : spec.effects) {
    if (kind == EffectKind::kDefocus) {
      *error = "defocus is a baseline component (ModelSpec::defocus), not an added effect";
      return nullptr;
    }
    if (kind == EffectKind::kDefocusOffset &&
        base.options().model.sampling == model::Sampling::kIntegrated) {
      *error = "defocus_offset cannot be fitted in integrated sampling: there it is exactly a "
               "shift of the spot (the positions absorb it)";
      return nullptr;
    }
    if (kind == EffectKind::kDefocusOffset && !spec.defocus) {
      *error = "defocus_offset needs the defocus component in the model";
      return nullptr;
    }
    if (kind == EffectKind::kJitter && n < 2) {
      *error = "jitter needs at least two exposures (one exposure's jitter is its CCD widths)";
      return nullptr;
    }
    if (std::count(spec.effects.begin(), spec.effects.end(), kind) > 1) {
      *error = model::ToString(kind) + " appears twice in the model";
      return nullptr;
    }
  }
  if (spec.Has(EffectKind::kJitter) && (spec.jitter_reference < 0 || spec.jitter_reference >= n)) {
    *error = "jitter reference exposure out of range";
    return nullptr;
  }
  std::unique_ptr<EffectModel> m(new EffectModel(base, spec));
  const auto& bn = base.names();
  const auto& bl = base.lower();
  const auto& bu = base.upper();
  // Shared block.
  if (spec.flux == FluxMode::kShared) {
    m->shared_flux_ = 0;
    m->Add(bn[fit::kFluxE], bl[fit::kFluxE], bu[fit::kFluxE], 0.5 * (bl[0] + bu[0]));
  }
  m->shape_begin_ = m->dim();
  for (int i = fit::kAiryRadiusPx; i <= fit::kCcdSigmaYPx; ++i) {
    if (i == fit::kDefocusPx && !spec.defocus) continue;
    m->Add(bn[i], bl[i], bu[i], 0.5 * (bl[i] + bu[i]));
  }
  m->blocks_.push_back({0, m->dim()});
  // Exposure blocks.
  m->exposure_begin_ = m->dim();
  m->exposure_size_ = spec.flux == FluxMode::kShared ? 2 : 3;
  double mean_sum = 0.0;
  for (const Stamp& s : base.stamps()) mean_sum += StampSum(s) / n;
  for (int k = 0; k < n; ++k) {
    const int b = m->dim();
    for (int j = 0; j < 2; ++j) {
      const int i = fit::FitModel::XIndex(k) + j;
      m->Add(bn[i], bl[i], bu[i], 0.5 * (bl[i] + bu[i]));
    }
    if (spec.flux == FluxMode::kPerExposure) {
      // The shared range, scaled by this stamp's share of the signal.
      const double scale = mean_sum > 0 ? std::max(StampSum(base.stamps()[k]), 1.0) / mean_sum : 1.0;
      m->Add(bn[fit::kFluxE] + "." + std::to_string(k), bl[fit::kFluxE] * scale,
             bu[fit::kFluxE] * scale, StampSum(base.stamps()[k]));
    }
    m->blocks_.push_back({b, m->dim() - b});
  }
  // Shared effect parameters.
  const int effect_begin = m->dim();
  for (EffectKind kind : spec.effects) {
    if (kind == EffectKind::kJitter) continue;
    m->effect_begin_.push_back({kind, m->dim()});
    const model::EffectInfo& info = model::DescribeEffect(kind);
    const std::vector<double> start = m->DefaultStart(kind);
    for (size_t j = 0; j < info.parameters.size(); ++j) {
      const auto& pi = info.parameters[j];
      m->Add(info.name + "." + pi.name, pi.prior_lower, pi.prior_upper, start[j]);
    }
  }
  if (m->dim() > effect_begin) {
    m->effect_block_ = static_cast<int>(m->blocks_.size());
    m->blocks_.push_back({effect_begin, m->dim() - effect_begin});
  }
  // Jitter variances.
  m->jitter_index_.assign(n, -1);
  m->jitter_block_.assign(n, -1);
  if (spec.Has(EffectKind::kJitter)) {
    const model::EffectInfo& info = model::DescribeEffect(EffectKind::kJitter);
    const double vx = std::pow(info.parameters[0].prior_upper, 2);
    const double vy = std::pow(info.parameters[1].prior_upper, 2);
    const std::vector<double> start = m->DefaultStart(EffectKind::kJitter);
    for (int k = 0; k < n; ++k) {
      if (k == spec.jitter_reference) continue;
      m->jitter_index_[k] = m->dim();
      m->jitter_block_[k] = static_cast<int>(m->blocks_.size());
      m->blocks_.push_back({m->dim(), 2});
      m->Add("jitter.var_x_px2." + std::to_string(k), 0.0, vx, start[0]);
      m->Add("jitter.var_y_px2." + std::to_string(k), 0.0, vy, start[1]);
    }
  }
  for (int i = 0; i < m->dim(); ++i) {
    if (!(m->lower_[i] < m->upper_[i])) {
      *error = "empty prior range for " + m->names_[i];
      return nullptr;
    }
  }
  // The fit twin: the same stamps and effects in the fit's model, which draws the images and
  // their analytic derivatives (jitter per exposure with the same reference).
  fit::FitModelOptions twin_options = base.options();
  twin_options.flux = fit::FluxMode::kShared;  // exposure k's flux goes into flux_e
  twin_options.effects.clear();
  for (EffectKind kind : spec.effects) twin_options.effects.push_back({kind, {}});
  twin_options.jitter_reference = spec.Has(EffectKind::kJitter) ? spec.jitter_reference : -1;
  m->twin_ = fit::FitModel::Create(base.stamps(), twin_options, error);
  if (m->twin_ == nullptr) return nullptr;
  const int first = m->twin_->EffectsFirstIndex();
  if (first >= 0) {
    m->twin_effect_to_p_.assign(m->twin_->dim() - first, -1);
    for (const auto& [kind, begin] : m->effect_begin_) {
      const int np = static_cast<int>(model::DescribeEffect(kind).parameters.size());
      for (int j = 0; j < np; ++j) {
        m->twin_effect_to_p_[m->twin_->EffectIndex(kind) + j - first] = begin + j;
      }
    }
    for (int k = 0; k < n; ++k) {
      const int v = m->twin_->JitterIndex(k);
      if (v < 0) continue;
      CHECK_GE(m->jitter_index_[k], 0) << "the twin's jitter reference differs";
      m->twin_effect_to_p_[v - first] = m->jitter_index_[k];
      m->twin_effect_to_p_[v + 1 - first] = m->jitter_index_[k] + 1;
    }
  }
  return m;
}

void EffectModel::TwinTheta(const double* p, int k, double* theta) const {
  std::fill_n(theta, twin_->dim(), 0.0);
  theta[fit::kFluxE] = p[FluxIndex(k)];
  for (int i = fit::kAiryRadiusPx; i <= fit::kCcdSigmaYPx; ++i) {
    const int j = ShapeIndex(i);
    theta[i] = j >= 0 ? p[j] : 0.0;  // no defocus component: held at 0
  }
  theta[fit::FitModel::XIndex(k)] = p[XIndex(k)];
  theta[fit::FitModel::YIndex(k)] = p[YIndex(k)];
  const int first = twin_->EffectsFirstIndex();
  for (size_t e = 0; e < twin_effect_to_p_.size(); ++e) theta[first + e] = p[twin_effect_to_p_[e]];
}

int EffectModel::TwinToP(int theta_index, int k) const {
  int i = -1;
  if (theta_index == fit::kFluxE) {
    i = FluxIndex(k);
  } else if (theta_index < fit::kNumShared) {
    i = ShapeIndex(theta_index);
  } else if (theta_index == fit::FitModel::XIndex(k)) {
    i = XIndex(k);
  } else if (theta_index == fit::FitModel::YIndex(k)) {
    i = YIndex(k);
  } else {
    const int first = twin_->EffectsFirstIndex();
    CHECK(first >= 0 && theta_index >= first)
        << "exposure " << k << " does not depend on theta[" << theta_index << "]";
    i = twin_effect_to_p_[theta_index - first];
  }
  return i;
}

fit::ExposureCostLayout EffectModel::ExposureLayout(int k) const {
  const fit::FitModel& twin = *twin_;
  const std::vector<int> blocks = BlocksOf(k);
  fit::ExposureCostLayout layout;
  for (int b : blocks) layout.blocks.push_back({blocks_[b].begin, blocks_[b].size});
  for (int t : TwinIndicesOf(twin, k)) {
    const int i = TwinToP(t, k);
    for (size_t b = 0; i >= 0 && b < layout.blocks.size(); ++b) {
      const int first = layout.blocks[b].first;
      if (i >= first && i < first + layout.blocks[b].size) {
        layout.place[t] = {static_cast<int>(b), i - first};
      }
    }
  }
  return layout;
}

int EffectModel::FluxIndex(int k) const {
  return spec_.flux == FluxMode::kShared ? shared_flux_ : XIndex(k) + 2;
}

int EffectModel::ShapeIndex(int shared_param) const {
  CHECK(shared_param >= fit::kAiryRadiusPx && shared_param <= fit::kCcdSigmaYPx);
  if (shared_param == fit::kAiryRadiusPx) return shape_begin_;
  if (shared_param == fit::kDefocusPx) return spec_.defocus ? shape_begin_ + 1 : -1;
  return shape_begin_ + (shared_param - fit::kAiryRadiusPx) - (spec_.defocus ? 0 : 1);
}

std::vector<int> EffectModel::EffectIndices(EffectKind kind) const {
  std::vector<int> out;
  if (kind == EffectKind::kDefocus) {
    if (spec_.defocus) out.push_back(ShapeIndex(fit::kDefocusPx));
    return out;
  }
  if (kind == EffectKind::kJitter) {
    for (int i : jitter_index_) {
      if (i >= 0) {
        out.push_back(i);
        out.push_back(i + 1);
      }
    }
    return out;
  }
  for (const auto& [k, begin] : effect_begin_) {
    if (k != kind) continue;
    const int np = static_cast<int>(model::DescribeEffect(kind).parameters.size());
    for (int j = 0; j < np; ++j) out.push_back(begin + j);
  }
  return out;
}

std::vector<int> EffectModel::BlocksOf(int k) const {
  std::vector<int> b = {0, 1 + k};
  if (effect_block_ >= 0) b.push_back(effect_block_);
  if (jitter_block_[k] >= 0) b.push_back(jitter_block_[k]);
  return b;
}

std::vector<double> EffectModel::DefaultStart(EffectKind kind) const {
  const model::EffectInfo& info = model::DescribeEffect(kind);
  if (kind == EffectKind::kJitter) {
    // The variances of the Gaussian part.
    return {info.parameters[0].start * info.parameters[0].start,
            info.parameters[1].start * info.parameters[1].start};
  }
  std::vector<double> start;
  for (const model::EffectParameterInfo& q : info.parameters) start.push_back(q.start);
  return start;
}

std::vector<double> EffectModel::FromBaseline(const std::vector<double>& theta) const {
  CHECK_EQ(static_cast<int>(theta.size()), base_.dim());
  std::vector<double> p = start_;
  const int n = num_exposures();
  double mean_sum = 0.0;
  std::vector<double> sums(n);
  for (int k = 0; k < n; ++k) {
    sums[k] = StampSum(base_.stamps()[k]);
    mean_sum += sums[k] / n;
  }
  for (int k = 0; k < n; ++k) {
    const double scale =
        spec_.flux == FluxMode::kShared || mean_sum <= 0 ? 1.0 : sums[k] / mean_sum;
    p[FluxIndex(k)] = theta[fit::kFluxE] * scale;
    p[XIndex(k)] = theta[fit::FitModel::XIndex(k)];
    p[YIndex(k)] = theta[fit::FitModel::YIndex(k)];
  }
  for (int i = fit::kAiryRadiusPx; i <= fit::kCcdSigmaYPx; ++i) {
    const int j = ShapeIndex(i);
    if (j >= 0) p[j] = theta[i];
  }
  for (int i = 0; i < dim(); ++i) p[i] = std::clamp(p[i], lower_[i], upper_[i]);
  return p;
}

std::vector<double> EffectModel::FromOther(const EffectModel& other,
                                           const std::vector<double>& q) const {
  std::vector<double> p = start_;
  for (int i = 0; i < dim(); ++i) {
    const auto it = std::find(other.names().begin(), other.names().end(), names_[i]);
    if (it != other.names().end()) p[i] = q[it - other.names().begin()];
    p[i] = std::clamp(p[i], lower_[i], upper_[i]);
  }
  return p;
}

model::SpotParams EffectModel::SpotFor(const double* p, int k) const {
  std::vector<double> theta(base_.dim(), 0.0);
  theta[fit::kFluxE] = p[FluxIndex(k)];
  for (int i = fit::kAiryRadiusPx; i <= fit::kCcdSigmaYPx; ++i) {
    const int j = ShapeIndex(i);
    // Without the defocus component it is 0: no blur in integrated sampling, no defocus step
    // at all in the 2015 model (pixel_centre_renderer.cc), whose unit-peak F kernel has no
    // useful limit at small widths.
    theta[i] = j >= 0 ? p[j] : 0.0;
  }
  theta[fit::FitModel::XIndex(k)] = p[XIndex(k)];
  theta[fit::FitModel::YIndex(k)] = p[YIndex(k)];
  return base_.SpotFor(theta.data(), k);
}

std::unique_ptr<EffectEvaluator> EffectModel::NewEvaluator() const {
  return std::make_unique<EffectEvaluator>(*this);
}

EffectEvaluator::EffectEvaluator(const EffectModel& model)
    : model_(model), twin_evaluator_(model.fit_twin().NewEvaluator()) {}

bool EffectEvaluator::Render(const double* p, int k, std::vector<double>* model_e,
                             std::vector<double>* charge_e) {
  // The fit's own model image (the residual blocks' too): one drawing of the model.
  const fit::FitModel& twin = model_.fit_twin();
  theta_.resize(twin.dim());
  model_.TwinTheta(p, k, theta_.data());
  std::string why;
  if (!model::ValidSpotParams(twin_evaluator_->renderer_options(), twin.SpotFor(theta_.data(), k),
                              &why) ||
      !twin_evaluator_->ModelImage(theta_.data(), k, &image_, nullptr)) {
    return false;
  }
  for (double v : image_) {
    if (!std::isfinite(v)) return false;
  }
  const double pedestal = twin.PedestalAt(theta_.data());
  if (charge_e != nullptr) {
    charge_e->resize(image_.size());
    for (size_t q = 0; q < image_.size(); ++q) (*charge_e)[q] = image_[q] - pedestal;
  }
  if (model_e != nullptr) *model_e = image_;
  return true;
}

bool EffectEvaluator::Score(const double* p, const std::vector<Image>* data_e,
                            double* log_likelihood, double* chi2) {
  *log_likelihood = 0.0;
  *chi2 = 0.0;
  theta_.resize(model_.fit_twin().dim());
  for (int k = 0; k < model_.num_exposures(); ++k) {
    model_.TwinTheta(p, k, theta_.data());
    double l, c;
    if (!twin_evaluator_->ExposureScore(theta_.data(), k,
                                        data_e != nullptr ? &(*data_e)[k] : nullptr, &l, &c)) {
      *log_likelihood = -INFINITY;
      *chi2 = INFINITY;
      return false;
    }
    *log_likelihood += l;
    *chi2 += c;
  }
  return true;
}

double EffectEvaluator::LogLikelihood(const double* p) {
  double log_likelihood, chi2;
  Score(p, nullptr, &log_likelihood, &chi2);
  return log_likelihood;
}

double EffectEvaluator::ChiSquare(const double* p) {
  double log_likelihood, chi2;
  Score(p, nullptr, &log_likelihood, &chi2);
  return chi2;
}

// The twin's Fisher information (fit::FitEvaluator::AddExposureFisherInformation, the fit's
// own), exposure by exposure at its theta, carried onto p by TwinToP. Empty if an exposure
// cannot be drawn (one left out would make the Laplace sds silently too wide).
std::vector<double> InformationMatrix(const EffectModel& model, const std::vector<double>& p,
                                      const std::vector<Image>* data_e) {
  const fit::FitModel& twin = model.fit_twin();
  const int dim = model.dim(), twin_dim = twin.dim();
  std::vector<double> info(static_cast<size_t>(dim) * dim, 0.0), theta(twin_dim), fisher;
  std::unique_ptr<fit::FitEvaluator> ev = twin.NewEvaluator();
  for (int k = 0; k < model.num_exposures(); ++k) {
    model.TwinTheta(p.data(), k, theta.data());
    fisher.assign(static_cast<size_t>(twin_dim) * twin_dim, 0.0);
    if (!ev->AddExposureFisherInformation(theta.data(), k,
                                          data_e != nullptr ? &(*data_e)[k] : nullptr, &fisher)) {
      return {};
    }
    const std::vector<int> indices = TwinIndicesOf(twin, k);
    for (int a : indices) {
      for (int b : indices) {
        const int i = model.TwinToP(a, k), j = model.TwinToP(b, k);
        if (i >= 0 && j >= 0) info[static_cast<size_t>(i) * dim + j] += fisher[a * twin_dim + b];
      }
    }
  }
  return info;
}

bool FitEffectModel(const EffectModel& model, const std::vector<std::vector<double>>& starts,
                    const EffectFitOptions& options, EffectFitResult* result, std::string* error,
                    const std::vector<Image>* data_e) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = EffectFitResult();
  double best_cost = INFINITY;
  std::vector<double> best;
  std::string best_message, last_message;
  int best_iterations = 0;
  for (const std::vector<double>& start : starts) {
    CHECK_EQ(static_cast<int>(start.size()), model.dim());
    std::vector<double> p = start;
    for (int i = 0; i < model.dim(); ++i) p[i] = std::clamp(p[i], model.lower()[i], model.upper()[i]);
    std::vector<fit::ExposureCostLayout> layouts;
    for (int k = 0; k < model.num_exposures(); ++k) layouts.push_back(model.ExposureLayout(k));
    fit::SolveSettings settings;
    settings.max_iterations = options.max_iterations;
    settings.function_tolerance = options.function_tolerance;
    settings.gradient_tolerance = 1e-10;
    settings.parameter_tolerance = 1e-9;
    settings.threads = options.num_threads;
    const fit::SolveOutcome o = fit::SolveResidualBlocks(model.fit_twin(), layouts, model.lower(),
                                                         model.upper(), settings, data_e, &p);
    ++result->num_starts;
    last_message = o.message;
    // A run stopped by the iteration limit still has a usable point: the evidence compares
    // likelihoods, and a better point can only help the model being tested.
    if (!o.usable) continue;
    if (o.cost < best_cost) {
      best_cost = o.cost;
      best = p;
      best_message = o.message;
      best_iterations = o.iterations;
    }
  }
  if (best.empty()) {
    *error = "the fit of '" + model.spec().Describe() + "' did not converge from any of " +
             std::to_string(starts.size()) + " starting points (" + last_message + ")";
    return false;
  }
  result->p = best;
  result->usable = true;
  result->iterations = best_iterations;
  result->termination = best_message;
  EffectEvaluator(model).Score(best.data(), data_e, &result->log_likelihood, &result->chi2);
  // Censored pixels are bounds: they add no chi^2 and no degree of freedom (as in a fit).
  result->num_pixels = model.base().NumMeasuredPixels();
  result->dof = result->num_pixels - model.dim();
  if (options.laplace && !AddLaplace(model, result, error, data_e)) {
    result->usable = false;
    return false;
  }
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

bool AddLaplace(const EffectModel& model, EffectFitResult* result, std::string* error,
                const std::vector<Image>* data_e) {
  const std::vector<double> info = InformationMatrix(model, result->p, data_e);
  if (info.empty()) {
    *error = "the model's derivatives cannot be evaluated at its best fit (no Laplace "
             "approximation)";
    return false;
  }
  const bool gaussian_defocus = model.spec().defocus &&
                                model.base().options().model.defocus == model::DefocusKind::kGaussian;
  result->laplace = fit::ComputeLaplace(model.names(), model.lower(), model.upper(), result->p,
                                        info, gaussian_defocus);
  return true;
}

std::vector<Image> SimulateData(const EffectModel& model, const std::vector<double>& p,
                                std::mt19937_64& engine) {
  EffectEvaluator ev(model);
  std::vector<Image> out;
  std::vector<double> m, c;
  for (int k = 0; k < model.num_exposures(); ++k) {
    const Stamp& s = model.base().stamps()[k];
    Image d(s.nx(), s.ny(), 0.0);
    CHECK(ev.Render(p.data(), k, &m, &c)) << "SimulateData outside the model's domain";
    const double g = s.gain_e_per_adu;
    const double ceiling = std::floor(std::min(s.saturation_adu, 65535.0));
    for (size_t q = 0; q < d.size(); ++q) {
      const double pedestal = m[q] - c[q];
      const double photo = static_cast<double>(Poisson(std::max(c[q], 0.0), engine)) + pedestal;
      const double read = s.read_noise_e * StandardNormal(engine);
      const double adu = std::clamp(std::nearbyint(s.bias_adu + (photo + read) / g), 0.0, ceiling);
      d.data[q] = (adu - s.bias_adu) * g;
    }
    out.push_back(std::move(d));
  }
  return out;
}

std::vector<double> PeakSignals(const std::vector<Stamp>& stamps) {
  std::vector<double> peaks;
  for (const Stamp& s : stamps) {
    double peak = -INFINITY;
    for (size_t q = 0; q < s.valid.size(); ++q) {
      if (s.valid[q]) peak = std::max(peak, s.electrons.data[q]);
    }
    peaks.push_back(peak);
  }
  return peaks;
}

bool IsMultiIntensity(const std::vector<Stamp>& stamps) {
  if (stamps.size() < 2) return false;
  // Sums over the pixels valid in every stamp (stamps are centred on their peak pixel).
  std::vector<double> sums(stamps.size(), 0.0);
  const size_t n = stamps[0].valid.size();
  for (size_t q = 0; q < n; ++q) {
    bool everywhere = true;
    for (const Stamp& s : stamps) everywhere = everywhere && s.valid.size() == n && s.valid[q];
    if (!everywhere) continue;
    for (size_t k = 0; k < stamps.size(); ++k) sums[k] += stamps[k].electrons.data[q];
  }
  const auto [lo, hi] = std::minmax_element(sums.begin(), sums.end());
  if (*lo > 0 && *hi / *lo > 1.25) return true;
  double t_lo = INFINITY, t_hi = -INFINITY;
  for (const Stamp& s : stamps) {
    if (!std::isfinite(s.info.exptime_s)) continue;
    t_lo = std::min(t_lo, s.info.exptime_s);
    t_hi = std::max(t_hi, s.info.exptime_s);
  }
  return std::isfinite(t_lo) && t_lo > 0 && t_hi / t_lo > 1.01;
}

}  // namespace ccdpsf::diagnose
