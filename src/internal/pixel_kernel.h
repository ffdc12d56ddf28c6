// The one-dimensional pixel response of a Gaussian: the fraction of a unit Gaussian of width
// s [px], centred at offset t [px] from a pixel centre, that falls inside the pixel's
// collecting window of width w (1 for the whole pixel; less when only its central part
// collects, a narrower pixel response),
//
//   k(t, s) = Phi((t + w/2) / s) - Phi((t - w/2) / s),
//
// with its derivatives in t and s. Written with erfc on the side away from the centre so the
// tails keep their relative precision.
#ifndef CCDPSF_INTERNAL_PIXEL_KERNEL_H_
#define CCDPSF_INTERNAL_PIXEL_KERNEL_H_

#include <cmath>

namespace ccdpsf::internal {

struct PixelKernelValue {
  double value;  // k(t, s)
  double d_dt;   // dk/dt
  double d_ds;   // dk/ds
};

inline PixelKernelValue PixelKernel(double t, double s, double w = 1.0) {
  constexpr double kInvSqrt2 = 0.70710678118654752440;
  constexpr double kInvSqrt2Pi = 0.39894228040143267794;
  const double half = 0.5 * w;
  const double zp = (t + half) / s;
  const double zm = (t - half) / s;
  PixelKernelValue k;
  const double a = std::fabs(t);
  if (a <= half) {
    // Window straddles the centre: no cancellation.
    k.value = 1.0 - 0.5 * std::erfc(zp * kInvSqrt2) - 0.5 * std::erfc(-zm * kInvSqrt2);
  } else {
    // Both edges on one side: difference of two small tail probabilities.
    const double za = (a - half) / s, zb = (a + half) / s;
    k.value = 0.5 * (std::erfc(za * kInvSqrt2) - std::erfc(zb * kInvSqrt2));
  }
  const double pp = kInvSqrt2Pi * std::exp(-0.5 * zp * zp);
  const double pm = kInvSqrt2Pi * std::exp(-0.5 * zm * zm);
  k.d_dt = (pp - pm) / s;
  k.d_ds = -(zp * pp - zm * pm) / s;
  return k;
}

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_PIXEL_KERNEL_H_
