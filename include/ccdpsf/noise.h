// The CCD noise model (paper eq. CCDnoise), in electrons.
//
// In ADU the paper writes sigma^2 = (M - B) / g + (RN / g)^2 for a model M [ADU] with bias B
// [ADU], gain g [e-/ADU] and read noise RN [e-]. Multiplying by g^2 gives the same model in
// electrons, which is how every fit here works (data are converted with (ADU - B) g):
//
//   var_e = m_e + RN^2 (+ g^2 / 12 for the ADC's rounding to whole ADU, when enabled),
//
// m_e the expected photo-electrons in the pixel. The rounding term is exact for a uniform
// quantisation error and matters only where the read noise is a few ADU.
#ifndef CCDPSF_NOISE_H_
#define CCDPSF_NOISE_H_

namespace ccdpsf {

struct CcdNoise {
  double gain_e_per_adu = 1.0;
  double read_noise_e = 0.0;
  bool include_quantisation = true;

  // Variance [e-^2] of a pixel expecting `expected_e` photo-electrons. Negative expectations
  // (possible only away from a model's valid domain) count as zero signal.
  double VarianceE2(double expected_e) const {
    const double signal = expected_e > 0.0 ? expected_e : 0.0;
    return signal + read_noise_e * read_noise_e +
           (include_quantisation ? gain_e_per_adu * gain_e_per_adu / 12.0 : 0.0);
  }
};

}  // namespace ccdpsf

#endif  // CCDPSF_NOISE_H_
