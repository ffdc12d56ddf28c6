#include "ccdpsf/diagnose/effect_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/simulate.h"
#include "glog/logging.h"

namespace ccdpsf::diagnose {

using model::EffectKind;

bool ModelSpec::Has(EffectKind kind) const {
  if (kind == EffectKind::kDefocus) return defocus;
  return std::find(effects.begin(), effects.end(), kind) != effects.end();
}

std::string ModelSpec::Describe() const {
  std::string s = defocus ? "baseline" : "baseline without defocus";
  for (EffectKind k : effects) s += " + " + model::ToString(k);
  return s;
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
  if (spec.flux == FluxMode::kExptimeScaled) {
    *error = "diagnose fits one flux, or one per exposure, not fluxes scaled by exposure time";
    return nullptr;
  }
  const int n = base.num_exposures();
  for (EffectKind kind : spec.effects) {
    if (kind == EffectKind::kDefocus) {
      *error = "defocus is a baseline component (ModelSpec::defocus), not an added effect";
      return nullptr;
    }
    if (kind == EffectKind::kDefocusOffset && !spec.defocus) {
      *error = "defocus_offset needs the defocus component in the model";
      return nullptr;
    }
  }
  if (spec.Has(EffectKind::kJitter) && (spec.jitter_reference < 0 || spec.jitter_reference >= n)) {
    *error = "jitter reference exposure out of range";
    return nullptr;
  }
  // The fit twin: the same stamps and effects in the fit's model (its Create refuses an
  // effect given twice, defocus_offset in integrated sampling and jitter with one exposure).
  fit::FitModelOptions twin_options = base.options();
  twin_options.flux = spec.flux;
  twin_options.effects.clear();
  for (EffectKind kind : spec.effects) twin_options.effects.push_back({kind, {}});
  twin_options.jitter_reference = spec.Has(EffectKind::kJitter) ? spec.jitter_reference : -1;
  // No Gaussian prior (gaussian_prior.h; `diagnose` takes no --ptc): diagnose names effects by
  // likelihood ratios, BIC and predictive checks, which compare maximum likelihoods; a prior in
  // the solve would move the points they are taken at.
  twin_options.gaussian_prior = fit::GaussianPrior();
  std::unique_ptr<EffectModel> m(new EffectModel(base, spec));
  m->twin_ = fit::FitModel::Create(base.stamps(), twin_options, error);
  if (m->twin_ == nullptr) return nullptr;
  const fit::FitModel& twin = *m->twin_;
  std::vector<double> start(twin.dim());
  for (int t = 0; t < twin.dim(); ++t) start[t] = 0.5 * (twin.lower()[t] + twin.upper()[t]);
  for (int k = 1; twin.per_exposure_flux() && k < n; ++k) {
    start[twin.RatioIndex(k)] = twin.StartFluxRatio(k);
  }
  for (EffectKind kind : spec.effects) {
    const std::vector<double> s = m->DefaultStart(kind);
    for (int j = 0; j < twin.EffectSize(kind); ++j) {
      start[twin.EffectIndex(kind) + j] = s[j % s.size()];
    }
  }
  m->index_.assign(twin.dim(), -1);
  for (int t = 0; t < twin.dim(); ++t) {
    if (t == fit::kDefocusPx && !spec.defocus) continue;
    m->index_[t] = m->dim();
    m->theta_.push_back(t);
    m->names_.push_back(twin.names()[t]);
    m->lower_.push_back(twin.lower()[t]);
    m->upper_.push_back(twin.upper()[t]);
    m->start_.push_back(std::clamp(start[t], twin.lower()[t], twin.upper()[t]));
  }
  return m;
}

std::vector<double> EffectModel::TwinTheta(const double* p) const {
  std::vector<double> theta(twin_->dim(), 0.0);
  for (int i = 0; i < dim(); ++i) theta[theta_[i]] = p[i];
  return theta;
}

fit::ExposureCostLayout EffectModel::ExposureLayout(int k) const {
  // The fit's blocks without the held parameters: the rest of a block stays contiguous in p,
  // which keeps theta's order.
  fit::ExposureCostLayout layout;
  for (const auto& block : fit::FitExposureCostLayout(*twin_, k).blocks) {
    const int b = static_cast<int>(layout.blocks.size());
    for (int t = block.first; t < block.first + block.size; ++t) {
      if (index_[t] < 0) continue;
      if (static_cast<int>(layout.blocks.size()) == b) layout.blocks.push_back({index_[t], 0});
      layout.place[t] = {b, layout.blocks[b].size++};
    }
  }
  return layout;
}

std::vector<int> EffectModel::EffectIndices(EffectKind kind) const {
  if (kind == EffectKind::kDefocus) {
    return spec_.defocus ? std::vector<int>{Index(fit::kDefocusPx)} : std::vector<int>{};
  }
  std::vector<int> out;
  const int first = twin_->EffectIndex(kind);
  for (int j = 0; first >= 0 && j < twin_->EffectSize(kind); ++j) out.push_back(Index(first + j));
  return out;
}

double EffectModel::FluxOf(const std::vector<double>& p, int k) const {
  return p[Index(fit::kFluxE)] * twin_->FluxScale(TwinTheta(p.data()).data(), k);
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

std::vector<double> EffectModel::FromNamed(const std::vector<std::string>& names,
                                           const std::vector<double>& values) const {
  std::vector<double> p = start_;
  for (int i = 0; i < dim(); ++i) {
    const auto it = std::find(names.begin(), names.end(), names_[i]);
    if (it != names.end()) p[i] = std::clamp(values[it - names.begin()], lower_[i], upper_[i]);
  }
  return p;
}

std::vector<double> EffectModel::FromBaseline(const std::vector<double>& theta) const {
  CHECK_EQ(static_cast<int>(theta.size()), base_.dim());
  return FromNamed(base_.names(), theta);
}

std::vector<double> EffectModel::FromOther(const EffectModel& other,
                                           const std::vector<double>& q) const {
  return FromNamed(other.names(), q);
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
  theta_ = model_.TwinTheta(p);
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
  theta_ = model_.TwinTheta(p);
  for (int k = 0; k < model_.num_exposures(); ++k) {
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

// The twin's Fisher information (fit::FitEvaluator::AddExposureFisherInformation, the fit's
// own) at its theta, less the held defocus. Empty if an exposure cannot be drawn (one left
// out would make the Laplace sds silently too wide).
std::vector<double> InformationMatrix(const EffectModel& model, const std::vector<double>& p,
                                      const std::vector<Image>* data_e) {
  const fit::FitModel& twin = model.fit_twin();
  const int dim = model.dim(), twin_dim = twin.dim();
  const std::vector<double> theta = model.TwinTheta(p.data());
  std::vector<double> fisher(static_cast<size_t>(twin_dim) * twin_dim, 0.0);
  std::unique_ptr<fit::FitEvaluator> ev = twin.NewEvaluator();
  for (int k = 0; k < model.num_exposures(); ++k) {
    const Image* data = data_e != nullptr ? &(*data_e)[k] : nullptr;
    if (!ev->AddExposureFisherInformation(theta.data(), k, data, &fisher)) return {};
  }
  std::vector<double> info(static_cast<size_t>(dim) * dim, 0.0);
  for (int a = 0; a < twin_dim; ++a) {
    for (int b = 0; b < twin_dim; ++b) {
      const int i = model.Index(a), j = model.Index(b);
      if (i >= 0 && j >= 0) info[static_cast<size_t>(i) * dim + j] = fisher[a * twin_dim + b];
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
  std::vector<fit::ExposureCostLayout> layouts;
  for (int k = 0; k < model.num_exposures(); ++k) layouts.push_back(model.ExposureLayout(k));
  for (const std::vector<double>& start : starts) {
    CHECK_EQ(static_cast<int>(start.size()), model.dim());
    std::vector<double> p = start;
    for (int i = 0; i < model.dim(); ++i)
      p[i] = std::clamp(p[i], model.lower()[i], model.upper()[i]);
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
    for (size_t q = 0; q < d.size(); ++q) {
      const double adu = ObservePixelAdu(c[q], m[q] - c[q], s.gain_e_per_adu, s.read_noise_e,
                                         s.bias_adu, s.saturation_adu, engine);
      d.data[q] = (adu - s.bias_adu) * s.gain_e_per_adu;
      // A pixel censored in the data stays censored, at its recorded level: the refits take
      // the stamps' censoring as it is, so the simulations are drawn given that pattern
      // (every draw is a bound there, as the data are).
      if (s.valid[q] && s.CensorAt(q) != Censor::kNone) d.data[q] = s.electrons.data[q];
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
