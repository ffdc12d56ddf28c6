// Per-pixel likelihoods of the CCD noise model (paper section 3.2), in electrons.
//
// A pixel records D = P + N electrons: P ~ Poisson(m) photo-electrons and N ~ Normal(0, s^2)
// with s^2 = RN^2 + g^2 / 12 (read noise plus the ADC's rounding to whole ADU).
//
//   kGaussian       the paper's high-count form: D ~ Normal(m, m + s^2), keeping the
//                   -1/2 log(2 pi var) term since the variance depends on the model.
//   kPoissonNormal  the exact convolution sum_k Poisson(k; m) Normal(D - k; 0, s^2), for
//                   low-signal data. Where m > kPoissonNormalGaussianAbove the Poisson's
//                   skewness 1/sqrt(m) is < 3 % and the Gaussian form is used instead: the
//                   sum would need ~20 sqrt(m) terms per pixel.
#ifndef CCDPSF_FIT_LIKELIHOOD_H_
#define CCDPSF_FIT_LIKELIHOOD_H_

#include <string>

#include "ccdpsf/noise.h"

namespace ccdpsf::fit {

enum class LikelihoodKind { kGaussian, kPoissonNormal };

bool ParseLikelihoodKind(const std::string& text, LikelihoodKind* kind);
std::string ToString(LikelihoodKind kind);

constexpr double kPoissonNormalGaussianAbove = 1000.0;  // [e-]

// log p(data_e | expected_e) for one pixel.
double GaussianLogLikelihood(double data_e, double expected_e, const CcdNoise& noise);
double PoissonNormalLogLikelihood(double data_e, double expected_e, const CcdNoise& noise);

inline double PixelLogLikelihood(LikelihoodKind kind, double data_e, double expected_e,
                                 const CcdNoise& noise) {
  return kind == LikelihoodKind::kGaussian
             ? GaussianLogLikelihood(data_e, expected_e, noise)
             : PoissonNormalLogLikelihood(data_e, expected_e, noise);
}

// The sum of GaussianLogLikelihood over many pixels, for the MCMC's hot loop: the
// -1/2 log(var) terms are summed as the log of the product of the variances, kept as a
// mantissa and a power of two (std::frexp every kRenormaliseEvery pixels, before a product of
// variances up to ~2^60 each could overflow), so that a stamp takes a log per
// kRenormaliseEvery pixels instead of one per pixel. Each factor rounds to 1.1e-16 relative,
// so n pixels' log-variance sum differs from the term-by-term one by ~n * 1e-16 (absolute),
// far below anything a log-posterior difference resolves. Order-deterministic.
class GaussianLogLikelihoodSum {
 public:
  explicit GaussianLogLikelihoodSum(const CcdNoise& noise)
      : floor_(noise.VarianceE2(0.0)) {}
  void Add(double data_e, double expected_e) {
    const double var = floor_ + (expected_e > 0.0 ? expected_e : 0.0);  // CcdNoise::VarianceE2
    const double r = data_e - expected_e;
    chi2_ += r * r / var;
    product_ *= var;
    ++count_;
    if (++since_renormalised_ == kRenormaliseEvery) Renormalise();
  }
  // The sum of log p over the pixels added.
  double Total();

 private:
  static constexpr int kRenormaliseEvery = 16;
  void Renormalise();
  double floor_;
  double chi2_ = 0.0;
  double product_ = 1.0;  // product of the variances since the last renormalisation, times 2^-exponent_
  long exponent_ = 0;
  long count_ = 0;
  int since_renormalised_ = 0;
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_LIKELIHOOD_H_
