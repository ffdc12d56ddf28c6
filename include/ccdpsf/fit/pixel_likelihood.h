// One stamp pixel in the likelihood, whatever the detector did to it: the CCD noise model
// of likelihood.h for an ordinary pixel, the ADC's coarse steps, and censoring.
//
// A pixel expecting m electrons records D = m + noise, noise of variance s^2 = m+ + RN^2
// (m+ = max(m, 0)), rounded by the ADC to whole ADU of h2 = 2h electrons (h = half a step;
// h = 0 for floating-point data) and possibly clipped. What is known of D:
//
//   measured, fine steps      D = d; the rounding adds a uniform error of variance
//                             (2h)^2 / 12 (Sheppard): the Gaussian of likelihood.h, exact to
//                             ~exp(-2 pi^2 (s / 2h)^2) in probability once s >= one step
//   measured, coarse steps    D in [d - h, d + h): P = Phi((d + h - m)/s) - Phi((d - h - m)/s)
//                             (the interval form: used for every pixel of a stamp whose read
//                             noise is below one ADU, where rounding is no longer a small
//                             added variance, e.g. an 8-bit camera)
//   censored at or above      D >= T = d - h (saturation, the ADC's top, a clipped top):
//                             P = Phi((m - T)/s)
//   censored at or below      D <= T = d + h (a black level clipped at the ADC's zero):
//                             P = Phi((T - m)/s)
//
// For the MAP (Ceres, least squares) each pixel gives two residuals r0, r1 with
// 1/2 (r0^2 + r1^2) = -log p + c, c independent of the model:
//   Gaussian   r0 = (d - m)/sigma, r1 = sqrt(log(var/var0) + 1) (as before: map_fit.h);
//   interval   r0 = sign(d - m) sqrt(2 (-log P - L0(s))), r1 = sqrt(2 (L0(s) - L0(s0)) + 1),
//              L0(s) = -log(2 Phi(h/s) - 1) the best -log P at this s (m = d), s0 = RN:
//              r0 behaves like a whitened residual (r0 -> (d - m)/s when s >> h), so the
//              Gauss-Newton steps stay good;
//   censored   r0 = sqrt(-2 log P), r1 = 1 (r0 -> 0 when the model is well beyond T).
// Their derivatives with respect to m, dr/dm, are exact (tested against finite differences),
// and so are those with respect to the datum d at a fixed m, dr/dd: a pedestal P (a bias
// residual, without shot noise) shifts the datum and the expectation alike, so a pixel with a
// pedestal is scored at (d - P, m - P) and d r / d P = -dr/dd (EvaluatePixelWithPedestal).
//
// The pixel's chi^2 (for chi^2/dof and normalised residuals): (d - m)^2 / (s^2 + (2h)^2/12)
// for a measured pixel. A censored pixel is a bound, not a measurement: it adds no chi^2 and
// no degree of freedom (the deviance -2 log P of a pixel near its level has no fixed
// expectation); instead censored_sd says by how many sd the model lies inside the allowed
// side (negative: on the wrong side of the level), and its normalised residual is the signed
// square root of the deviance, for maps.
#ifndef CCDPSF_FIT_PIXEL_LIKELIHOOD_H_
#define CCDPSF_FIT_PIXEL_LIKELIHOOD_H_

#include "ccdpsf/fit/likelihood.h"
#include "ccdpsf/image.h"

namespace ccdpsf::fit {

// The noise of one stamp's pixels.
struct PixelNoise {
  CcdNoise ccd;             // gain, read noise, rounding (for the Gaussian form)
  double half_step_e = 0;   // h [e-]
  bool interval = false;    // coarse steps: measured pixels take the interval form
  double var0 = 0;          // ccd.VarianceE2(0)
  double l0_floor = 0;      // L0(RN) (interval form)
};

// The noise of `stamp`: interval form when its data are integers (adc_step_e > 0) and its
// read noise is below one step.
PixelNoise StampNoise(const Stamp& stamp);

struct PixelValue {
  double log_p = 0;       // log p(pixel | m) under `kind` (censored and interval pixels:
                          // the probability above for either kind)
  double r[2] = {0, 0};   // residuals for Ceres
  double dr_dm[2] = {0, 0};
  double dr_dd[2] = {0, 0};  // d r / d data_e at a fixed expectation
  double chi2 = 0;        // whitened residual squared (0 for censored pixels)
  double normalised = 0;  // (d - m)/sigma, or for a censored pixel the signed sqrt of its
                          // deviance (positive when a saturated pixel's model falls short)
  double censored_sd = INFINITY;  // censored pixels: (m - T)/s above, (T - m)/s below

  // d r[i] / d u for a parameter u that moves the expectation by dm_du, or, when u is the
  // pedestal of EvaluatePixelWithPedestal (which moves the datum's reference, not the
  // charge), -dr_dd[i].
  double ResidualDerivative(int i, double dm_du, bool u_is_pedestal) const {
    return u_is_pedestal ? -dr_dd[i] : dr_dm[i] * dm_du;
  }
};

// Evaluates pixel (data_e, censor) at expectation m. With want_residuals false only log_p,
// chi2 and normalised are computed.
void EvaluatePixel(LikelihoodKind kind, double data_e, Censor censor, double m,
                   const PixelNoise& noise, bool want_residuals, PixelValue* out);

// A pixel whose expectation m holds a pedestal P [e-] without shot noise (the background
// effect, model/effects.h: a bias residual): the likelihood of the datum less P at
// expectation m - P, so that the shot noise follows the charge m - P only, and the censoring
// level moves with the datum. The residuals' derivative with respect to m is then the one at
// expectation m - P (P fixed), and with respect to P (m - P fixed) it is -dr_dd.
void EvaluatePixelWithPedestal(LikelihoodKind kind, double data_e, Censor censor, double m,
                               double pedestal_e, const PixelNoise& noise, bool want_residuals,
                               PixelValue* out);

// log Phi(u), accurate far into both tails.
double LogNormalCdf(double u);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_PIXEL_LIKELIHOOD_H_
