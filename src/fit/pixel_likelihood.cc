// One pixel's likelihood and residuals (pixel_likelihood.h).
#include "ccdpsf/fit/pixel_likelihood.h"

#include <algorithm>
#include <cmath>

namespace ccdpsf::fit {
namespace {

constexpr double kLogSqrt2Pi = 0.91893853320467274178;  // 0.5 log(2 pi)
constexpr double kSqrt2 = 1.41421356237309504880;

double LogNormalPdf(double u) { return -0.5 * u * u - kLogSqrt2Pi; }

// log(Phi(b) - Phi(a)) for a < b, without cancellation in either tail.
double LogIntervalProbability(double a, double b) {
  if (a >= 0.0) {
    const double upper = LogNormalCdf(-a), lower = LogNormalCdf(-b);
    return upper + std::log1p(-std::exp(lower - upper));
  }
  if (b <= 0.0) {
    const double upper = LogNormalCdf(b), lower = LogNormalCdf(a);
    return upper + std::log1p(-std::exp(lower - upper));
  }
  return std::log1p(-(0.5 * std::erfc(-a / kSqrt2) + 0.5 * std::erfc(b / kSqrt2)));
}

// L0(s) = -log(2 Phi(h / s) - 1) = -log erf(h / (s sqrt 2)), and dL0/ds.
void BestInterval(double h, double s, double* l0, double* dl0_ds) {
  const double x = h / (s * kSqrt2);
  const double e = std::erf(x);
  *l0 = -std::log(e);
  *dl0_ds = kSqrt2 * h * std::exp(-x * x) / (std::sqrt(M_PI) * s * s * e);
}

// The read noise is floored here for the interval and censored forms only: at RN = 0 a dark
// pixel recorded one step up would have probability 0 and stop the fit. A tenth of a step
// is indistinguishable from zero in such data (the probability of a dark pixel leaving its
// step is then < 1e-23).
constexpr double kMinSdInSteps = 0.1;

double IntervalSd(const PixelNoise& noise, double m) {
  const double rn = noise.ccd.read_noise_e;
  const double floor = kMinSdInSteps * 2.0 * noise.half_step_e;
  return std::max(std::sqrt(std::max(m, 0.0) + rn * rn), floor);
}

}  // namespace

double LogNormalCdf(double u) {
  if (u > 5.0) return std::log1p(-0.5 * std::erfc(u / kSqrt2));
  if (u > -37.0) return std::log(0.5 * std::erfc(-u / kSqrt2));
  // Asymptotic series of the Mills ratio: Phi(u) = phi(u) / |u| (1 - 1/u^2 + 3/u^4 - ...).
  const double u2 = u * u;
  return LogNormalPdf(u) - std::log(-u) + std::log1p(-1.0 / u2 + 3.0 / (u2 * u2) - 15.0 / (u2 * u2 * u2));
}

PixelNoise StampNoise(const Stamp& stamp) {
  PixelNoise n;
  n.ccd.gain_e_per_adu = stamp.gain_e_per_adu;
  n.ccd.read_noise_e = stamp.read_noise_e;
  n.ccd.include_quantisation = true;
  n.half_step_e = 0.5 * stamp.adc_step_e;
  n.interval = stamp.adc_step_e > 0.0 && stamp.read_noise_e < stamp.adc_step_e;
  n.var0 = n.ccd.VarianceE2(0.0);
  if (n.interval) {
    double unused = 0.0;
    BestInterval(n.half_step_e, IntervalSd(n, 0.0), &n.l0_floor, &unused);
  }
  return n;
}

void EvaluatePixel(LikelihoodKind kind, double d, Censor censor, double m, const PixelNoise& noise,
                   bool want_residuals, PixelValue* out) {
  const double h = noise.half_step_e;
  if (censor == Censor::kNone && !noise.interval) {
    // The Gaussian of likelihood.h (the MAP's residuals are always this form; the posterior
    // uses `kind`).
    const double var = noise.ccd.VarianceE2(m);
    const double sigma = std::sqrt(var);
    const double r = d - m;
    out->log_p = PixelLogLikelihood(kind, d, m, noise.ccd);
    out->normalised = r / sigma;
    out->chi2 = r * r / var;
    if (!want_residuals) return;
    const double r1 = std::sqrt(std::log(var / noise.var0) + 1.0);
    out->r[0] = out->normalised;
    out->r[1] = r1;
    const double dvar_dm = m > 0 ? 1.0 : 0.0;
    out->dr_dm[0] = -1.0 / sigma - r / (2.0 * var * sigma) * dvar_dm;
    out->dr_dm[1] = dvar_dm / (2.0 * var * r1);
    out->dr_dd[0] = 1.0 / sigma;
    out->dr_dd[1] = 0.0;
    return;
  }

  const double s = IntervalSd(noise, m);
  const double ds_dm = m > 0 && s > kMinSdInSteps * 2.0 * h ? 0.5 / s : 0.0;
  // d/dm of (c - m) / s for a fixed c: -1/s - ((c - m)/s) s'/s.
  auto slope = [&](double u) { return -1.0 / s - u * ds_dm / s; };

  if (censor == Censor::kNone) {
    // Interval form: D in [d - h, d + h).
    const double b = (d + h - m) / s, a = (d - h - m) / s;
    const double log_p = LogIntervalProbability(a, b);
    out->log_p = log_p;
    const double var_eff = s * s + (2.0 * h) * (2.0 * h) / 12.0;
    out->normalised = (d - m) / std::sqrt(var_eff);
    out->chi2 = (d - m) * (d - m) / var_eff;
    if (!want_residuals) return;
    double l0 = 0.0, dl0_ds = 0.0;
    BestInterval(h, s, &l0, &dl0_ds);
    const double excess = std::max(0.0, -log_p - l0);
    const double dlogp_dm =
        std::exp(LogNormalPdf(b) - log_p) * slope(b) - std::exp(LogNormalPdf(a) - log_p) * slope(a);
    const double dexcess_dm = -dlogp_dm - dl0_ds * ds_dm;
    // a and b both move by 1/s per unit of d; L0 does not depend on d.
    const double dexcess_dd =
        -(std::exp(LogNormalPdf(b) - log_p) - std::exp(LogNormalPdf(a) - log_p)) / s;
    const double sign = d >= m ? 1.0 : -1.0;
    out->r[0] = sign * std::sqrt(2.0 * excess);
    if (excess > 1e-12) {
      out->dr_dm[0] = sign * dexcess_dm / std::sqrt(2.0 * excess);
      out->dr_dd[0] = sign * dexcess_dd / std::sqrt(2.0 * excess);
    } else {
      // At m = d the excess has a double zero: r0 ~ sqrt(c) (d - m), with c its curvature
      // there at fixed s, 2 (h/s) phi(h/s) / (s^2 (2 Phi(h/s) - 1)).
      const double x = h / s;
      const double curvature = 2.0 * x * std::exp(LogNormalPdf(x)) / (s * s * std::erf(x / kSqrt2));
      out->dr_dm[0] = -std::sqrt(curvature);
      out->dr_dd[0] = std::sqrt(curvature);
    }
    const double r1 = std::sqrt(std::max(0.0, 2.0 * (l0 - noise.l0_floor)) + 1.0);
    out->r[1] = r1;
    out->dr_dm[1] = dl0_ds * ds_dm / r1;
    out->dr_dd[1] = 0.0;
    return;
  }

  // Censored: D >= T (at or above) or D <= T (at or below). u is the standardised distance
  // by which the model lies inside the allowed side.
  const bool above = censor == Censor::kAtOrAbove;
  const double threshold = above ? d - h : d + h;
  const double u = above ? (m - threshold) / s : (threshold - m) / s;
  const double du_dm = above ? -slope((threshold - m) / s) : slope(u);
  const double du_dd = above ? -1.0 / s : 1.0 / s;  // the level moves with the datum
  const double log_p = LogNormalCdf(u);
  out->log_p = log_p;
  const double deviance = std::max(0.0, -2.0 * log_p);
  // A bound is not a measurement: no chi^2 (its deviance has no fixed expectation near the
  // level); how far the model lies on the wrong side is censored_sd.
  out->chi2 = 0.0;
  out->censored_sd = u;
  // Data minus model: positive when a saturated pixel's model falls short of the level.
  const double short_of = above ? (m < threshold ? 1.0 : -1.0) : (m > threshold ? -1.0 : 1.0);
  out->normalised = short_of * std::sqrt(deviance);
  if (!want_residuals) return;
  const double r0 = std::sqrt(deviance);
  out->r[0] = r0;
  out->r[1] = 1.0;
  out->dr_dm[1] = 0.0;
  out->dr_dd[1] = 0.0;
  // d(-log P)/dm = -lambda(u) u', lambda = phi/Phi; dr0/dm = d(-log P)/dm / r0.
  if (r0 > 1e-150) {
    const double lambda = std::exp(LogNormalPdf(u) - log_p);
    out->dr_dm[0] = -lambda * du_dm / r0;
    out->dr_dd[0] = -lambda * du_dd / r0;
  } else {
    out->dr_dm[0] = 0.0;
    out->dr_dd[0] = 0.0;
  }
}

void EvaluatePixelWithPedestal(LikelihoodKind kind, double data_e, Censor censor, double m,
                               double pedestal_e, const PixelNoise& noise, bool want_residuals,
                               PixelValue* out) {
  EvaluatePixel(kind, data_e - pedestal_e, censor, m - pedestal_e, noise, want_residuals, out);
}

}  // namespace ccdpsf::fit
