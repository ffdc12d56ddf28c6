// The forward model of one spot-projection exposure (docs/conventions.md):
//
//   M = [ Airy(flux, x, y, r) (*) D(defocus) ] (*) G_ccd(sigma_x, sigma_y), on the pixel grid
//
// Airy: astropy AiryDisk2D convention, I(d) = A [2 J1(k d) / (k d)]^2 with k = pi Rz / r,
//   r the radius of the first dark ring [px] and Rz = 1.2196698912665045. Its integral over
//   the plane is 4 pi A / k^2; in `integrated` sampling the amplitude A is set so that this
//   integral equals flux_e, the total electrons of the continuous image.
// D: a unit-integral symmetric Gaussian of sigma defocus_px (the paper), or a unit-integral
//   uniform disc (pillbox) of radius defocus_px.
// G_ccd: an axis-aligned unit-integral Gaussian, sigmas ccd_sigma_x_px, ccd_sigma_y_px.
//
// Two samplings:
//   kIntegrated   each pixel holds the exact integral of the continuous image over its unit
//                 square (the default; the physics).
//   kPixelCentre  the discretisation of the authors' 2015 code (docs/conventions.md, Sampling),
//                 on stamp indices, parameterised by the peak meta-parameter m instead of the
//                 flux. Kept so results can be compared with the paper's.
#ifndef CCDPSF_MODEL_SPOT_MODEL_H_
#define CCDPSF_MODEL_SPOT_MODEL_H_

#include <array>
#include <string>

namespace ccdpsf::model {

// First zero of J1(pi x): r / Rz is the Airy length scale (astropy's AiryDisk2D constant).
constexpr double kAiryRz = 1.2196698912665045;

enum class Sampling { kIntegrated, kPixelCentre };
enum class DefocusKind { kGaussian, kPillbox };

// Parses "integrated" / "pixel_centre" and "gaussian" / "pillbox". Return false on anything
// else and leave the output untouched.
bool ParseSampling(const std::string& text, Sampling* sampling);
bool ParseDefocusKind(const std::string& text, DefocusKind* kind);
std::string ToString(Sampling sampling);
std::string ToString(DefocusKind kind);

// Which model: chosen once per run.
struct ModelOptions {
  Sampling sampling = Sampling::kIntegrated;
  DefocusKind defocus = DefocusKind::kGaussian;
  // Integrated sampling only: the quadrature is refined until its error bound, relative to
  // the total flux, is below this. 1e-10 keeps every pixel well inside 1e-6 of the peak pixel.
  double relative_tolerance = 1e-10;
  // Integrated sampling only: the width [px] of each pixel's collecting window, centred on the
  // pixel, along each axis: 1 collects the whole pixel (the paper's model); less models a pixel
  // response narrower than the pixel (charge landing near the edges lost), an alternative
  // `ccdpsf diagnose` tests. In (0, 1].
  double pixel_response_width = 1.0;
};

// Parameters of one spot, in the order used by every Jacobian in the project.
enum SpotParam {
  kFlux = 0,        // integrated: total electrons [e-]; pixel_centre: peak meta-parameter m [e-]
  kCentreX = 1,     // Airy (and defocus) centre [px], in the coordinates of the pixel grid
  kCentreY = 2,
  kAiryRadius = 3,  // radius of the first dark ring [px]
  kDefocus = 4,     // Gaussian sigma or pillbox radius [px]
  kCcdSigmaX = 5,   // CCD diffusion kernel sigma along x (serial) [px]
  kCcdSigmaY = 6,   // ... along y (parallel) [px]
  kNumSpotParams = 7
};

using SpotParams = std::array<double, kNumSpotParams>;

// The pixels a model is rendered onto: pixel (i, j), 0 <= i < nx, 0 <= j < ny, is centred
// at (x0 + i, y0 + j) in the coordinates the spot centre is given in. pixel_centre sampling
// works on stamp indices and requires x0 = y0 = 0.
struct PixelGrid {
  int nx = 21;
  int ny = 21;
  double x0 = 0.0;
  double y0 = 0.0;
  int size() const { return nx * ny; }
};

// Domain limits of integrated sampling: the quadrature's node spacing shrinks with the
// smallest Gaussian width and the Airy radius, so vanishing values would need unbounded work.
// Both are far below anything a CCD273 spot shows (widths ~0.3-0.5 px, radius ~0.5 px).
constexpr double kMinGaussianWidthPx = 0.05;
constexpr double kMinAiryRadiusPx = 0.05;

// Checks that the parameters are inside the model's domain (finite, flux >= 0, radius > 0,
// widths >= 0, and for integrated sampling a total Gaussian width > 0 on each axis). Returns
// false with a one-line reason otherwise.
bool ValidSpotParams(const ModelOptions& options, const SpotParams& params, std::string* error);

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_SPOT_MODEL_H_
