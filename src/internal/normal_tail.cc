// See normal_tail.h. Four points at a time in GCC vector types (one AVX register with
// -march=x86-64-v3, two SSE2 registers without); a short last group is padded.
#include "internal/normal_tail.h"

#include <algorithm>
#include <cstdint>
#include <cstring>

namespace ccdpsf::internal {
namespace {

typedef double Vec4 __attribute__((vector_size(32)));
typedef int64_t Vec4i __attribute__((vector_size(32)));
inline Vec4 Broadcast(double v) { return Vec4{v, v, v, v}; }

// R(x) = t G(t), t = K / (K + x), G(t) = sum_k c_k T_k(2 t - 1), K = 4.
constexpr double kMillsK = 4.0;
// 25 coefficients; largest relative error of Q on [0, 37] in double: 6.2e-16
constexpr double kMillsChebyshev[25] = {
    0.6081401071287601,      0.47106364364487086,     0.1392391622740954,
    0.030403993036051142,    0.004340177035931943,    0.00020090530018249141,
    -6.300873370135883e-05,  -1.1845929817645294e-05, 6.331472841497064e-07,
    3.85101745997825e-07,    -2.118740157515424e-09,  -1.296334650273668e-08,
    -7.070323319150624e-11,  4.871641594722769e-10,   -6.2298637420689176e-12,
    -1.9893121798622115e-11, 1.1546035447888047e-12,  8.227140310560963e-13,
    -1.0913460109524325e-13, -3.0751779598081935e-14, 8.103543395521696e-15,
    7.633098896831416e-16,   -5.045935068926838e-16,  1.792548875355647e-17,
    2.5423880995096355e-17,
};

// exp(a) for a <= 0. a below -708 is taken as -708 (exp(-708) = 3.3e-308, the smallest power
// that keeps the result normal; nothing here needs smaller values exactly). a = n ln 2 + r
// with n = round(a / ln 2) and |r| <= ln 2 / 2, ln 2 split in two parts so that n ln 2 is
// exact to ~1e-26; exp(r) by its Taylor series to r^13 (remainder below 4e-18); 2^n put
// into the exponent bits.
inline Vec4 ExpNonPositive(Vec4 a) {
  constexpr double kLog2e = 1.4426950408889634074;
  constexpr double kLn2Hi = 6.93147180369123816490e-01;  // ln 2 to 32 bits (exact n * kLn2Hi)
  constexpr double kLn2Lo = 1.90821492927058770002e-10;  // ln 2 - kLn2Hi
  constexpr double kShifter = 6755399441055744.0;  // 1.5 x 2^52: adding it rounds to an integer
  const Vec4 floor_a = Broadcast(-708.0);
  a = a < floor_a ? floor_a : a;
  const Vec4 shifted = a * kLog2e + kShifter;  // n in the low bits of the mantissa
  const Vec4 n = shifted - kShifter;
  Vec4 r = a - n * kLn2Hi;
  r = r - n * kLn2Lo;
  // 1/k! for k = 13 down to 0.
  constexpr double kInvFactorial[14] = {1.0 / 6227020800.0,
                                        1.0 / 479001600.0,
                                        1.0 / 39916800.0,
                                        1.0 / 3628800.0,
                                        1.0 / 362880.0,
                                        1.0 / 40320.0,
                                        1.0 / 5040.0,
                                        1.0 / 720.0,
                                        1.0 / 120.0,
                                        1.0 / 24.0,
                                        1.0 / 6.0,
                                        1.0 / 2.0,
                                        1.0,
                                        1.0};
  Vec4 p = Broadcast(kInvFactorial[0]);
  for (int k = 1; k < 14; ++k) p = p * r + kInvFactorial[k];
  // 2^n: the biased exponent n + 1023 (1..1023 here) in bits 52..62.
  Vec4i bits;
  Vec4i shifter_bits;
  const Vec4 shifter_vec = Broadcast(kShifter);
  std::memcpy(&bits, &shifted, sizeof bits);
  std::memcpy(&shifter_bits, &shifter_vec, sizeof bits);
  const Vec4i exponent = (bits - shifter_bits + 1023) << 52;
  Vec4 scale;
  std::memcpy(&scale, &exponent, sizeof scale);
  return p * scale;
}

// phi(z) for four points.
inline Vec4 Densities4(Vec4 z) {
  constexpr double kInvSqrt2Pi = 0.39894228040143267794;
  return ExpNonPositive(-0.5 * (z * z)) * kInvSqrt2Pi;
}

// Q(|z|) and phi(z) for four points.
inline void TailsAndDensities4(Vec4 z, Vec4* tail, Vec4* density) {
  const Vec4 x = z < 0.0 ? -z : z;
  const Vec4 phi = Densities4(z);
  // Clenshaw's recurrence for the Chebyshev series in u = 2 t - 1.
  const Vec4 t = kMillsK / (kMillsK + x);
  const Vec4 u = 2.0 * t - 1.0;
  constexpr int kTerms = sizeof(kMillsChebyshev) / sizeof(kMillsChebyshev[0]);
  Vec4 b1 = Broadcast(0.0), b2 = Broadcast(0.0);
  for (int k = kTerms - 1; k >= 1; --k) {
    const Vec4 b0 = 2.0 * u * b1 - b2 + kMillsChebyshev[k];
    b2 = b1;
    b1 = b0;
  }
  const Vec4 series = u * b1 - b2 + kMillsChebyshev[0];
  *tail = phi * (t * series);
  *density = phi;
}

}  // namespace

void NormalTailsAndDensities(const double* z, int n, double* tail, double* density) {
  int e = 0;
  for (; e + 4 <= n; e += 4) {
    Vec4 zv, tv, dv;
    std::memcpy(&zv, z + e, sizeof zv);
    TailsAndDensities4(zv, &tv, &dv);
    std::memcpy(tail + e, &tv, sizeof tv);
    if (density != nullptr) std::memcpy(density + e, &dv, sizeof dv);
  }
  if (e == n) return;
  double zp[4] = {0.0, 0.0, 0.0, 0.0}, tp[4], dp[4];
  std::copy(z + e, z + n, zp);
  Vec4 zv, tv, dv;
  std::memcpy(&zv, zp, sizeof zv);
  TailsAndDensities4(zv, &tv, &dv);
  std::memcpy(tp, &tv, sizeof tp);
  std::memcpy(dp, &dv, sizeof dp);
  std::copy(tp, tp + (n - e), tail + e);
  if (density != nullptr) std::copy(dp, dp + (n - e), density + e);
}

void NormalDensities(const double* z, int n, double* density) {
  int e = 0;
  for (; e + 4 <= n; e += 4) {
    Vec4 zv;
    std::memcpy(&zv, z + e, sizeof zv);
    const Vec4 dv = Densities4(zv);
    std::memcpy(density + e, &dv, sizeof dv);
  }
  if (e == n) return;
  double zp[4] = {0.0, 0.0, 0.0, 0.0}, dp[4];
  std::copy(z + e, z + n, zp);
  Vec4 zv;
  std::memcpy(&zv, zp, sizeof zv);
  const Vec4 dv = Densities4(zv);
  std::memcpy(dp, &dv, sizeof dp);
  std::copy(dp, dp + (n - e), density + e);
}

}  // namespace ccdpsf::internal
