#include "internal/airy_disc_average.h"

#include <algorithm>
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
// c_m = (-1)^(m+1) (2m)! / (m!^4 (m + 1)) (from the power series of J0^2 and J1^2, whose
// terms combine): c_1 = 1, c_{m+1} / c_m = -2 (2m + 1) / ((m + 1)^2 (m + 2)). At x <= 1 the
// 18th term is ~1e-23 of the first.
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
  const int n_full = static_cast<int>(std::ceil(2.0 * k * radius * 1.1 + 20.0));
  const int n = (n_full + 1) / 2;
  cos_theta_.resize(n);
  for (int l = 0; l < n; ++l) cos_theta_[l] = std::cos(M_PI * (l + 0.5) / n);
}

void AiryDiscAverage::Evaluate(double d, double* value, double* d_dk, double* d_dR) const {
  const double d4[4] = {d, d, d, d};
  double v4[4], dk4[4], dR4[4];
  const bool derivs = d_dk != nullptr || d_dR != nullptr;
  Evaluate4(d4, v4, derivs ? dk4 : nullptr, derivs ? dR4 : nullptr);
  *value = v4[0];
  if (d_dk != nullptr) *d_dk = dk4[0];
  if (d_dR != nullptr) *d_dR = dR4[0];
}

void AiryDiscAverage::Evaluate4(const double* d, double* value, double* d_dk, double* d_dR) const {
  static const double* const table = model::AiryTableCoefficients();
  const double k = k_, R = radius_;
  const bool derivs = d_dk != nullptr;
  // Per point: sums over theta of E (d cos + R) / rho^2, of I and of I cos.
  double flux[4] = {0, 0, 0, 0}, ring[4] = {0, 0, 0, 0}, ring_cos[4] = {0, 0, 0, 0};
#if defined(__AVX2__) && defined(__FMA__)
  // The four points side by side, one angle at a time. A point whose rho falls in the
  // series range (v < 2) or past the table has that angle's e and a redone alone.
  const __m256d dv = _mm256_loadu_pd(d), Rv = _mm256_set1_pd(R), kv = _mm256_set1_pd(k);
  const __m256d base = _mm256_fmadd_pd(dv, dv, _mm256_set1_pd(R * R));
  const __m256d cross = _mm256_mul_pd(_mm256_set1_pd(2.0 * R), dv);
  const __m256d half = _mm256_set1_pd(0.5), one = _mm256_set1_pd(1.0);
  const __m256d lowest = _mm256_set1_pd(kSeriesBelow);
  const __m256d highest = _mm256_set1_pd(model::kAiryTableMax);
  __m256d flux4 = _mm256_setzero_pd(), ring4 = _mm256_setzero_pd(), ring_cos4 = _mm256_setzero_pd();
  for (const double cos_theta : cos_theta_) {
    const __m256d c = _mm256_set1_pd(cos_theta);
    const __m256d rho2 = _mm256_max_pd(_mm256_setzero_pd(), _mm256_fmadd_pd(cross, c, base));
    const __m256d v = _mm256_mul_pd(kv, _mm256_sqrt_pd(rho2));
    __m256d da;
    __m256d a = TablePolynomial4(table, v, &da);
    const __m256d j1 = _mm256_mul_pd(_mm256_mul_pd(half, v), a);
    const __m256d j0 = _mm256_fmadd_pd(_mm256_mul_pd(half, v), da, a);
    const __m256d rest = _mm256_fnmadd_pd(j1, j1, _mm256_fnmadd_pd(j0, j0, one));
    __m256d e = _mm256_div_pd(rest, _mm256_mul_pd(v, v));
    const int outside = _mm256_movemask_pd(
        _mm256_or_pd(_mm256_cmp_pd(v, lowest, _CMP_LT_OQ), _mm256_cmp_pd(v, highest, _CMP_GE_OQ)));
    if (outside != 0) {
      alignas(32) double vs[4], es[4], as[4];
      _mm256_store_pd(vs, v);
      _mm256_store_pd(es, e);
      _mm256_store_pd(as, a);
      for (int lane = 0; lane < 4; ++lane) {
        if ((outside >> lane) & 1)
          EncircledOverSquareAndAmplitude(vs[lane], table, &es[lane], &as[lane]);
      }
      e = _mm256_load_pd(es);
      a = _mm256_load_pd(as);
    }
    flux4 = _mm256_fmadd_pd(e, _mm256_fmadd_pd(dv, c, Rv), flux4);
    if (derivs) {
      const __m256d a2 = _mm256_mul_pd(a, a);
      ring4 = _mm256_add_pd(ring4, a2);
      ring_cos4 = _mm256_fmadd_pd(a2, c, ring_cos4);
    }
  }
  _mm256_storeu_pd(flux, flux4);
  _mm256_storeu_pd(ring, ring4);
  _mm256_storeu_pd(ring_cos, ring_cos4);
#else
  for (int lane = 0; lane < 4; ++lane) {
    const double base = d[lane] * d[lane] + R * R, cross = 2.0 * d[lane] * R;
    for (const double c : cos_theta_) {
      const double v = k * std::sqrt(std::max(0.0, std::fma(cross, c, base)));
      double e, a;
      EncircledOverSquareAndAmplitude(v, table, &e, &a);
      flux[lane] = std::fma(e, std::fma(d[lane], c, R), flux[lane]);
      ring[lane] += a * a;
      ring_cos[lane] = std::fma(a * a, c, ring_cos[lane]);
    }
  }
#endif
  const double n = static_cast<double>(cos_theta_.size());
  const double k2 = k * k;
  for (int lane = 0; lane < 4; ++lane) {
    // E / rho^2 = k^2 e(v); I = k^2 a^2 / (4 pi).
    const double s = k2 * flux[lane] / (n * M_PI * R);
    value[lane] = s;
    if (!derivs) continue;
    const double mean_i = k2 * ring[lane] / (4.0 * M_PI * n);
    const double mean_i_cos = k2 * ring_cos[lane] / (4.0 * M_PI * n);
    const double ds_dR = 2.0 / R * (mean_i - s);
    const double ds_dd = 2.0 / R * mean_i_cos;
    d_dR[lane] = ds_dR;
    d_dk[lane] = (2.0 * s + d[lane] * ds_dd + R * ds_dR) / k;
  }
}

namespace {

// The Chebyshev points t_j = cos(pi (j + 1/2) / N) and the cosine matrix of the discrete
// cosine transform that turns values there into coefficients, cos(pi m (j + 1/2) / N) at
// [j * N + m].
struct ChebyshevBasis {
  std::array<double, AiryDiscProfile::kTerms> points;
  std::vector<double> cosines;
};
const ChebyshevBasis& Basis() {
  static const ChebyshevBasis basis = [] {
    constexpr int n = AiryDiscProfile::kTerms;
    ChebyshevBasis b;
    b.cosines.resize(n * n);
    for (int j = 0; j < n; ++j) b.points[j] = std::cos(M_PI * (j + 0.5) / n);
    for (int m = 0; m < n; ++m) {
      for (int j = 0; j < n; ++j) b.cosines[j * n + m] = std::cos(M_PI * m * (j + 0.5) / n);
    }
    return b;
  }();
  return basis;
}

// Clenshaw's sum of Q series sharing t: out[q] = sum_m c[q][m] T_m(t), c_0 pre-halved.
template <int Q>
inline void Clenshaw(const double* c, double t, double* out) {
  constexpr int n = AiryDiscProfile::kTerms;
  double b1[Q] = {}, b2[Q] = {};
  const double two_t = 2.0 * t;
  for (int m = n - 1; m >= 1; --m) {
    for (int q = 0; q < Q; ++q) {
      const double b0 = std::fma(two_t, b1[q], c[q * n + m] - b2[q]);
      b2[q] = b1[q];
      b1[q] = b0;
    }
  }
  for (int q = 0; q < Q; ++q) out[q] = std::fma(t, b1[q], c[q * n] - b2[q]);
}

#if defined(__AVX2__) && defined(__FMA__)
using ClenshawItem = AiryDiscProfile::SumItem;

// G items at once: their sums are independent chains, so that the multiply-add latency of
// one chain is hidden behind the others (one chain alone runs at a quarter of the machine's
// rate). Results are blended into out[q][at ..] for the lanes each item uses.
template <int Q, int G>
inline void ClenshawItems(const ClenshawItem* item, double* const* out) {
  constexpr int n = AiryDiscProfile::kTerms;
  __m256d b1[G][Q], b2[G][Q], two_t[G];
  for (int g = 0; g < G; ++g) {
    const __m256d t = _mm256_load_pd(item[g].t);
    two_t[g] = _mm256_add_pd(t, t);
    for (int q = 0; q < Q; ++q) b1[g][q] = b2[g][q] = _mm256_setzero_pd();
  }
  for (int m = n - 1; m >= 1; --m) {
    for (int g = 0; g < G; ++g) {
      for (int q = 0; q < Q; ++q) {
        const __m256d b0 = _mm256_fmadd_pd(
            two_t[g], b1[g][q], _mm256_sub_pd(_mm256_set1_pd(item[g].c[q * n + m]), b2[g][q]));
        b2[g][q] = b1[g][q];
        b1[g][q] = b0;
      }
    }
  }
  for (int g = 0; g < G; ++g) {
    for (int q = 0; q < Q; ++q) {
      const __m256d f = _mm256_fmadd_pd(_mm256_load_pd(item[g].t), b1[g][q],
                                        _mm256_sub_pd(_mm256_set1_pd(item[g].c[q * n]), b2[g][q]));
      double* o = out[q] + item[g].at;
      _mm256_storeu_pd(o, _mm256_blendv_pd(_mm256_loadu_pd(o), f, _mm256_load_pd(item[g].use)));
    }
  }
}

template <int Q, int G>
void ClenshawAll(const std::vector<ClenshawItem>& items, double* const* out) {
  size_t i = 0;
  for (; i + G <= items.size(); i += G) ClenshawItems<Q, G>(&items[i], out);
  for (; i < items.size(); ++i) ClenshawItems<Q, 1>(&items[i], out);
}
#endif

}  // namespace

double AiryDiscProfile::Reach(double k, double d_max) {
  const double half_length = 8.0 / k;
  return 2.0 * half_length * std::max(1.0, std::ceil(d_max / (2.0 * half_length)));
}

void AiryDiscProfile::Build(double k, double radius, double d_max, bool derivs) {
  constexpr int n = kTerms;
  derivs_ = derivs;
  // Pieces of half-length 8 / k (2 k H = 16) from d = 0 on, as many as reach d_max. A piece
  // does not depend on d_max, so neither does any value (a larger quadrant made for another
  // stamp gives the same S at the same node).
  half_length_ = 8.0 / k;
  pieces_ = std::max(1, static_cast<int>(std::ceil(d_max / (2.0 * half_length_))));
  const AiryDiscAverage average(k, radius);
  const ChebyshevBasis& basis = Basis();
  const int quantities = derivs ? 3 : 1;
  coefficients_.assign(static_cast<size_t>(pieces_) * 3 * n, 0.0);
  scratch_.resize(3 * n);
  double* values = scratch_.data();  // [q * n + j]
  for (int p = 0; p < pieces_; ++p) {
    const double centre = (2 * p + 1) * half_length_;
    for (int j = 0; j < n; j += 4) {  // n is a multiple of 4
      double d[4];
      for (int l = 0; l < 4; ++l) d[l] = std::max(0.0, centre + half_length_ * basis.points[j + l]);
      average.Evaluate4(d, &values[j], derivs ? &values[n + j] : nullptr,
                        derivs ? &values[2 * n + j] : nullptr);
    }
    // c_m = (2 / N) sum_j f_j cos(pi m (j + 1/2) / N), c_0 halved: summed over j outermost so
    // that the N sums over m run side by side (each alone is a chain of N multiply-adds).
    for (int q = 0; q < quantities; ++q) {
      double* c = coefficients_.data() + (static_cast<size_t>(p) * 3 + q) * n;
      for (int j = 0; j < n; ++j) {
        const double f = values[q * n + j];
        const double* row = basis.cosines.data() + j * n;  // cos(pi m (j + 1/2) / N) over m
        for (int m = 0; m < n; ++m) c[m] = std::fma(f, row[m], c[m]);
      }
      c[0] *= 1.0 / n;
      for (int m = 1; m < n; ++m) c[m] *= 2.0 / n;
    }
  }
}

void AiryDiscProfile::Evaluate(const double* d, int count, double* value, double* d_dk,
                               double* d_dR) const {
  const double inv_width = 0.5 / half_length_;  // pieces per px
  const int last = pieces_ - 1;
  int i = 0;
#if defined(__AVX2__) && defined(__FMA__)
  // Four points at a time. The points of a group usually share a piece (they are
  // consecutive nodes); otherwise the group is summed once per piece it touches, each sum
  // filling its own lanes. All sums are listed first, then run several at a time.
  const bool all = derivs_ && d_dk != nullptr;
  const int groups = count / 4;
  std::fill_n(value, 4 * groups, 0.0);
  if (all) {
    std::fill_n(d_dk, 4 * groups, 0.0);
    std::fill_n(d_dR, 4 * groups, 0.0);
  }
  const __m256d inv_width4 = _mm256_set1_pd(inv_width), h = _mm256_set1_pd(half_length_);
  const __m256d inv_h4 = _mm256_set1_pd(1.0 / half_length_);
  items_.clear();
  for (; i + 4 <= count; i += 4) {
    const __m256d dv = _mm256_loadu_pd(d + i);
    const __m256d piece = _mm256_min_pd(_mm256_floor_pd(_mm256_mul_pd(dv, inv_width4)),
                                        _mm256_set1_pd(static_cast<double>(last)));
    alignas(32) double lane_piece[4];
    _mm256_store_pd(lane_piece, piece);
    const int lo = static_cast<int>(
        std::min(std::min(lane_piece[0], lane_piece[1]), std::min(lane_piece[2], lane_piece[3])));
    const int hi = static_cast<int>(
        std::max(std::max(lane_piece[0], lane_piece[1]), std::max(lane_piece[2], lane_piece[3])));
    for (int p = lo; p <= hi; ++p) {
      const __m256d pv = _mm256_set1_pd(static_cast<double>(p));
      ClenshawItem item;
      _mm256_store_pd(item.use, _mm256_cmp_pd(piece, pv, _CMP_EQ_OQ));
      // t = (d - (2 p + 1) H) / H
      const __m256d centre =
          _mm256_mul_pd(_mm256_fmadd_pd(_mm256_set1_pd(2.0), pv, _mm256_set1_pd(1.0)), h);
      _mm256_store_pd(item.t, _mm256_mul_pd(_mm256_sub_pd(dv, centre), inv_h4));
      item.c = coefficients_.data() + static_cast<size_t>(p) * 3 * kTerms;
      item.at = i;
      items_.push_back(item);
    }
  }
  double* const out[3] = {value, d_dk, d_dR};
  if (all) {
    ClenshawAll<3, 2>(items_, out);
  } else {
    ClenshawAll<1, 4>(items_, out);
  }
#endif
  // The rest, rounded as the vector lanes are.
  const double inv_h = 1.0 / half_length_;
  for (; i < count; ++i) {
    const int p = std::min(static_cast<int>(std::floor(d[i] * inv_width)), last);
    const double t = (d[i] - std::fma(2.0, p, 1.0) * half_length_) * inv_h;
    const double* c = coefficients_.data() + static_cast<size_t>(p) * 3 * kTerms;
    if (derivs_ && d_dk != nullptr) {
      double out[3];
      Clenshaw<3>(c, t, out);
      value[i] = out[0];
      d_dk[i] = out[1];
      d_dR[i] = out[2];
    } else {
      Clenshaw<1>(c, t, &value[i]);
    }
  }
}

}  // namespace ccdpsf::internal
