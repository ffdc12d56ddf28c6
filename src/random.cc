#include "ccdpsf/random.h"

#include <cmath>

#include "glog/logging.h"

namespace ccdpsf {

uint64_t DeriveSeed(uint64_t seed, uint64_t stream) {
  uint64_t z = seed + 0x9E3779B97F4A7C15ULL * (stream + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

double Uniform01(std::mt19937_64& engine) {
  return (static_cast<double>(engine() >> 11) + 0.5) * 0x1.0p-53;
}

double StandardNormal(std::mt19937_64& engine) {
  const double u1 = Uniform01(engine);
  const double u2 = Uniform01(engine);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

int64_t Poisson(double mean, std::mt19937_64& engine) {
  CHECK(mean >= 0.0 && std::isfinite(mean)) << "Poisson mean " << mean;
  if (mean == 0.0) return 0;
  if (mean < 10.0) {
    // Count uniforms until their product drops below exp(-mean).
    const double limit = std::exp(-mean);
    double product = Uniform01(engine);
    int64_t k = 0;
    while (product > limit) {
      ++k;
      product *= Uniform01(engine);
    }
    return k;
  }
  // PTRS: W. Hormann, "The transformed rejection method for generating Poisson random
  // variables", Insurance: Mathematics and Economics 12 (1993) 39-45.
  const double smu = std::sqrt(mean);
  const double b = 0.931 + 2.53 * smu;
  const double a = -0.059 + 0.02483 * b;
  const double inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
  const double v_r = 0.9277 - 3.6224 / (b - 2.0);
  const double log_mean = std::log(mean);
  while (true) {
    const double u = Uniform01(engine) - 0.5;
    const double v = Uniform01(engine);
    const double us = 0.5 - std::fabs(u);
    const double k = std::floor((2.0 * a / us + b) * u + mean + 0.43);
    if (us >= 0.07 && v <= v_r) return static_cast<int64_t>(k);
    if (k < 0.0 || (us < 0.013 && v > us)) continue;
    if (std::log(v) + std::log(inv_alpha) - std::log(a / (us * us) + b) <=
        -mean + k * log_mean - std::lgamma(k + 1.0)) {
      return static_cast<int64_t>(k);
    }
  }
}

}  // namespace ccdpsf
