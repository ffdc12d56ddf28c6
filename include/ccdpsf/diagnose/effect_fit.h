// The baseline spot model plus a chosen set of catalogue effects (model/effects.h), as one
// statistical model that can be fitted (MAP with Ceres), evaluated and simulated: the model
// side of `ccdpsf diagnose`.
//
// The expected electrons of exposure k are those of the simulator (simulate.h):
//
//   charge_k = ApplyChargeEffects( RenderSpotWithKernelEffects(spot_k, kernel effects) )
//   model_k  = charge_k + pedestal                       (the background, if in the model)
//
// with the noise model of fit/likelihood.h on the charge only (the pedestal is a bias
// residual without shot noise, as the simulator makes it): var = charge + RN^2 + g^2 / 12.
// Each pixel is scored by the fit's own pixel likelihood (fit/pixel_likelihood.h), applied
// to the datum less the pedestal at expectation = the charge: the Gaussian with
// model-dependent variance (the paper's) for a measured pixel, a bound for a censored
// (saturated) one, the interval form for coarse ADC steps; the fit minimises
// 1/2 sum (r0^2 + r1^2) of its residuals, as fit/map_fit.h does, so cost = -log L + constant,
// and chi^2 and the degrees of freedom count the measured (not censored) pixels.
//
// Parameter vector p (names as in fit.json; order fixed by the spec):
//   flux_e                      shared flux (FluxMode::kShared; as fit/fit_model.h: the
//                               total electrons, or the 2015 peak meta-parameter m)
//   airy_radius_px, defocus_sigma_px (defocus_radius_px for a pillbox), ccd_sigma_x_px,
//   ccd_sigma_y_px              shared; the CCD widths are those at zero signal when
//                               brighter_fatter is in the model
//   x_px_K, y_px_K [, flux_e.K] per exposure (flux_e.K with FluxMode::kPerExposure: a
//                               multi-intensity set)
//   <effect>.<parameter>        the catalogue's parameters of every effect in the spec except
//                               jitter, in the spec's order (e.g. serial_cti.trail_fraction)
//   jitter.var_x_px2.K, jitter.var_y_px2.K
//                               jitter, per exposure K except the reference exposure: the
//                               jitter VARIANCE [px^2] (sigma^2: a regular parameter at 0,
//                               where d model / d sigma vanishes). A jitter common to every
//                               exposure is exactly a change of the CCD widths, so only the
//                               excess over the reference exposure (the sharpest, see
//                               fit::SharpestExposure) is identified; its own jitter is absorbed in
//                               the CCD widths. The Gaussian part only: motion blur is not
//                               fitted.
// Priors: flat. Baseline ranges from fit::PriorRanges (via the fit::FitModel this is built
// on), effect ranges from the catalogue's prior_lower / prior_upper (jitter variance:
// [0, prior_upper^2]). Bounds are Ceres parameter bounds.
//
// Images and derivatives: the fit's own model draws every image and its analytic
// derivatives (fit::FitEvaluator::ModelImageColumns on a fit::FitModel with the same stamps,
// sampling, effects and jitter reference: the "fit twin"), in both samplings, so that
// diagnose and fit draw and differentiate one model. Its residual blocks, its solve
// (fit::SolveResidualBlocks), its log-likelihood and chi^2 (fit::FitEvaluator::ExposureScore)
// and its Laplace information (the fit's Fisher information) are the fit's too. This file
// holds diagnose's layout of the parameters (a spec without the defocus, per-exposure
// fluxes) and its multi-start search.
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

enum class FluxMode { kShared, kPerExposure };
std::string ToString(FluxMode mode);

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
  // non-Gaussian likelihood).
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

  // Indices into p. Flux: the shared index in kShared mode, else exposure k's.
  int FluxIndex(int k) const;
  int XIndex(int k) const { return exposure_begin_ + exposure_size_ * k; }
  int YIndex(int k) const { return XIndex(k) + 1; }
  int ShapeIndex(int shared_param) const;  // fit::SharedParam except kFluxE
  // The parameters of `kind` (empty if absent): for jitter, [var_x.K, var_y.K] over K.
  std::vector<int> EffectIndices(model::EffectKind kind) const;

  // Ceres parameter blocks as contiguous segments [begin, begin + size) of p, and the blocks
  // exposure k's residuals depend on.
  struct Block {
    int begin;
    int size;
  };
  const std::vector<Block>& blocks() const { return blocks_; }
  std::vector<int> BlocksOf(int k) const;

  // p from a baseline theta of fit::FitModel layout (its shared flux; per-exposure fluxes
  // scaled by each stamp's share of the summed signal), every effect at DefaultStart.
  std::vector<double> FromBaseline(const std::vector<double>& theta) const;
  // p of this model from p of another spec on the same stamps: parameters with the same name
  // are copied, the rest take their default start.
  std::vector<double> FromOther(const EffectModel& other, const std::vector<double>& p) const;
  // The starting value of every parameter of `kind`: the catalogue's start (jitter: the
  // variances, its sigmas squared).
  std::vector<double> DefaultStart(model::EffectKind kind) const;

  // The renderer's spot parameters of exposure k at p (before any kernel effect).
  model::SpotParams SpotFor(const double* p, int k) const;

  std::unique_ptr<EffectEvaluator> NewEvaluator() const;

  // The fit's model of this spec (see the top of this file); theta for exposure k at p in its
  // layout (shared flux: exposure k's own flux; the jitter variances with the same reference
  // exposure), and for a theta index exposure k depends on, the p index equal to it (-1: held
  // at 0, the defocus of a spec without it).
  const fit::FitModel& fit_twin() const { return *twin_; }
  void TwinTheta(const double* p, int k, double* theta) const;
  int TwinToP(int theta_index, int k) const;
  // Where exposure k's residual block (the fit's own, fit/map_fit.h, on the twin) reads its
  // parameters in p: each twin theta index the exposure depends on sits at the p index
  // TwinToP gives, in the blocks BlocksOf(k); the defocus of a spec without it is held at 0.
  fit::ExposureCostLayout ExposureLayout(int k) const;

 private:
  EffectModel(const fit::FitModel& base, const ModelSpec& spec) : base_(base), spec_(spec) {}
  void Add(const std::string& name, double lower, double upper, double start);

  const fit::FitModel& base_;
  ModelSpec spec_;
  std::vector<std::string> names_;
  std::vector<double> lower_, upper_, start_;
  std::vector<Block> blocks_;
  int shared_flux_ = -1;       // index of flux_e in kShared mode
  int shape_begin_ = 0;        // airy_radius_px, then defocus, sigma_x, sigma_y
  int exposure_begin_ = 0;     // x_px_0
  int exposure_size_ = 2;      // 2 or 3 (with flux_e.K)
  std::vector<std::pair<model::EffectKind, int>> effect_begin_;  // non-jitter effects
  std::vector<int> jitter_index_;  // per exposure: var_x index, or -1 for the reference
  int effect_block_ = -1;          // block index of the shared effect parameters
  std::vector<int> jitter_block_;  // per exposure: block index, or -1
  std::unique_ptr<fit::FitModel> twin_;
  std::vector<int> twin_effect_to_p_;  // theta index - twin's first effect index -> p index
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
  double LogLikelihood(const double* p);
  double ChiSquare(const double* p);

 private:
  const EffectModel& model_;
  std::unique_ptr<fit::FitEvaluator> twin_evaluator_;
  std::vector<double> model_buf_, theta_, image_;
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
