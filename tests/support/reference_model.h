// An independent, slow, high-accuracy reference for the pixel-integrated spot model
// (docs/conventions.md), used only by tests.
//
// It shares nothing with the renderer: it works in Fourier space, where every factor of
//
//   M = [ Airy(flux, x, y, r) (*) D ] (*) G_ccd(sigma_x, sigma_y), integrated over unit pixels
//
// is a closed-form multiplier. The value of the pixel centred at (X, Y) [px] is
//
//   M(X, Y) = flux * Integral_{rho <= rho_c} OTF(rho) Dhat(rho)
//                      exp(-2 pi^2 (sigma_x^2 u^2 + sigma_y^2 v^2)) sinc(u) sinc(v)
//                      cos(2 pi (u (X - x) + v (Y - y))) du dv
//
// with u, v [cycles/px], rho = hypot(u, v), rho_c = Rz / r, s = rho / rho_c,
//   OTF(rho) = (2/pi) [acos(s) - s sqrt(1 - s^2)]     (the unit-flux Airy intensity's transform)
//   Dhat     = exp(-2 pi^2 sigma_f^2 rho^2)           (Gaussian defocus, sigma_f [px])
//            = 2 J1(2 pi R rho) / (2 pi R rho)         (pillbox defocus, radius R [px])
//   sinc(u)  = sin(pi u) / (pi u)                     (the unit pixel's box).
//
// The integrand is even in u and in v separately, so the integral is 4 times the one over the
// first quadrant with cos(2 pi u dx) cos(2 pi v dy) in place of the cosine of the sum. The
// quadrant is integrated in polar coordinates with composite Gauss-Legendre rules:
//   - radially, the OTF behaves like (1 - s)^(3/2) at the disc edge; the substitution
//     s = 1 - t^2 makes the radial integrand analytic in t (acos(1 - t^2) = 2 asin(t / sqrt 2),
//     s sqrt(1 - s^2) = (1 - t^2) t sqrt(2 - t^2)), so Gauss-Legendre panels in t converge
//     geometrically;
//   - where the Gaussian envelope exp(-2 pi^2 (sigma_min^2 + sigma_f^2) rho^2) makes the rest of
//     the disc negligible (its integral over the plane beyond rho_max is below 1e-17 of the
//     flux), the radial range is cut there;
//   - the panel counts are set from the number of oscillations of the cosines and sincs, and
//     then all doubled (radial and angular) until two successive results agree to
//     `tolerance` (default 1e-12) relative to the flux on every requested pixel. Failure to
//     converge within kMaxLevels doublings is reported in ReferenceResult::converged.
//
// Cost: milliseconds per pixel near the spot, up to ~0.5 s for a corner of a 41 x 41 stamp
// with all widths 0.1 px. Not for use outside tests.
#ifndef CCDPSF_TESTS_SUPPORT_REFERENCE_MODEL_H_
#define CCDPSF_TESTS_SUPPORT_REFERENCE_MODEL_H_

#include <vector>

#include "ccdpsf/model/spot_model.h"

namespace ccdpsf::testing_reference {

// What the Fourier integrand's "pupil" factor is.
enum class Pupil {
  kAiry,         // the circular-pupil OTF, zero beyond rho_c (the model)
  kPointSource,  // OTF = 1 everywhere: a point source; only for self-tests, needs a Gaussian
                 // envelope (some sigma > 0) for the integral to converge
};

struct ReferenceSpot {
  double flux_e = 1.0;      // total electrons of the continuous image [e-]
  double centre_x_px = 0.0;  // spot centre, in the coordinates of the pixel centres [px]
  double centre_y_px = 0.0;
  Pupil pupil = Pupil::kAiry;
  double airy_radius_px = 0.5;  // radius of the first dark ring [px]; unused for kPointSource
  model::DefocusKind defocus_kind = model::DefocusKind::kGaussian;
  double defocus_px = 0.0;  // Gaussian sigma or pillbox radius [px]; 0 means no defocus
  double ccd_sigma_x_px = 0.0;
  double ccd_sigma_y_px = 0.0;
  // Width of each pixel's collecting window [px] (1: the whole pixel). Its box transform is
  // w sinc(w u) per axis in place of sinc(u).
  double pixel_window = 1.0;
  // Where positive, the window's width along x (y) alone, in place of pixel_window: the value
  // is then the integral over a pixel_window_x x pixel_window_y rectangle centred at (X, Y).
  double pixel_window_x = 0.0;
  double pixel_window_y = 0.0;
  // A line instead of the window along x (y): the value at (X, Y) is then the line integral
  // of the image along x = X (y = Y) over the window's extent on the other axis [e- / px],
  // what SpotRenderer::RenderBoundaryDensity gives for a pixel boundary.
  bool line_x = false;
  bool line_y = false;
};

// The spot of the renderer's SpotParams (integrated sampling), in the reference's terms.
ReferenceSpot FromSpotParams(const model::SpotParams& params, model::DefocusKind kind);

struct ReferenceResult {
  std::vector<double> values;  // [e-], row-major: values[j * nx + i] is pixel (i, j)
  bool converged = false;
  int levels = 0;            // number of doublings performed
  double last_change = 0.0;  // max |change| over the pixels at the last doubling [e-]
  long long nodes = 0;       // quadrature nodes evaluated, all levels together
};

// The maximum number of doublings tried before giving up.
constexpr int kMaxLevels = 5;

// Every pixel of an nx x ny grid whose pixel (i, j) is centred at (x0 + i, y0 + j) [px].
// One set of nodes serves all pixels, sized for the farthest, so for a few far-apart pixels
// calling ReferencePixel on each is cheaper.
ReferenceResult ReferenceImage(const ReferenceSpot& spot, int nx, int ny, double x0, double y0,
                               double tolerance = 1e-12);

// The pixel centred at (x, y) [px]: values has one element.
ReferenceResult ReferencePixel(const ReferenceSpot& spot, double x_px, double y_px,
                               double tolerance = 1e-12);

// --- Building blocks, exposed for the self-tests ------------------------------------------

// Gauss-Legendre nodes and weights of order n on [-1, 1], by Newton's method on the Legendre
// polynomial P_n (three-term recurrence). Nodes ascending.
void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights);

// P(a <= Z <= b) for Z ~ N(0, sigma^2), sigma > 0, accurate to a few ulp of the result even
// far in the tails (uses erfc on the side away from the mode).
double GaussianIntervalProbability(double a, double b, double sigma);

// Closed form of a point source of total `flux` blurred by an axis-aligned Gaussian
// (sigma_x, sigma_y > 0) [px] and integrated over the unit pixel whose centre is at offset
// (dx, dy) [px] from the source.
double PixelIntegratedGaussian(double flux, double dx, double dy, double sigma_x,
                               double sigma_y);

// Unit-flux Airy intensity [1/px^2] at distance d [px] from its centre:
// (k^2 / 4 pi) [2 J1(k d) / (k d)]^2 with k = pi Rz / r.
double AiryIntensity(double d_px, double airy_radius_px);

// Fraction of an Airy pattern's energy outside radius d [px]: J0(k d)^2 + J1(k d)^2
// (Lord Rayleigh's encircled-energy formula).
double AiryEnergyOutside(double d_px, double airy_radius_px);

}  // namespace ccdpsf::testing_reference

#endif  // CCDPSF_TESTS_SUPPORT_REFERENCE_MODEL_H_
