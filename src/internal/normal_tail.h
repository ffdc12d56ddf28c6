// The standard normal's upper tail and density at many points, vectorised: the pixel kernel's
// weights (integrated_renderer.cc) take one of each per window edge, and glibc's erfc and exp,
// one point per call, were a fifth of a render.
#ifndef CCDPSF_INTERNAL_NORMAL_TAIL_H_
#define CCDPSF_INTERNAL_NORMAL_TAIL_H_

namespace ccdpsf::internal {

// For e in [0, n):
//   tail[e]    = Q(|z[e]|) = P(Z > |z[e]|) = erfc(|z[e]| / sqrt 2) / 2,
//   density[e] = phi(z[e]) = exp(-z[e]^2 / 2) / sqrt(2 pi)   (when density is not null).
// Q(x) = phi(x) R(x), with the Mills ratio R from a Chebyshev series
// (tools/make_normal_tail_coefficients.py). Relative error of either about 1e-15 for
// |z| <= 37; past ~37.6 both are below 1e-307 and come out as at 37.6 (phi) or smaller (Q).
// Every point goes through the same arithmetic, whatever n and its place: a value depends only
// on z[e]. NaN gives NaN.
void NormalTailsAndDensities(const double* z, int n, double* tail, double* density);
// density[e] = phi(z[e]) alone, the same values as above at a third of the cost (the upper-edge
// kernel needs no tails).
void NormalDensities(const double* z, int n, double* density);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_NORMAL_TAIL_H_
