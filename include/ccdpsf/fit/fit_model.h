// The statistical model of a fit: which parameters, their flat priors, and the likelihood of
// a set of calibrated stamps. A single-exposure fit is the one-stamp case of the joint fit.
//
// Parameter vector theta (the order of every vector and matrix in fit/):
//   0 flux_e             total electrons (integrated) or peak_e, the 2015 meta-parameter m
//                        (pixel_centre)                                      shared
//   1 airy_radius_px     first dark ring [px]                                shared
//   2 defocus_sigma_px   Gaussian defocus sigma, or defocus_radius_px (pillbox) [px]  shared
//   3 ccd_sigma_x_px     CCD kernel [px]                                     shared
//   4 ccd_sigma_y_px                                                         shared
//   5 + 2K, 6 + 2K       x_px_K, y_px_K: spot centre of exposure K, frame coordinates [px]
// (the paper's joint fit: CCD widths, intensity and defocus shared, one position per
// exposure). Priors are flat within [lower, upper] for every parameter, except those a
// Gaussian prior names (FitModelOptions::gaussian_prior, gaussian_prior.h): their prior is
// that normal truncated to their flat ranges.
//
// Effects (FitModelOptions::effects): each fitted effect of the catalogue (model/effects.h)
// adds its parameters, shared by every exposure, at the very end of theta (after best focus
// and the flux ratios), named "<effect>.<parameter>" (e.g. "serial_cti.trail_fraction"),
// in catalogue order. The expected image of exposure k is then the spot rendered with the
// brighter-fatter widths (CCD widths + slope x the peak pixel of the spot rendered without
// them), through the image effects of effects.h in their order. In pixel_centre sampling
// (the 2015 model, whose flux_e is the peak meta-parameter m) the halo's share is of the
// stamp's summed charge, as the simulator takes it, and defocus_offset (there not a shift)
// centres the 2015 F kernel away from the Airy centre, with its derivatives from the
// renderer (SpotRenderer::RenderWithDefocusOffset).
//
// Jitter is the one effect fitted per exposure: a Gaussian blur shared by every exposure is
// exactly a change of the CCD widths, but one that differs between exposures is not. Its
// place among the effect parameters holds the jitter VARIANCES of every exposure K but the
// reference (the sharpest, JitterReference(); its own jitter is part of the CCD widths):
//   jitter.var_x_px2.K, jitter.var_y_px2.K   [px^2], flat priors [lo^2, hi^2] from the
//                                            sigma_x_px / sigma_y_px ranges,
// and exposure K is drawn with CCD widths sqrt(sigma^2 + v_K) (as model::AdjustSpotParams
// adds jitter). The variance, not the sigma, is the parameter: the model is regular at v = 0,
// where d model / d sigma_jitter vanishes. With brighter_fatter the growth applies first,
// sqrt((sigma + b I)^2 + v_K), I the peak of the spot drawn with the jitter but without the
// growth, as the simulator draws them (exact when the reference has no jitter of its own: its
// jitter then sits inside sigma, before the growth). Needs two or more exposures. Motion blur
// is not fitted.
//
// Through-focus mode (FitModelOptions::through_focus): a series of exposures taken at stage
// positions z_k [um] (FITS keyword FOCUSPOS, Stamp::info.focus_position_um), where the
// geometric defocus grows linearly with the distance from best focus z0 while the CCD kernel
// stays fixed:
//
//   sigma_f,k = defocus_rate_px_per_um * |z_k - z0|      (Gaussian defocus sigma, exposure k)
//
// The layout above is kept (XIndex / YIndex stay valid), index 2 becomes
//   2 defocus_rate_px_per_um   d sigma_f / d|z - z0| [px/um]                    shared
// and ONE more shared parameter follows the positions, at the very end of theta:
//   5 + 2K  best_focus_um      z0, the stage position of best focus [um]      shared
// (FitModel::FocusIndex()). With one focus position and a Gaussian defocus only the total
// widths sqrt(sigma_f^2 + sigma_ccd^2) are identified (docs/trust.md, single focus); over a series
// the total variance sigma_ccd^2 + rate^2 (z_k - z0)^2 changes with z_k while the CCD part
// does not, which identifies the CCD widths. The model depends on sigma_f only through
// sigma_f^2 = rate^2 (z_k - z0)^2, so it is smooth in rate and z0 (also at z_k = z0).
// Priors: rate in [0, defocus_px[1] / (0.5 (z_max - z_min))] (the prior's largest defocus
// reached half the scanned range away from best focus); z0 in [z_min, z_max]: the model
// ASSUMES that best focus lies inside the scanned range (a lab series is taken across it).
// Valid only for integrated sampling with a Gaussian defocus (the 2015 pixel_centre model
// has its own, discretisation-driven, identification, and a pillbox's radius would need its
// own law), with a finite focus position on every stamp and at least 3 distinct positions
// (a parabola in z needs three).
#ifndef CCDPSF_FIT_FIT_MODEL_H_
#define CCDPSF_FIT_FIT_MODEL_H_

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/fit/gaussian_prior.h"
#include "ccdpsf/fit/likelihood.h"
#include "ccdpsf/fit/pixel_likelihood.h"
#include "ccdpsf/image.h"
#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/renderer.h"

namespace ccdpsf::fit {

constexpr int kNumShared = 5;
enum SharedParam {
  kFluxE = 0,
  kAiryRadiusPx = 1,
  kDefocusPx = 2,
  kCcdSigmaXPx = 3,
  kCcdSigmaYPx = 4
};

// Flat prior ranges. Defaults are physical limits for a CCD273-like spot projector:
// the radius and widths span 0.1-1.5 px (the paper's values are 0.3-0.5 px); the CCD widths
// stop at 0.05 px because integrated sampling needs some Gaussian width (spot_model.h); the
// position may wander `position_halfwidth_px` from where the spot was found (the paper saw
// < 0.1 px). The flux range is relative to the stamp's summed signal S: [0.2 S, 5 S].
struct PriorRanges {
  double flux_lower_fraction = 0.2;
  double flux_upper_fraction = 5.0;
  double airy_radius_px[2] = {0.1, 1.5};
  double defocus_px[2] = {0.0, 1.5};
  double ccd_sigma_x_px[2] = {0.05, 1.5};
  double ccd_sigma_y_px[2] = {0.05, 1.5};
  double position_halfwidth_px = 2.0;
};

// How the exposures of a joint fit share the light (flux_e):
//   kShared          one flux for every exposure (the paper's joint fit: one setting)
//   kPerExposure     exposure K's flux is flux_e x flux_ratio_K (K >= 1; flux_e is exposure
//                    0's), the ratios fitted: for exposures whose lamp or shutter differ
//   kExptimeScaled   exposure K's flux is flux_e x t_K / t_0 from the exposure times
//                    (EXPTIME): one rate, for a clean shutter and a stable lamp
enum class FluxMode { kShared, kPerExposure, kExptimeScaled };
bool ParseFluxMode(const std::string& text, FluxMode* mode);
std::string ToString(FluxMode mode);

// An effect of the catalogue (model/effects.h) fitted as a component of the model: its
// parameters are shared by every exposure. `priors` holds a flat range [lower, upper] per
// parameter (EffectParameters order); empty takes the catalogue's prior ranges.
struct FitEffect {
  model::EffectKind kind = model::EffectKind::kSerialCti;
  std::vector<std::array<double, 2>> priors;
};

// Whether `kind` can be a fit component, with the catalogue's one-line reason when not
// (EffectInfo::not_fittable): defocus is the model's own component. (Jitter is fitted per
// exposure: see the top; defocus_offset only in pixel_centre sampling, as FitModel::Create
// says: in integrated sampling it is exactly a shift of the position.)
bool IsFittableEffect(model::EffectKind kind, std::string* why);
// The names of every effect IsFittableEffect allows, in catalogue order, joined by
// `separator`, leaving out those in `except` (a command that fits some of them elsewhere):
// what the commands' help lists, so that a new catalogue entry appears there by itself.
std::string FittableEffectNames(const std::string& separator,
                                const std::vector<model::EffectKind>& except = {});

struct FitModelOptions;
// Whether the options' effects can be fitted in their sampling, with a one-line reason when
// not: defocus_offset only in pixel_centre (FitModel::Create checks it too; the commands
// check it before any output).
bool EffectsFitInSampling(const FitModelOptions& options, std::string* error);

// For the compression check of a set (exposure_set.h): "the model fits brighter_fatter"
// (and/or nonlinearity) when the options fit an effect that changes the core with the
// signal, else "".
std::string SignalDependenceModelled(const FitModelOptions& options);

struct FitModelOptions {
  model::ModelOptions model;
  LikelihoodKind likelihood = LikelihoodKind::kGaussian;
  PriorRanges priors;
  // Fit a through-focus series with the defocus law above (see the top of this file).
  bool through_focus = false;
  FluxMode flux = FluxMode::kShared;
  // Effects fitted with the spot, in any order given; theta holds them in catalogue order.
  std::vector<FitEffect> effects;
  // With jitter: the reference exposure, whose jitter is held at 0; -1 chooses the sharpest
  // (SharpestExposure). Models remade from one another (after outlier masking) keep theirs,
  // so that their theta layouts agree.
  int jitter_reference = -1;
  // A Gaussian prior on named parameters (gaussian_prior.h; empty: every prior flat), e.g.
  // boundary_shift's a_ij from flats (`--ptc`). A model that fits none of its parameters
  // leaves it out (GaussianPriorTerm::Bind); one that fits some but not all is refused.
  GaussianPrior gaussian_prior;
  bool HasEffect(model::EffectKind kind) const;
};

// The options for one exposure of a joint model's set (the seeds and per-exposure points of
// a joint fit): the same, without jitter, which needs two or more exposures.
FitModelOptions SingleExposureOptions(const FitModelOptions& options);

// Whether a model identifies only the total widths, not the CCD widths themselves: integrated
// sampling with a Gaussian defocus at one focus, where the defocus and the CCD kernel
// convolve to one Gaussian (docs/trust.md, single focus). The CCD-only metrics' posteriors
// are then the priors' along that ridge.
bool CcdSplitUnidentified(const FitModelOptions& options);

// Whether a set of stamps can be fitted as a through-focus series: every stamp has a finite
// focus position and there are at least 3 distinct ones. False with a one-line reason.
bool IsFocusSeries(const std::vector<Stamp>& stamps, std::string* why);

class FitModel;
// Whether the data can identify the model's effects, with a one-line reason when not:
// brighter_fatter needs exposures at two or more intensities (summed signals spanning more
// than x1.25), since at one its slope is exactly a change of the CCD widths. For the
// commands, before a fit (the model itself is well defined either way).
bool EffectsIdentifiable(const FitModel& model, std::string* why);

// Renders the model of each stamp for a parameter vector; owns scratch space, so use one per
// thread.
class FitEvaluator;

class FitModel {
 public:
  // Builds the model for the given stamps (at least one; all must share a size when more
  // than one). Returns nullptr with a one-line reason on bad input: no stamps, stamps of
  // different sizes, a stamp with no valid pixel, no signal to fit, pixel_centre with a
  // pillbox; with through_focus, a model other than integrated + Gaussian defocus or stamps
  // that are not a focus series (IsFocusSeries).
  static std::unique_ptr<FitModel> Create(std::vector<Stamp> stamps, const FitModelOptions& options,
                                          std::string* error);

  int dim() const { return static_cast<int>(names_.size()); }
  int num_exposures() const { return static_cast<int>(stamps_.size()); }
  const std::vector<std::string>& names() const { return names_; }
  const std::vector<double>& lower() const { return lower_; }
  const std::vector<double>& upper() const { return upper_; }
  const std::vector<Stamp>& stamps() const { return stamps_; }
  const FitModelOptions& options() const { return options_; }
  int NumValidPixels() const;
  // Valid pixels that are not censored: the ones that count as degrees of freedom.
  int NumMeasuredPixels() const;

  // Index of x_px_K and y_px_K in theta.
  static int XIndex(int k) { return kNumShared + 2 * k; }
  static int YIndex(int k) { return kNumShared + 2 * k + 1; }

  // Parameters after the positions ("trailing"), shared by every exposure: best_focus_um in
  // focus mode, then flux_ratio_1 .. flux_ratio_(K-1) with per-exposure fluxes.
  // Through-focus mode: whether theta carries best_focus_um, and its index (-1 when not in
  // focus mode).
  bool through_focus() const { return options_.through_focus; }
  int FocusIndex() const { return through_focus() ? kNumShared + 2 * num_exposures() : -1; }
  // The starting values of the effect parameters: "no effect" (0) where the prior allows it,
  // else the catalogue default clamped into the prior. Written into theta's effect slots.
  void SetEffectStart(double* theta) const;
  // Per-exposure fluxes: the index of flux_ratio_k (k >= 1), -1 otherwise.
  bool per_exposure_flux() const { return options_.flux == FluxMode::kPerExposure; }
  int RatioIndex(int k) const {
    return per_exposure_flux() && k > 0
               ? kNumShared + 2 * num_exposures() + (through_focus() ? 1 : 0) + (k - 1)
               : -1;
  }
  // Effects: the index in theta of the first parameter of `kind`, -1 when it is not fitted;
  // whether any is; and the effects at theta (parameters read from theta; false when one
  // lies outside its physical domain).
  int EffectIndex(model::EffectKind kind) const { return effect_index_[static_cast<int>(kind)]; }
  bool HasEffects() const { return !options_.effects.empty(); }
  // The number of theta parameters of a fitted effect: its catalogue parameters, or for
  // jitter two per exposure but the reference.
  int EffectSize(model::EffectKind kind) const;
  // Jitter: the exposure whose jitter is held at 0 (-1 without jitter), and the index of
  // exposure k's jitter.var_x_px2.k (var_y follows it; -1 for the reference or without).
  int JitterReference() const { return jitter_reference_; }
  int JitterIndex(int k) const { return jitter_index_.empty() ? -1 : jitter_index_[k]; }
  // The index of the first effect parameter (they run to the end of theta), -1 without.
  int EffectsFirstIndex() const {
    return HasEffects() ? dim() - static_cast<int>(effect_start_.size()) : -1;
  }
  bool EffectsAt(const double* theta, model::ExposureEffects* effects) const;
  // The background's pedestal at theta [e-] (0 when it is not fitted): a bias residual
  // without shot noise, so every pixel is scored with EvaluatePixelWithPedestal
  // (pixel_likelihood.h), as the simulator makes it and diagnose scores it.
  double PedestalAt(const double* theta) const {
    const int i = EffectIndex(model::EffectKind::kBackground);
    return i >= 0 ? theta[i] : 0.0;
  }
  // Exposure k's flux over flux_e: the exposure-time ratio, or its fitted ratio, or 1.
  double FluxScale(const double* theta, int k) const;
  // The fixed part of it (t_k / t_0 when exposure-time scaled, else 1).
  double FixedFluxScale(int k) const { return fixed_flux_scale_[k]; }
  // A starting value of flux_ratio_k: the ratio of the stamps' summed signals.
  double StartFluxRatio(int k) const { return signal_per_stamp_e_[k] / signal_per_stamp_e_[0]; }
  // Shared parameters in theta: kNumShared, then the trailing ones; their indices in theta
  // order (0..4, then FocusIndex(), then the ratios).
  int NumTrailing() const { return dim() - kNumShared - 2 * num_exposures(); }
  int NumSharedParams() const { return kNumShared + NumTrailing(); }
  std::vector<int> SharedIndices() const;
  // Stage position of exposure k [um] (NaN when unknown).
  double FocusPositionUm(int k) const { return stamps_[k].info.focus_position_um; }
  // The defocus of exposure k [px]: theta[kDefocusPx], or in focus mode
  // theta[kDefocusPx] * |z_k - theta[FocusIndex()]|. d_rate / d_z0 (may be null) receive its
  // derivatives with respect to the rate and z0 (0 outside focus mode; at z_k = z0 the
  // derivative in z0 is taken as 0, exact for the model, which depends on sigma_f^2 only).
  double DefocusFor(const double* theta, int k, double* d_rate = nullptr,
                    double* d_z0 = nullptr) const;

  bool InsidePrior(const double* theta) const;
  // The Gaussian prior as bound to theta (inactive without one), and its log density at theta
  // (0 without: the flat priors' constant is left out of every log density, as it is of the
  // log posterior the MCMC walks).
  const GaussianPriorTerm& gaussian_prior() const { return gaussian_prior_; }
  double LogPrior(const double* theta) const { return gaussian_prior_.LogDensity(theta); }
  // The posterior's information for the Laplace approximation: the likelihood's Fisher
  // information (dim x dim, row-major) with the Gaussian prior's precision added.
  std::vector<double> PosteriorInformation(std::vector<double> fisher) const;

  // The renderer's parameters and pixel grid for exposure k (pixel_centre works on stamp
  // indices, so its centre is shifted by the stamp origin).
  model::SpotParams SpotFor(const double* theta, int k) const;
  model::PixelGrid GridFor(int k) const;

  // A starting point from the stamps' moments (centroid, summed signal, second moments
  // split between defocus and CCD kernel), for the given Airy radius and share of the
  // Gaussian width given to the defocus (0..1).
  // Not for focus mode (map_fit.cc builds those starts from MomentGaussianVariances).
  std::vector<double> MomentStart(double airy_radius_px, double defocus_share) const;

  // The Gaussian variance of each exposure from its second moments [px^2] (mean of the x
  // and y axes, less the pixel and an Airy core of the given radius; not clamped): in focus
  // mode the quantity that grows as sigma_ccd^2 + rate^2 (z_k - z0)^2.
  std::vector<double> MomentGaussianVariances(double airy_radius_px) const;
  // boundary_shift's window of stamp k (model/boundary_shift.h): around its centroid's pixel.
  const model::PixelWindow& ShiftWindow(int k) const { return shift_window_[k]; }
  // Frame-coordinate centroid of stamp k [px] (the moment start's position).
  double CentroidX(int k) const { return centroid_x_[k]; }
  double CentroidY(int k) const { return centroid_y_[k]; }

  std::unique_ptr<FitEvaluator> NewEvaluator() const;

 private:
  FitModel() = default;
  std::vector<Stamp> stamps_;
  FitModelOptions options_;
  std::vector<std::string> names_;
  std::vector<double> lower_, upper_;
  std::vector<double> centroid_x_, centroid_y_;  // frame coordinates, per stamp
  std::vector<model::PixelWindow> shift_window_;  // ShiftWindow, per stamp
  std::vector<double> signal_per_stamp_e_;       // summed signal of each stamp
  std::vector<double> fixed_flux_scale_;         // FixedFluxScale
  std::array<int, model::kNumEffectKinds> effect_index_;  // EffectIndex
  std::vector<double> effect_start_;             // theta's effect parameters at a start (no effect)
  int jitter_reference_ = -1;                    // JitterReference
  std::vector<int> jitter_index_;                // JitterIndex, per exposure (empty without)
  GaussianPriorTerm gaussian_prior_;              // options_.gaussian_prior bound to names_
  double signal_e_ = 0.0;                        // mean summed signal per stamp
};

// The exposure whose stamp has the smallest second-moment width (the sharpest; moments as
// MomentGaussianVariances with a 0.5 px Airy radius): the jitter reference.
int SharpestExposure(const FitModel& model);

class FitEvaluator {
 public:
  explicit FitEvaluator(const FitModel& model);
  const model::ModelOptions& renderer_options() const { return renderer_.options(); }

  // Log-likelihood of all stamps (without the prior). theta must be inside the prior.
  double LogLikelihood(const double* theta);
  // ... of stamp k alone (LogLikelihood is the sum of these over k). Renders only stamp k.
  double ExposureLogLikelihood(const double* theta, int k);

  // Expected electrons of stamp k (row-major, stamp-sized) and, if jacobian != nullptr, its
  // derivatives with respect to theta (pixels x dim, row-major; zero columns for other
  // exposures' positions). False (model left unspecified) where the renderer cannot draw
  // theta (a width the brighter-fatter growth takes out of the renderer's domain).
  bool ModelImage(const double* theta, int k, std::vector<double>* model,
                  std::vector<double>* jacobian);
  // The same with the derivatives only for the theta indices exposure k depends on:
  // jacobian is pixels x columns->size(), columns the theta index of each column. The one
  // place a model image is computed (the Ceres residuals use this form).
  bool ModelImageColumns(const double* theta, int k, std::vector<double>* model,
                         std::vector<double>* jacobian, std::vector<int>* columns);

  // The CCD widths [px] exposure k's spot is drawn with at theta: theta's, grown by the
  // brighter-fatter slopes times the peak pixel [e-] of the spot drawn without the growth
  // (model/effects.h; theta's own widths without the effect). False where the spot cannot
  // be drawn.
  bool KernelWidths(const double* theta, int k, double* sigma_x_px, double* sigma_y_px);

  // Fisher information of theta for the Gaussian likelihood with model-dependent variance:
  // sum over valid pixels of g g^T / var + (1/2) h h^T / var^2, g = dm/dtheta, h = dvar/dtheta
  // (= g where m > 0); censored and interval pixels give the Gauss-Newton information of
  // their residuals (observed). dim x dim, row-major; NaN where an image cannot be drawn.
  // With `scores`, the same pass also gives ScoreOuterProducts there.
  std::vector<double> FisherInformation(const double* theta,
                                        std::vector<double>* scores = nullptr);
  // The outer products of the pixels' scores at theta, sum over valid pixels of s s^T with
  // s = d log p(pixel) / d theta (from the residuals: -(r0 dr0 + r1 dr1), pixel_likelihood.h):
  // the "meat" of the misspecification-robust (sandwich) covariance. Its expectation is the
  // Fisher information when the model and its noise are right; where the residuals are
  // larger than the noise model says, it is larger. dim x dim, row-major; NaN where an image
  // cannot be drawn.
  std::vector<double> ScoreOuterProducts(const double* theta);
  // The same for exposure k alone, its censored and interval pixels against `data_e`
  // (stamp-sized; null: the stamp's data); added into *fisher (dim x dim). False where the
  // image cannot be drawn.
  // With `scores`, that exposure's ScoreOuterProducts is added there too (one render).
  bool AddExposureFisherInformation(const double* theta, int k, const Image* data_e,
                                    std::vector<double>* fisher,
                                    std::vector<double>* scores = nullptr);

  // Sets theta[kFluxE] to the least-squares flux of exposures [first, last), clamped to the
  // prior, and returns those exposures' log-likelihood there (-inf if it is not finite). One
  // render per exposure instead of two: the model is linear in the flux. For the screening
  // searches of map_fit.cc.
  double BestFluxLogLikelihood(double* theta, int first, int last);

  // Sum of squared normalised residuals (chi^2) over the valid measured (not censored)
  // pixels (pixel_likelihood.h).
  double ChiSquare(const double* theta);
  // Log-likelihood (of the model's likelihood kind) and chi^2 of exposure k's valid pixels
  // against `data_e` (stamp-sized; null: the stamp's data). False where theta is outside the
  // renderer's domain or the image is not finite.
  bool ExposureScore(const double* theta, int k, const Image* data_e, double* log_likelihood,
                     double* chi2);
  // Censored pixels whose model lies more than `sd` standard deviations on the wrong side of
  // their level (a saturated pixel the model puts well below saturation), and the worst.
  int CensoredViolations(const double* theta, double sd, double* worst_sd);

 private:
  // Renders the spot without the brighter-fatter growth (with effects' defocus offset) into
  // plain_ (with its Jacobian in spot_jacobian_, and the offset's in plain_offset_jacobian_,
  // if want) and returns its brightest pixel's index; -1 if it cannot be drawn.
  int RenderWithoutGrowth(const model::SpotParams& spot, const model::PixelGrid& grid,
                          const model::ExposureEffects& effects, bool want);

  const FitModel& fit_model_;
  model::SpotRenderer renderer_;
  std::vector<double> pixels_, spot_jacobian_, local_jacobian_;
  std::vector<int> columns_;
  // ModelImageColumns' chain from theta to the renderer's parameters, and its nonzero entries.
  struct Link {
    int spot_param, column;
    double value;
  };
  std::vector<double> chain_, plain_chain_;  // plain_chain_: the brighter-fatter signal's
  std::vector<Link> links_;
  std::vector<double> plain_;                     // the brighter-fatter signal's render
  // d image / d (defocus_offset dx, dy), pixels x 2: the image's and plain_'s.
  std::vector<double> offset_jacobian_, plain_offset_jacobian_;
  model::DualImage dual_;                         // image effects with derivatives
  // boundary_shift: the light along the x and y boundaries and at their corners, with
  // derivatives, and the renderer's values and Jacobian of one of them.
  model::BoundaryDensities boundary_densities_;
  // boundary_shift's densities on the exposure's window (x, y, corner) and their Jacobians.
  std::array<std::vector<double>, 3> density_values_, density_jacobian_;
  std::vector<std::vector<double>> unit_models_;  // BestFluxLogLikelihood's renders
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_MODEL_H_
