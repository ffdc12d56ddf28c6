// Tests of one pixel's likelihood (fit/pixel_likelihood.h): the interval and censored forms
// against a direct numerical integral of the normal density, the residuals' defining identity
// 1/2 (r0^2 + r1^2) = -log p + c (c independent of the model), their derivatives against
// central differences, and the far tails.
#include "ccdpsf/fit/pixel_likelihood.h"

#include <cmath>

#include "gtest/gtest.h"

namespace ccdpsf::fit {
namespace {

// P(a <= X < b) for X ~ N(mu, s^2) by composite Simpson over 20000 panels: an independent
// check of the closed forms (error ~ (b-a)^5 / n^4 f'''' , far below the 1e-10 asked).
double SimpsonNormal(double a, double b, double mu, double s) {
  const int n = 20000;
  const double h = (b - a) / n;
  auto f = [&](double x) {
    const double z = (x - mu) / s;
    return std::exp(-0.5 * z * z) / (s * std::sqrt(2 * M_PI));
  };
  double sum = f(a) + f(b);
  for (int i = 1; i < n; ++i) sum += (i % 2 ? 4 : 2) * f(a + i * h);
  return sum * h / 3;
}

// An 8-bit-like stamp: 40 e-/ADU, read noise 5 e- (below one step: interval form).
PixelNoise CoarseNoise() {
  Stamp s;
  s.gain_e_per_adu = 40.0;
  s.read_noise_e = 5.0;
  s.adc_step_e = 40.0;
  return StampNoise(s);
}

PixelNoise FineNoise() {
  Stamp s;
  s.gain_e_per_adu = 3.1;
  s.read_noise_e = 4.5;
  s.adc_step_e = 3.1;
  return StampNoise(s);
}

TEST(PixelLikelihood, NoiseFormIsChosenByReadNoiseAgainstTheStep) {
  EXPECT_TRUE(CoarseNoise().interval);
  EXPECT_FALSE(FineNoise().interval);
  Stamp floating;  // floating-point data: no steps
  floating.read_noise_e = 0.1;
  EXPECT_FALSE(StampNoise(floating).interval);
}

TEST(PixelLikelihood, IntervalFormIsTheProbabilityOfTheStep) {
  const PixelNoise noise = CoarseNoise();
  PixelValue v;
  for (double m : {0.0, 3.0, 25.0, 80.0, 400.0, 5000.0}) {
    for (double d : {0.0, 40.0, 80.0, 400.0, 5040.0}) {
      EvaluatePixel(LikelihoodKind::kGaussian, d, Censor::kNone, m, noise, false, &v);
      const double s = std::sqrt(m + 25.0);
      const double p = SimpsonNormal(d - 20.0, d + 20.0, m, s);
      if (p < 1e-280) continue;  // below what the integral resolves
      EXPECT_NEAR(v.log_p, std::log(p), 1e-8) << "m " << m << " d " << d;
    }
  }
}

TEST(PixelLikelihood, CensoredFormsAreTheTailProbabilities) {
  const PixelNoise noise = CoarseNoise();
  PixelValue v;
  for (double m : {0.0, 30.0, 200.0, 1000.0}) {
    const double s = std::sqrt(m + 25.0);
    // At or above a saturation level recorded as 400 e-: D >= 380.
    EvaluatePixel(LikelihoodKind::kGaussian, 400.0, Censor::kAtOrAbove, m, noise, false, &v);
    const double above = SimpsonNormal(380.0, m + 40 * s, m, s) + 0.5 * std::erfc(40 / std::sqrt(2.0));
    if (above > 1e-280) {
      EXPECT_NEAR(v.log_p, std::log(above), 1e-8) << m;
    }
    EXPECT_EQ(v.chi2, 0.0);  // a bound adds no chi^2
    // At or below a black level recorded as 0: D <= 20.
    EvaluatePixel(LikelihoodKind::kGaussian, 0.0, Censor::kAtOrBelow, m, noise, false, &v);
    const double below = SimpsonNormal(m - 40 * s, 20.0, m, s);
    if (below > 1e-280) {
      EXPECT_NEAR(v.log_p, std::log(below), 1e-8) << m;
    }
  }
}

TEST(PixelLikelihood, FarTailsStayFinite) {
  // log Phi against its asymptotic series and erfc where both hold.
  EXPECT_NEAR(LogNormalCdf(-36.9), std::log(0.5 * std::erfc(36.9 / std::sqrt(2.0))), 1e-10);
  EXPECT_NEAR(LogNormalCdf(-37.1) - LogNormalCdf(-36.9),
              -0.5 * (37.1 * 37.1 - 36.9 * 36.9) - std::log(37.1 / 36.9), 1e-3);
  EXPECT_TRUE(std::isfinite(LogNormalCdf(-1e4)));
  EXPECT_NEAR(LogNormalCdf(8.0), -6.22096057427178e-16, 1e-20);
  // A saturated pixel the model puts 100 sd below the level: a huge but finite cost.
  PixelValue v;
  EvaluatePixel(LikelihoodKind::kGaussian, 1e6, Censor::kAtOrAbove, 100.0, CoarseNoise(), true,
                &v);
  EXPECT_TRUE(std::isfinite(v.log_p) && std::isfinite(v.r[0]) && std::isfinite(v.dr_dm[0]));
  EXPECT_LT(v.censored_sd, -100.0);
}

// 1/2 (r0^2 + r1^2) + log p must not depend on m: the MAP's least squares is the likelihood.
TEST(PixelLikelihood, ResidualsAreTheNegativeLogLikelihoodUpToAConstant) {
  struct Case {
    const char* name;
    PixelNoise noise;
    double d;
    Censor censor;
  };
  const Case cases[] = {{"gaussian", FineNoise(), 150.0, Censor::kNone},
                        {"interval", CoarseNoise(), 120.0, Censor::kNone},
                        {"interval dark", CoarseNoise(), 0.0, Censor::kNone},
                        {"above", CoarseNoise(), 800.0, Censor::kAtOrAbove},
                        {"below", CoarseNoise(), 0.0, Censor::kAtOrBelow}};
  for (const Case& c : cases) {
    double constant = NAN;
    for (double m : {1.0, 20.0, 90.0, 130.0, 300.0, 700.0, 2000.0}) {
      PixelValue v;
      EvaluatePixel(LikelihoodKind::kGaussian, c.d, c.censor, m, c.noise, true, &v);
      const double k = 0.5 * (v.r[0] * v.r[0] + v.r[1] * v.r[1]) + v.log_p;
      if (std::isnan(constant)) constant = k;
      // Relative to the size of the terms (log p reaches -300 here).
      EXPECT_NEAR(k, constant, 1e-9 * (1 + std::fabs(v.log_p))) << c.name << " m " << m;
    }
  }
}

TEST(PixelLikelihood, ResidualDerivativesMatchCentralDifferences) {
  struct Case {
    PixelNoise noise;
    double d;
    Censor censor;
  };
  const Case cases[] = {{FineNoise(), 150.0, Censor::kNone},
                        {CoarseNoise(), 120.0, Censor::kNone},
                        {CoarseNoise(), 40.0, Censor::kNone},
                        {CoarseNoise(), 800.0, Censor::kAtOrAbove},
                        {CoarseNoise(), 0.0, Censor::kAtOrBelow}};
  for (const Case& c : cases) {
    for (double m : {3.0, 37.0, 118.0, 121.5, 500.0, 790.0, 1500.0}) {
      PixelValue v, plus, minus;
      EvaluatePixel(LikelihoodKind::kGaussian, c.d, c.censor, m, c.noise, true, &v);
      const double h = 1e-4 * std::max(1.0, m);
      EvaluatePixel(LikelihoodKind::kGaussian, c.d, c.censor, m + h, c.noise, true, &plus);
      EvaluatePixel(LikelihoodKind::kGaussian, c.d, c.censor, m - h, c.noise, true, &minus);
      for (int i = 0; i < 2; ++i) {
        const double numeric = (plus.r[i] - minus.r[i]) / (2 * h);
        // Central differences err by O(h^2 r'''): 1e-6 of the scale of the derivatives.
        EXPECT_NEAR(v.dr_dm[i], numeric, 1e-5 * (1e-3 + std::fabs(numeric)))
            << "d " << c.d << " m " << m << " residual " << i;
      }
      // The same with respect to the datum at a fixed expectation (a censored pixel's level
      // moves with it: it is d -/+ h).
      const double hd = 1e-4 * std::max(1.0, std::fabs(c.d));
      EvaluatePixel(LikelihoodKind::kGaussian, c.d + hd, c.censor, m, c.noise, true, &plus);
      EvaluatePixel(LikelihoodKind::kGaussian, c.d - hd, c.censor, m, c.noise, true, &minus);
      for (int i = 0; i < 2; ++i) {
        const double numeric = (plus.r[i] - minus.r[i]) / (2 * hd);
        EXPECT_NEAR(v.dr_dd[i], numeric, 1e-5 * (1e-3 + std::fabs(numeric)))
            << "d " << c.d << " m " << m << " residual " << i << " (datum)";
      }
    }
  }
}

TEST(PixelLikelihood, IntervalResidualIsSmoothThroughItsZero) {
  // At m = d the interval residual r0 has a double zero of its square; its slope there comes
  // from the closed-form curvature and must join the slope just beside it.
  const PixelNoise noise = CoarseNoise();
  PixelValue at, beside;
  EvaluatePixel(LikelihoodKind::kGaussian, 120.0, Censor::kNone, 120.0, noise, true, &at);
  EvaluatePixel(LikelihoodKind::kGaussian, 120.0, Censor::kNone, 120.01, noise, true, &beside);
  EXPECT_NEAR(at.r[0], 0.0, 1e-6);
  EXPECT_NEAR(at.dr_dm[0], beside.dr_dm[0], 2e-3 * std::fabs(beside.dr_dm[0]));
  EXPECT_LT(at.dr_dm[0], 0.0);
  EXPECT_NEAR(at.dr_dd[0], beside.dr_dd[0], 2e-3 * std::fabs(beside.dr_dd[0]));
  EXPECT_GT(at.dr_dd[0], 0.0);
}

TEST(PixelLikelihood, GaussianFormIsLikelihoodH) {
  // Fine steps: the Gaussian of likelihood.h with the rounding variance, unchanged.
  const PixelNoise noise = FineNoise();
  PixelValue v;
  EvaluatePixel(LikelihoodKind::kGaussian, 160.0, Censor::kNone, 140.0, noise, true, &v);
  EXPECT_DOUBLE_EQ(v.log_p, GaussianLogLikelihood(160.0, 140.0, noise.ccd));
  const double var = noise.ccd.VarianceE2(140.0);
  EXPECT_DOUBLE_EQ(v.r[0], 20.0 / std::sqrt(var));
  EXPECT_DOUBLE_EQ(v.chi2, 400.0 / var);
}

}  // namespace
}  // namespace ccdpsf::fit
