// The baseline spot model plus a chosen set of catalogue effects (model/effects.h), as one
// statistical model that can be fitted (MAP with Ceres), evaluated and simulated: the model
// side of `ccdpsf diagnose`. The expected electrons of exposure k are the simulator's
// (simulate.h), the pedestal of a background without shot noise; every pixel is scored by the
// fit's pixel likelihood (fit/pixel_likelihood.h: Gaussian with model-dependent variance for a
// measured pixel, a bound for a censored one, the interval form for coarse ADC steps); chi^2
// and the degrees of freedom count the measured (not censored) pixels.
//
// Parameter vector p: the theta of the fit's own model of the same stamps, sampling and effects
// (fit/fit_model.h: names, order, priors and derivatives; the "fit twin"), less the defocus
// in a spec without it (held at 0: a baseline for which "defocus" is a candidate effect):
//   flux_e, airy_radius_px, defocus_sigma_px (defocus_radius_px for a pillbox),
//   ccd_sigma_x_px, ccd_sigma_y_px, x_px_K, y_px_K, flux_ratio_K (K >= 1, FluxMode::kPerExposure:
//   a multi-intensity set), then every effect's parameters in catalogue order
//   ("<effect>.<parameter>"; jitter: the variances jitter.var_x_px2.K, jitter.var_y_px2.K of
//   every exposure but ModelSpec::jitter_reference).
// Images and derivatives, residual blocks, the solve (fit::SolveResidualBlocks), the
// log-likelihood and chi^2 (fit::FitEvaluator::ExposureScore) and the Laplace information
// (the fit's Fisher information) are the fit twin's. This file holds what diagnose adds: the
// defocus held at 0, the catalogue's starting strengths and the multi-start search.
#ifndef CCDPSF_DIAGNOSE_EFFECT_FIT_H_
#define CCDPSF_DIAGNOSE_EFFECT_FIT_H_

#include <memory>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/laplace.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/image.h"
#include "ccdpsf/model/effects.h"

namespace ccdpsf::diagnose {

class EffectEvaluator;

// kShared or kPerExposure (fit::FluxMode; diagnose does not scale fluxes by exposure time).
using FluxMode = fit::FluxMode;

// Which model: the baseline components and the effects added to it.
struct ModelSpec {
  // The defocus component: true is the paper's model; false holds it at 0 (a baseline
  // without defocus, for which "defocus" is a candidate effect).
  bool defocus = true;
  // Effects in the order they were added (never kDefocus: see `defocus`).
  std::vector<model::EffectKind> effects;
  FluxMode flux = FluxMode::kShared;
  // Exposure whose jitter is fixed at 0 (only with jitter in `effects`).
  int jitter_reference = 0;

  bool Has(model::EffectKind kind) const;
  // "baseline", or "baseline + serial_cti + ipc", ... (defocus named when it was added).
  std::string Describe() const;
};

// The model of a set of stamps under a spec. Holds the stamps (through the fit::FitModel it
// was built on, which must outlive it).
class EffectModel {
 public:
  // `base` supplies the stamps, the model options (sampling, defocus kind) and the baseline
  // priors; it must not be in through-focus mode. Returns nullptr with a one-line reason for a
  // spec the data cannot support (jitter with one exposure, a jitter reference out of range,
  // defocus_offset in integrated sampling or without the defocus, kDefocus in `effects`, a
  // non-Gaussian likelihood, fluxes scaled by exposure time).
  static std::unique_ptr<EffectModel> Create(const fit::FitModel& base, const ModelSpec& spec,
                                             std::string* error);

  const fit::FitModel& base() const { return base_; }
  const ModelSpec& spec() const { return spec_; }
  int dim() const { return static_cast<int>(names_.size()); }
  int num_exposures() const { return base_.num_exposures(); }
  const std::vector<std::string>& names() const { return names_; }
  const std::vector<double>& lower() const { return lower_; }
  const std::vector<double>& upper() const { return upper_; }
  int NumValidPixels() const { return base_.NumValidPixels(); }

  // The fit's model of this spec (see the top of this file), theta in its layout at p (the
  // defocus of a spec without it at 0), and the index in p of a theta index (-1: held at 0).
  const fit::FitModel& fit_twin() const { return *twin_; }
  std::vector<double> TwinTheta(const double* p) const;
  int Index(int theta_index) const { return index_[theta_index]; }
  int XIndex(int k) const { return Index(fit::FitModel::XIndex(k)); }
  int YIndex(int k) const { return Index(fit::FitModel::YIndex(k)); }
  int ShapeIndex(int shared_param) const { return Index(shared_param); }  // fit::SharedParam
  // The parameters of `kind` (empty if absent): for jitter, [var_x.K, var_y.K] over K.
  std::vector<int> EffectIndices(model::EffectKind kind) const;
  // Exposure k's flux at p [e-, or the 2015 peak meta-parameter]: flux_e times its ratio.
  double FluxOf(const std::vector<double>& p, int k) const;

  // p from a theta of `base` (its flux as exposure 0's; flux ratios at those of the stamps'
  // summed signals), every effect at DefaultStart.
  std::vector<double> FromBaseline(const std::vector<double>& theta) const;
  // p of this model from p of another spec on the same stamps: parameters with the same name
  // are copied, the rest take their default start.
  std::vector<double> FromOther(const EffectModel& other, const std::vector<double>& p) const;
  // The starting value of every parameter of `kind`: the catalogue's start (jitter: the
  // variances, its sigmas squared).
  std::vector<double> DefaultStart(model::EffectKind kind) const;

  std::unique_ptr<EffectEvaluator> NewEvaluator() const;

  // Where exposure k's residual block (the fit's own, fit/map_fit.h, on the twin) reads its
  // parameters in p: the fit's layout with the held defocus left out (held at 0).
  fit::ExposureCostLayout ExposureLayout(int k) const;

 private:
  EffectModel(const fit::FitModel& base, const ModelSpec& spec) : base_(base), spec_(spec) {}
  // p from named values: those whose name p has are copied, the rest are the start; clamped.
  std::vector<double> FromNamed(const std::vector<std::string>& names,
                                const std::vector<double>& values) const;

  const fit::FitModel& base_;
  ModelSpec spec_;
  std::unique_ptr<fit::FitModel> twin_;
  std::vector<std::string> names_;
  std::vector<double> lower_, upper_, start_;
  std::vector<int> index_;  // Index: per theta index, its p index or -1
  std::vector<int> theta_;  // per p index, its theta index
};

// Renders the model of an EffectModel; owns scratch space and a renderer, so use one per
// thread.
class EffectEvaluator {
 public:
  explicit EffectEvaluator(const EffectModel& model);

  // Expected electrons of exposure k (stamp-sized, row-major) and the charge part of it
  // (the same without the background pedestal; the shot noise follows it). Either may be
  // null. False (nothing written) if p is outside the renderer's domain. The fit twin's
  // images (fit::FitEvaluator::ModelImage).
  bool Render(const double* p, int k, std::vector<double>* model_e,
              std::vector<double>* charge_e);

  // Gaussian log-likelihood and chi^2 (valid pixels; the fit's, fit::FitEvaluator::
  // ExposureScore) of all stamps, or of `data_e` in their place. False (-infinity, infinity)
  // outside the renderer's domain.
  bool Score(const double* p, const std::vector<Image>* data_e, double* log_likelihood,
             double* chi2);

 private:
  const EffectModel& model_;
  std::unique_ptr<fit::FitEvaluator> twin_evaluator_;
  std::vector<double> theta_, image_;
};

struct EffectFitOptions {
  int max_iterations = 100;
  int num_threads = 1;  // Ceres threads (one residual block per exposure)
  // Convergence: Ceres' function tolerance (relative change of the cost).
  double function_tolerance = 1e-10;
  // The Laplace approximation after the solve (InformationMatrix, about the cost of an
  // iteration); off for refits that only need the point (predictive simulations).
  bool laplace = true;
};

struct EffectFitResult {
  std::vector<double> p;
  double log_likelihood = -INFINITY;
  double chi2 = 0.0;
  int num_pixels = 0;
  int dof = 0;  // pixels - parameters
  bool usable = false;
  int iterations = 0;
  int num_starts = 0;
  std::string termination;
  // Laplace approximation (fit::ComputeLaplace on InformationMatrix, prior-scaled): sd NaN
  // along what the data do not constrain; empty with EffectFitOptions::laplace off.
  fit::LaplaceResult laplace;
  double seconds = 0.0;
};

// MAP of `model` from each of `starts` (each clamped into the bounds); the best usable solve
// wins. Returns false with a one-line reason when none is usable. The stamps' data are
// replaced by `data_e` when it is non-null (one stamp-sized image per exposure, for
// predictive simulations and threshold studies; the masks stay).
bool FitEffectModel(const EffectModel& model, const std::vector<std::vector<double>>& starts,
                    const EffectFitOptions& options, EffectFitResult* result, std::string* error,
                    const std::vector<Image>* data_e = nullptr);

// The Laplace approximation at result->p (for a fit made with EffectFitOptions::laplace
// off). False with a reason when the derivatives cannot be evaluated there.
bool AddLaplace(const EffectModel& model, EffectFitResult* result, std::string* error,
                const std::vector<Image>* data_e = nullptr);

// The information matrix (dim x dim, row-major) at p: the fit's Fisher information
// (fit::FitEvaluator::AddExposureFisherInformation, analytic derivatives), censored and
// interval pixels against data_e (null: the stamps). Empty when an exposure cannot be drawn.
std::vector<double> InformationMatrix(const EffectModel& model, const std::vector<double>& p,
                                      const std::vector<Image>* data_e = nullptr);

// One noisy realisation of the model at p, as the simulator makes it (Poisson shot noise on
// the charge, the pedestal without noise, Gaussian read noise, rounding to whole ADU at the
// stamp's gain and clipping at the stamp's saturation), in bias-subtracted electrons.
std::vector<Image> SimulateData(const EffectModel& model, const std::vector<double>& p,
                                std::mt19937_64& engine);

// The exposures' peak-pixel signals [e-] (largest valid data pixel), and whether they span
// several intensities: their summed signals (over the pixels valid in every stamp, which do
// not change with the spot's sub-pixel position as a peak pixel does, by > 1.25 x alone)
// differ by more than a factor 1.25, or their EXPTIME values by more than 1 %.
std::vector<double> PeakSignals(const std::vector<Stamp>& stamps);
bool IsMultiIntensity(const std::vector<Stamp>& stamps);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_EFFECT_FIT_H_
