#include "internal/airy_disc_average.h"

#include <array>
#include <cmath>

#include "ccdpsf/model/airy.h"
#include "internal/airy_table_simd.h"

namespace ccdpsf::internal {
namespace {

// Below this v = k rho the encircled-energy ratio comes from its power series: there
// 1 - J0^2 - J1^2 cancels to ~v^2 / 4 and would lose digits.
constexpr double kSeriesBelow = 2.0;

// E(v) / v^2 = (1/4) sum_{m >= 1} c_m x^(m-1), x = v^2 / 4, with
// c_m = (-1)^(m+1) (2m)! / (m!^4 (m + 1)) (from the power series of J0^2 and J1^2, DLMF
// 10.8.3): c_1 = 1, c_{m+1} / c_m = -2 (2m + 1) / ((m + 1)^2 (m + 2)). At x <= 1 the 18th term
// is below 1e-30 of the first.
constexpr int kSeriesTerms = 18;
const std::array<double, kSeriesTerms>& SeriesCoefficients() {
  static const std::array<double, kSeriesTerms> c = [] {
    std::array<double, kSeriesTerms> out{};
    out[0] = 0.25;
    for (int m = 1; m < kSeriesTerms; ++m) {
      out[m] = -out[m - 1] * 2.0 * (2.0 * m + 1.0) / ((m + 1.0) * (m + 1.0) * (m + 2.0));
    }
    return out;
  }();
  return c;
}

// E(v) / v^2 and the Airy amplitude a(v) at v = k rho >= 0.
inline void EncircledOverSquareAndAmplitude(double v, const double* table, double* e, double* a) {
  double da;
  model::AiryAmplitudeAndDerivativeInline(v, table, a, &da);
  if (v < kSeriesBelow) {
    const std::array<double, kSeriesTerms>& c = SeriesCoefficients();
    const double x = 0.25 * v * v;
    double sum = c[kSeriesTerms - 1];
    for (int m = kSeriesTerms - 2; m >= 0; --m) sum = std::fma(sum, x, c[m]);
    *e = sum;
    return;
  }
  // a = 2 J1 / v and a' = 2 J0 / v - 4 J1 / v^2 give J1 and J0.
  const double j1 = 0.5 * v * *a;
  const double j0 = *a + 0.5 * v * da;
  *e = (1.0 - j0 * j0 - j1 * j1) / (v * v);
}

}  // namespace

AiryDiscAverage::AiryDiscAverage(double k, double radius) : k_(k), radius_(radius) {
  // Angular frequencies up to ~2 k R, plus the Bessel-like tail past it: 10 % and 20 nodes
  // over the full circle, half of them on [0, pi].
  // (Rounded up to whole groups of four for the vector loop: more nodes only help.)
  const int n_full = static_cast<int>(std::ceil(2.0 * k * radius * 1.1 + 20.0));
  const int n = ((n_full + 1) / 2 + 3) / 4 * 4;
  cos_theta_.resize(n);
  for (int l = 0; l < n; ++l) cos_theta_[l] = std::cos(M_PI * (l + 0.5) / n);
}

void AiryDiscAverage::Evaluate(double d, double* value, double* d_dk, double* d_dR) const {
  static const double* const table = model::AiryTableCoefficients();
  const double k = k_, R = radius_;
  const double base = d * d + R * R, cross = 2.0 * d * R;
  const bool derivs = d_dk != nullptr || d_dR != nullptr;
  double flux = 0.0, ring = 0.0, ring_cos = 0.0;  // sums of E (d cos + R) / rho^2, I, I cos
  const int n_nodes = static_cast<int>(cos_theta_.size());
  int l = 0;
#if defined(__AVX2__) && defined(__FMA__)
  // Four angles at a time; a group with a point in the series range (v < 2) or past the
  // table goes through the scalar loop below, in the same order, so the sums do not depend
  // on how the groups fell.
  const __m256d kv = _mm256_set1_pd(k), crossv = _mm256_set1_pd(cross);
  const __m256d basev = _mm256_set1_pd(base), dv = _mm256_set1_pd(d), Rv = _mm256_set1_pd(R);
  const __m256d half = _mm256_set1_pd(0.5), one = _mm256_set1_pd(1.0);
  const __m256d lowest = _mm256_set1_pd(kSeriesBelow);
  const __m256d highest = _mm256_set1_pd(model::kAiryTableMax);
  __m256d flux4 = _mm256_setzero_pd(), ring4 = _mm256_setzero_pd(), ring_cos4 = _mm256_setzero_pd();
  for (; l + 4 <= n_nodes; l += 4) {
    const __m256d c = _mm256_loadu_pd(cos_theta_.data() + l);
    const __m256d rho2 = _mm256_max_pd(_mm256_setzero_pd(), _mm256_fmadd_pd(crossv, c, basev));
    const __m256d v = _mm256_mul_pd(kv, _mm256_sqrt_pd(rho2));
    const __m256d outside =
        _mm256_or_pd(_mm256_cmp_pd(v, lowest, _CMP_LT_OQ), _mm256_cmp_pd(v, highest, _CMP_GE_OQ));
    if (_mm256_movemask_pd(outside) != 0) break;
    __m256d da;
    const __m256d a = TablePolynomial4(table, v, &da);
    const __m256d j1 = _mm256_mul_pd(_mm256_mul_pd(half, v), a);
    const __m256d j0 = _mm256_fmadd_pd(_mm256_mul_pd(half, v), da, a);
    const __m256d rest = _mm256_fnmadd_pd(j1, j1, _mm256_fnmadd_pd(j0, j0, one));
    const __m256d e = _mm256_div_pd(rest, _mm256_mul_pd(v, v));
    flux4 = _mm256_fmadd_pd(e, _mm256_fmadd_pd(dv, c, Rv), flux4);
    if (derivs) {
      const __m256d a2 = _mm256_mul_pd(a, a);
      ring4 = _mm256_add_pd(ring4, a2);
      ring_cos4 = _mm256_fmadd_pd(a2, c, ring_cos4);
    }
  }
  // Lane sums in a fixed order.
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, flux4);
  flux = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
  _mm256_store_pd(lanes, ring4);
  ring = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
  _mm256_store_pd(lanes, ring_cos4);
  ring_cos = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
#endif
  for (; l < n_nodes; ++l) {
    const double c = cos_theta_[l];
    const double rho2 = std::max(0.0, std::fma(cross, c, base));
    const double v = k * std::sqrt(rho2);
    double e, a;
    EncircledOverSquareAndAmplitude(v, table, &e, &a);
    flux = std::fma(e, std::fma(d, c, R), flux);
    if (derivs) {
      ring += a * a;
      ring_cos = std::fma(a * a, c, ring_cos);
    }
  }
  const double n = static_cast<double>(cos_theta_.size());
  const double k2 = k * k;
  // E / rho^2 = k^2 e(v); I = k^2 a^2 / (4 pi).
  const double s = k2 * flux / (n * M_PI * R);
  *value = s;
  if (!derivs) return;
  const double mean_i = k2 * ring / (4.0 * M_PI * n);
  const double mean_i_cos = k2 * ring_cos / (4.0 * M_PI * n);
  const double ds_dR = 2.0 / R * (mean_i - s);
  const double ds_dd = 2.0 / R * mean_i_cos;
  if (d_dR != nullptr) *d_dR = ds_dR;
  if (d_dk != nullptr) *d_dk = (2.0 * s + d * ds_dd + R * ds_dR) / k;
}

}  // namespace ccdpsf::internal
