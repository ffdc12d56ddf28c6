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
//   5 + 2K, 6 + 2K       x_px.K, y_px.K: spot centre of exposure K, frame coordinates [px]
// (the paper's joint fit: CCD widths, intensity and defocus shared, one position per
// exposure). Priors are flat within [lower, upper] for every parameter.
#ifndef CCDPSF_FIT_FIT_MODEL_H_
#define CCDPSF_FIT_FIT_MODEL_H_

#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/fit/likelihood.h"
#include "ccdpsf/image.h"
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

struct FitModelOptions {
  model::ModelOptions model;
  LikelihoodKind likelihood = LikelihoodKind::kGaussian;
  PriorRanges priors;
};

// Renders the model of each stamp for a parameter vector; owns scratch space, so use one per
// thread.
class FitEvaluator;

class FitModel {
 public:
  // Builds the model for the given stamps (at least one; all must share a size when more
  // than one). Returns nullptr with a one-line reason on bad input: no stamps, stamps of
  // different sizes, a stamp with no valid pixel, no signal to fit, pixel_centre with a
  // pillbox.
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

  // Index of x_px.K and y_px.K in theta.
  static int XIndex(int k) { return kNumShared + 2 * k; }
  static int YIndex(int k) { return kNumShared + 2 * k + 1; }

  bool InsidePrior(const double* theta) const;

  // The renderer's parameters and pixel grid for exposure k (pixel_centre works on stamp
  // indices, so its centre is shifted by the stamp origin).
  model::SpotParams SpotFor(const double* theta, int k) const;
  model::PixelGrid GridFor(int k) const;

  // A starting point from the stamps' moments (centroid, summed signal, second moments
  // split between defocus and CCD kernel), for the given Airy radius and share of the
  // Gaussian width given to the defocus (0..1).
  std::vector<double> MomentStart(double airy_radius_px, double defocus_share) const;

  std::unique_ptr<FitEvaluator> NewEvaluator() const;

 private:
  FitModel() = default;
  std::vector<Stamp> stamps_;
  FitModelOptions options_;
  std::vector<std::string> names_;
  std::vector<double> lower_, upper_;
  std::vector<double> centroid_x_, centroid_y_;  // frame coordinates, per stamp
  double signal_e_ = 0.0;                        // mean summed signal per stamp
};

class FitEvaluator {
 public:
  explicit FitEvaluator(const FitModel& model);

  // Log-likelihood of all stamps (without the prior). theta must be inside the prior.
  double LogLikelihood(const double* theta);
  // ... of stamp k alone (LogLikelihood is the sum of these over k). Renders only stamp k.
  double ExposureLogLikelihood(const double* theta, int k);
  // Log-posterior up to a constant: -infinity outside the prior, else the log-likelihood.
  double LogPosterior(const double* theta);

  // Expected electrons of stamp k (row-major, stamp-sized) and, if jacobian != nullptr, its
  // derivatives with respect to theta (pixels x dim, row-major; zero columns for other
  // exposures' positions).
  void ModelImage(const double* theta, int k, std::vector<double>* model,
                  std::vector<double>* jacobian);

  // Fisher information of theta for the Gaussian likelihood with model-dependent variance:
  // sum over valid pixels of g g^T / var + (1/2) h h^T / var^2, g = dm/dtheta, h = dvar/dtheta
  // (= g where m > 0). dim x dim, row-major.
  std::vector<double> FisherInformation(const double* theta);

  // The flux that best fits the data (unweighted least squares over valid pixels, every
  // exposure) for the shape and positions in theta; theta[kFluxE] is ignored. The model is
  // linear in the flux, so this is exact for that criterion. NaN if the model is all zero.
  double LeastSquaresFlux(const double* theta);

  // Sum of squared normalised residuals (chi^2) over valid pixels.
  double ChiSquare(const double* theta);

 private:
  // Renders exposures [first, last) at theta and calls visit(data_e, model_e, noise) for each
  // valid pixel: the one loop behind the log-likelihood, chi^2 and least-squares flux.
  template <typename Visit>
  void ForEachValidPixel(const double* theta, int first, int last, Visit visit);

  const FitModel& fit_model_;
  model::SpotRenderer renderer_;
  std::vector<double> pixels_, spot_jacobian_;
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_MODEL_H_
