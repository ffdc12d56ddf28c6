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

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_LIKELIHOOD_H_
