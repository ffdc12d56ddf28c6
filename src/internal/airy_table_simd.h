// The Airy amplitude table (model/airy.h) evaluated inline, one point or four at a time, for
// the renderer's fills. Header-only: a call per node would cost more than the polynomial.
#ifndef CCDPSF_INTERNAL_AIRY_TABLE_SIMD_H_
#define CCDPSF_INTERNAL_AIRY_TABLE_SIMD_H_

#include <algorithm>
#include <cmath>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

#include "ccdpsf/model/airy.h"

namespace ccdpsf::internal {

// The Airy amplitude a(v) and da/dv for v >= 0 from the table's quintic pieces (airy.h), as
// AiryAmplitudeAndDerivativeInline computes them, except that v at or past kAiryTableMax
// reads the last piece: the caller redoes those. Every operation is the one TablePolynomial4
// does in its lane, rounded the same (explicit fused multiply-adds), so that a node's value
// does not depend on whether it fell in a vector of four or in the remainder.
inline void TablePolynomial(const double* table, double v, double* amp, double* damp) {
  constexpr double kInvStep = 1.0 / model::kAiryTableStep;
  constexpr int kLast = static_cast<int>(model::kAiryTableMax * kInvStep + 0.5) - 1;
  const double sv = std::min(v, model::kAiryTableMax) * kInvStep;
  const int i = std::min(static_cast<int>(sv), kLast);
  const double u = sv - i;
  const double* c = table + 6 * static_cast<long>(i);
  double a = std::fma(u, c[5], c[4]);
  a = std::fma(u, a, c[3]);
  a = std::fma(u, a, c[2]);
  a = std::fma(u, a, c[1]);
  *amp = std::fma(u, a, c[0]);
  if (damp != nullptr) {
    double d = std::fma(u, 5.0 * c[5], 4.0 * c[4]);
    d = std::fma(u, d, 3.0 * c[3]);
    d = std::fma(u, d, c[2] + c[2]);
    d = std::fma(u, d, c[1]);
    *damp = d * kInvStep;
  }
}

#if defined(__AVX2__) && defined(__FMA__)
// The table pieces of four points v >= 0 and the offsets u in them (units of the step), as
// TablePolynomial finds them.
inline void TablePieces4(__m256d v, __m128i* index, __m256d* u) {
  constexpr double kInvStep = 1.0 / model::kAiryTableStep;
  constexpr int kLast = static_cast<int>(model::kAiryTableMax * kInvStep + 0.5) - 1;
  const __m256d sv = _mm256_mul_pd(_mm256_min_pd(v, _mm256_set1_pd(model::kAiryTableMax)),
                                   _mm256_set1_pd(kInvStep));
  *index = _mm_min_epi32(_mm256_cvttpd_epi32(sv), _mm_set1_epi32(kLast));  // sv >= 0
  *u = _mm256_sub_pd(sv, _mm256_cvtepi32_pd(*index));
}

// The polynomial of TablePolynomial at four points, whose pieces' six coefficients start at
// c[0..3], at offsets u. The coefficients of a piece are contiguous, so two loads fetch them,
// and a 4 x 4 (plus a 4 x 2) transpose turns four points' coefficients into one vector per
// coefficient; the polynomial then runs four points per instruction. (AVX2 gathers of the
// coefficients measured slower on the development machine, the scalar loop about 2x slower
// than this.) damp may be null.
inline __m256d PiecePolynomial4(const double* const c[4], __m256d u, __m256d* damp) {
  // Rows r_l = (c0, c1, c2, c3) of point l, transposed to columns C0..C3 over the points.
  const __m256d r0 = _mm256_loadu_pd(c[0]), r1 = _mm256_loadu_pd(c[1]);
  const __m256d r2 = _mm256_loadu_pd(c[2]), r3 = _mm256_loadu_pd(c[3]);
  const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
  const __m256d t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
  const __m256d c0 = _mm256_permute2f128_pd(t0, t2, 0x20);
  const __m256d c1 = _mm256_permute2f128_pd(t1, t3, 0x20);
  const __m256d c2 = _mm256_permute2f128_pd(t0, t2, 0x31);
  const __m256d c3 = _mm256_permute2f128_pd(t1, t3, 0x31);
  // (c4, c5) of points 0 and 2, of points 1 and 3; then columns C4, C5.
  const __m256d s02 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(c[0] + 4)),
                                           _mm_loadu_pd(c[2] + 4), 1);
  const __m256d s13 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(c[1] + 4)),
                                           _mm_loadu_pd(c[3] + 4), 1);
  const __m256d c4 = _mm256_unpacklo_pd(s02, s13), c5 = _mm256_unpackhi_pd(s02, s13);
  __m256d a = _mm256_fmadd_pd(u, c5, c4);
  a = _mm256_fmadd_pd(u, a, c3);
  a = _mm256_fmadd_pd(u, a, c2);
  a = _mm256_fmadd_pd(u, a, c1);
  a = _mm256_fmadd_pd(u, a, c0);
  if (damp != nullptr) {
    __m256d d = _mm256_fmadd_pd(u, _mm256_mul_pd(_mm256_set1_pd(5.0), c5),
                                _mm256_mul_pd(_mm256_set1_pd(4.0), c4));
    d = _mm256_fmadd_pd(u, d, _mm256_mul_pd(_mm256_set1_pd(3.0), c3));
    d = _mm256_fmadd_pd(u, d, _mm256_add_pd(c2, c2));
    d = _mm256_fmadd_pd(u, d, c1);
    *damp = _mm256_mul_pd(d, _mm256_set1_pd(1.0 / model::kAiryTableStep));
  }
  return a;
}

// TablePolynomial at four points. damp may be null.
inline __m256d TablePolynomial4(const double* table, __m256d v, __m256d* damp) {
  __m128i index;
  __m256d u;
  TablePieces4(v, &index, &u);
  // (Extracted from the register: storing the vector and reading its parts back stalls on
  // store forwarding.)
  const double* const c[4] = {table + 6 * static_cast<long>(_mm_cvtsi128_si32(index)),
                              table + 6 * static_cast<long>(_mm_extract_epi32(index, 1)),
                              table + 6 * static_cast<long>(_mm_extract_epi32(index, 2)),
                              table + 6 * static_cast<long>(_mm_extract_epi32(index, 3))};
  return PiecePolynomial4(c, u, damp);
}
#endif

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_AIRY_TABLE_SIMD_H_
