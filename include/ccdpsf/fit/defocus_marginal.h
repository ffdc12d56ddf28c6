// The Gaussian-defocus / CCD-width split, integrated out exactly.
//
// In `integrated` sampling with a Gaussian defocus the model depends on the defocus d and the
// CCD widths sigma_x, sigma_y only through the total widths t_x = sqrt(sigma_x^2 + d^2),
// t_y = sqrt(sigma_y^2 + d^2) (two Gaussians make one; docs/trust.md, single focus). With flat
// priors on d, sigma_x, sigma_y the prior density of (d, t_x, t_y) is the Jacobian
//
//   J(d) = t_x t_y / (sigma_x sigma_y) = t_x t_y / sqrt((t_x^2 - d^2) (t_y^2 - d^2))
//
// on the d allowed by the bounds, so the posterior factorises: p(t, rest | data) carries the
// weight W(t) = integral of J(d) dd over the allowed d, and d | t, data has density J(d) / W(t)
// whatever the data. The sampler therefore walks (t_x, t_y) with log W added and draws d
// afterwards from its exact conditional: the flat ridge along d, on which ensemble moves mix
// slowly, is gone from the chain.
//
// Numerics: with d = t_m tanh(w), t_m = min(t_x, t_y) and t_M = max, J(d) dd becomes
//   f(w) dw = t_M t_m sech(w) / sqrt(t_M^2 - t_m^2 tanh^2(w)) dw,
// which is smooth and bounded (it is the constant t_m when t_x = t_y), so Gauss-Legendre
// quadrature in w converges fast; the singularity of J at d -> t_m is mapped to w -> inf,
// and the bound sigma >= sigma_min > 0 keeps w finite.
#ifndef CCDPSF_FIT_DEFOCUS_MARGINAL_H_
#define CCDPSF_FIT_DEFOCUS_MARGINAL_H_

namespace ccdpsf::fit {

// Flat-prior bounds [px] of the three widths.
struct WidthBounds {
  double defocus_lower = 0.0, defocus_upper = 1.5;
  double sigma_x_lower = 0.05, sigma_x_upper = 1.5;
  double sigma_y_lower = 0.05, sigma_y_upper = 1.5;
};

// The defocus values [lower, upper] that keep d, sigma_x and sigma_y inside their bounds for
// total widths (t_x, t_y) [px]; false when there are none.
bool AllowedDefocus(double t_x, double t_y, const WidthBounds& bounds, double* lower,
                    double* upper);

// W(t) = integral of J(d) over [lower, upper] [px] (needs upper < min(t_x, t_y)); relative
// accuracy ~1e-12 (64-point Gauss-Legendre in w; checked against brute force in the tests).
double DefocusMarginalWeight(double t_x, double t_y, double lower, double upper);

// The defocus with conditional CDF u in [0, 1] (inverse-CDF sampling of J(d) / W(t) on
// [lower, upper]): tabulated on 48 panels in w with 3-point Gauss-Legendre each, then inverted
// with f linear across the panel (error of the CDF ~1e-5, far below Monte-Carlo noise).
double DefocusQuantile(double t_x, double t_y, double lower, double upper, double u);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_DEFOCUS_MARGINAL_H_
