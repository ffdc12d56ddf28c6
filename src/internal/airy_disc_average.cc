#include "internal/airy_disc_average.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "ccdpsf/model/airy.h"
#include "internal/airy_table_simd.h"
#include "internal/vec4.h"

namespace ccdpsf::internal {
namespace {

// e(v) = E(v) / v^2 and the Airy amplitude a(v) at v = k rho >= 0, for one lane: from the
// tables as the vector lanes read them, or without them past the tables' range.
inline void EncircledRatioAndAmplitude(double v, const double* e_table, const double* a_table,
                                       double* e, double* a) {
  if (v >= model::kAiryTableMax) {
    model::EncircledRatioDirect(v, e);
    *a = model::AiryAmplitude(v);
    return;
  }
  TablePolynomial(e_table, v, e, nullptr);
  TablePolynomial(a_table, v, a, nullptr);
}

}  // namespace

void EnsureDiscAverageTables(double v_max) {
  model::EnsureEncircledRatioTable(v_max);
  model::EnsureAiryTable(v_max);
}

AiryDiscAverage::AiryDiscAverage(double k, double radius) : k_(k), radius_(radius) {
  // Angular frequencies up to ~2 k R, plus the Bessel-like tail past it: 10 % and 16 nodes
  // over the full circle, half of them on [0, pi]. Measured against 400 nodes (scipy's
  // Bessel functions, r 0.3-0.9 px, R 0.05-3 px, d 0-15 px): worst error 1.9e-13 of the Airy
  // peak with 16 (20: 3.7e-15; 12: 4.8e-11), below the Airy table's own ~1e-12.
  const int n_full = static_cast<int>(std::ceil(2.0 * k * radius * 1.1 + 16.0));
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
  static const double* const e_table = model::EncircledRatioTableCoefficients();
  static const double* const a_table = model::AiryTableCoefficients();
  const double k = k_, R = radius_;
  const bool derivs = d_dk != nullptr;
  // Per point: sums over theta of E (d cos + R) / rho^2, of I and of I cos.
  double flux[4] = {0, 0, 0, 0}, ring[4] = {0, 0, 0, 0}, ring_cos[4] = {0, 0, 0, 0};
#if defined(__AVX2__) && defined(__FMA__)
  // The four points side by side, one angle at a time. A point whose v falls past the
  // tables has that angle's e and a redone alone.
  const __m256d dv = _mm256_loadu_pd(d), Rv = _mm256_set1_pd(R), kv = _mm256_set1_pd(k);
  const __m256d base = _mm256_fmadd_pd(dv, dv, _mm256_set1_pd(R * R));
  const __m256d cross = _mm256_mul_pd(_mm256_set1_pd(2.0 * R), dv);
  const __m256d highest = _mm256_set1_pd(model::kAiryTableMax);
  __m256d flux4 = _mm256_setzero_pd(), ring4 = _mm256_setzero_pd(), ring_cos4 = _mm256_setzero_pd();
  // Angles in chunks, each in stages over the whole chunk: v; the tables; the sums. Angle by
  // angle, the chain square root -> table piece -> coefficient loads -> polynomial was longer
  // than the out-of-order window could overlap; staged, each loop's iterations are
  // independent. Every lane's operations are the same.
  constexpr int kChunk = 16;
  __m256d v_at[kChunk], e_at[kChunk], a_at[kChunk];
  const int n_angles = static_cast<int>(cos_theta_.size());
  for (int l0 = 0; l0 < n_angles; l0 += kChunk) {
    const int m = std::min(kChunk, n_angles - l0);
    const double* cosines = cos_theta_.data() + l0;
    for (int l = 0; l < m; ++l) {
      const __m256d c = _mm256_set1_pd(cosines[l]);
      const __m256d rho2 = _mm256_max_pd(_mm256_setzero_pd(), _mm256_fmadd_pd(cross, c, base));
      v_at[l] = _mm256_mul_pd(kv, _mm256_sqrt_pd(rho2));
    }
    for (int l = 0; l < m; ++l) e_at[l] = TablePolynomial4(e_table, v_at[l], nullptr);
    if (derivs) {
      for (int l = 0; l < m; ++l) a_at[l] = TablePolynomial4(a_table, v_at[l], nullptr);
    }
    for (int l = 0; l < m; ++l) {
      const __m256d c = _mm256_set1_pd(cosines[l]);
      __m256d e = e_at[l], a = derivs ? a_at[l] : _mm256_setzero_pd();
      const int outside = _mm256_movemask_pd(_mm256_cmp_pd(v_at[l], highest, _CMP_GE_OQ));
      if (outside != 0) {
        alignas(32) double vs[4], es[4], as[4];
        _mm256_store_pd(vs, v_at[l]);
        _mm256_store_pd(es, e);
        _mm256_store_pd(as, a);
        for (int lane = 0; lane < 4; ++lane) {
          if ((outside >> lane) & 1)
            EncircledRatioAndAmplitude(vs[lane], e_table, a_table, &es[lane], &as[lane]);
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
      EncircledRatioAndAmplitude(v, e_table, a_table, &e, &a);
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

// The maps that turn S at the Chebyshev points of a piece into the power series of its
// sub-pieces. Sub-piece s covers t in [-1 + 2 s / kSub, -1 + 2 (s + 1) / kSub] of the piece,
// with local variable u in [-1, 1] (t = t_s + u / kSub). Two steps, each well conditioned:
//   interpolation  values f_j at the piece's N Chebyshev points -> the Chebyshev coefficients
//                  b_l (l < kMonomials) of the sub-piece's interpolant in u: the piece's
//                  interpolant evaluated at the sub-piece's Chebyshev points, then a discrete
//                  cosine transform. Its entries are bounded by ~ the Lebesgue constant.
//   power basis    b_l -> a_i with sum_l b_l T_l(u) = sum_i a_i u^i. Entries reach ~3e6
//                  (T_19's), but b_l falls like J_l(2 k H / kSub) = J_l(4), so the products
//                  stay small: the rounding error is ~1e-14 of the peak (measured on test
//                  functions of the same band while this was written;
//                  tests/unit/airy_disc_average_test.cc holds the profile to the direct
//                  quadrature over the disc).
// (The product of the two maps is the direct map from values to power series; it has entries
// ~1e6 on the outer sub-pieces and loses four digits to cancellation, so it is not used.)
// Built once in long double.
struct SubPieceMaps {
  std::array<double, AiryDiscProfile::kTerms> points;  // the piece's t_j = cos(pi (j + 1/2) / N)
  // interpolation[s][j * kMonomials + l]
  std::array<std::vector<double>, AiryDiscProfile::kSub> interpolation;
  std::vector<double> power;  // [l * kMonomials + i]
};
const SubPieceMaps& Maps() {
  static const SubPieceMaps maps = [] {
    constexpr int n = AiryDiscProfile::kTerms, d = AiryDiscProfile::kMonomials;
    constexpr int sub = AiryDiscProfile::kSub;
    const long double pi = 3.141592653589793238462643383279502884L;
    SubPieceMaps m;
    for (int j = 0; j < n; ++j) m.points[j] = static_cast<double>(std::cos(pi * (j + 0.5L) / n));
    // Lagrange form of the piece's interpolant through its Chebyshev points t_j: the value at
    // t is sum_j f_j sum_m w_m T_m(t_j) T_m(t) with w_0 = 1 / N, w_m = 2 / N (the DCT and the
    // series in one).
    std::vector<long double> dct(static_cast<size_t>(n) * n);  // w_k T_k(t_j), [j * n + k]
    for (int j = 0; j < n; ++j) {
      for (int k = 0; k < n; ++k) {
        dct[static_cast<size_t>(j) * n + k] =
            (k == 0 ? 1.0L / n : 2.0L / n) * std::cos(pi * k * (j + 0.5L) / n);
      }
    }
    std::vector<long double> sub_dct(static_cast<size_t>(d) * d);  // cos(pi l (q + 1/2) / d)
    for (int l = 0; l < d; ++l) {
      for (int q = 0; q < d; ++q)
        sub_dct[static_cast<size_t>(l) * d + q] = std::cos(pi * l * (q + 0.5L) / d);
    }
    std::vector<long double> cheb_t(n);  // T_k(t) = cos(k acos t)
    for (int s = 0; s < sub; ++s) {
      const long double ts = -1.0L + (2.0L * s + 1.0L) / sub;
      std::vector<long double> at_sub(static_cast<size_t>(n) * d);  // [j * d + q]
      for (int q = 0; q < d; ++q) {
        const long double theta = std::acos(ts + std::cos(pi * (q + 0.5L) / d) / sub);
        for (int k = 0; k < n; ++k) cheb_t[k] = std::cos(k * theta);
        for (int j = 0; j < n; ++j) {
          long double sum = 0.0L;
          for (int k = 0; k < n; ++k) sum += dct[static_cast<size_t>(j) * n + k] * cheb_t[k];
          at_sub[static_cast<size_t>(j) * d + q] = sum;
        }
      }
      // DCT over the sub-piece's points q: b_l = w_l sum_q value_q cos(pi l (q + 1/2) / d).
      m.interpolation[s].resize(static_cast<size_t>(n) * d);
      for (int j = 0; j < n; ++j) {
        for (int l = 0; l < d; ++l) {
          long double sum = 0.0L;
          for (int q = 0; q < d; ++q) {
            sum += at_sub[static_cast<size_t>(j) * d + q] * sub_dct[static_cast<size_t>(l) * d + q];
          }
          m.interpolation[s][static_cast<size_t>(j) * d + l] =
              static_cast<double>(sum * (l == 0 ? 1.0L / d : 2.0L / d));
        }
      }
    }
    // Power-basis coefficients of T_l: T_0 = 1, T_1 = u, T_{l+1} = 2 u T_l - T_{l-1} (exact
    // integers below 2^64).
    std::vector<long double> t(static_cast<size_t>(d) * d, 0.0L);
    t[0] = 1.0L;
    if (d > 1) t[static_cast<size_t>(d) + 1] = 1.0L;
    for (int l = 1; l + 1 < d; ++l) {
      for (int i = 0; i < d; ++i) {
        long double v = -t[static_cast<size_t>(l - 1) * d + i];
        if (i > 0) v += 2.0L * t[static_cast<size_t>(l) * d + i - 1];
        t[static_cast<size_t>(l + 1) * d + i] = v;
      }
    }
    m.power.assign(t.begin(), t.end());
    return m;
  }();
  return maps;
}

// Horner's sum of Q power series sharing u: out[q] = sum_i a[q][i] u^i.
template <int Q>
inline void Horner(const double* a, double u, double* out) {
  constexpr int d = AiryDiscProfile::kMonomials;
  for (int q = 0; q < Q; ++q) {
    double sum = a[q * d + d - 1];
    for (int i = d - 2; i >= 0; --i) sum = std::fma(sum, u, a[q * d + i]);
    out[q] = sum;
  }
}

#if defined(__AVX2__) && defined(__FMA__)
using SumItem = AiryDiscProfile::SumItem;

// G items at once: their sums are independent chains, so that the multiply-add latency of
// one chain is hidden behind the others (one chain alone runs at a quarter of the machine's
// rate). Results are stored to out[q][at ..] for the lanes each item uses. Each lane's
// operations are those of Horner<Q>, rounded the same.
template <int Q, int G>
inline void HornerItems(const SumItem* item, double* const* out) {
  constexpr int d = AiryDiscProfile::kMonomials;
  __m256d sum[G][Q], u[G];
  for (int g = 0; g < G; ++g) {
    u[g] = _mm256_load_pd(item[g].t);
    for (int q = 0; q < Q; ++q) sum[g][q] = _mm256_set1_pd(item[g].c[q * d + d - 1]);
  }
  for (int i = d - 2; i >= 0; --i) {
    for (int g = 0; g < G; ++g) {
      for (int q = 0; q < Q; ++q) {
        sum[g][q] = _mm256_fmadd_pd(sum[g][q], u[g], _mm256_set1_pd(item[g].c[q * d + i]));
      }
    }
  }
  for (int g = 0; g < G; ++g) {
    const __m256i mask = _mm256_castpd_si256(_mm256_load_pd(item[g].use));
    for (int q = 0; q < Q; ++q) _mm256_maskstore_pd(out[q] + item[g].at, mask, sum[g][q]);
  }
}

template <int Q, int G>
void HornerAll(const SumItem* items, size_t count, double* const* out) {
  size_t i = 0;
  for (; i + G <= count; i += G) HornerItems<Q, G>(&items[i], out);
  for (; i < count; ++i) HornerItems<Q, 1>(&items[i], out);
}
#endif

}  // namespace

double AiryDiscProfile::Reach(double k, double d_max) {
  const double half_length = 8.0 / k;
  return 2.0 * half_length * std::max(1.0, std::ceil(d_max / (2.0 * half_length)));
}

void AiryDiscProfile::Build(double k, double radius, double d_max, bool derivs, double dk_scale) {
  constexpr int n = kTerms, d = kMonomials;
  derivs_ = derivs;
  // Pieces of half-length 8 / k (2 k H = 16) from d = 0 on, as many as reach d_max. A piece
  // does not depend on d_max, so neither does any value (a larger quadrant made for another
  // stamp gives the same S at the same node).
  half_length_ = 8.0 / k;
  pieces_ = std::max(1, static_cast<int>(std::ceil(d_max / (2.0 * half_length_))));
  const AiryDiscAverage average(k, radius);
  const SubPieceMaps& maps = Maps();
  const int quantities = derivs ? 3 : 1;
  coefficients_.assign(static_cast<size_t>(pieces_) * kSub * 3 * d, 0.0);
  scratch_.resize(3 * n);
  double* values = scratch_.data();  // [q * n + j]
  for (int p = 0; p < pieces_; ++p) {
    const double centre = (2 * p + 1) * half_length_;
    for (int j = 0; j < n; j += 4) {  // n is a multiple of 4
      double dist[4];
      for (int l = 0; l < 4; ++l) {
        dist[l] = std::max(0.0, centre + half_length_ * maps.points[j + l]);
      }
      average.Evaluate4(dist, &values[j], derivs ? &values[n + j] : nullptr,
                        derivs ? &values[2 * n + j] : nullptr);
    }
    // The series are linear in the sampled values: scaling these scales every node's value.
    if (derivs) {
      for (int j = 0; j < n; ++j) values[n + j] *= dk_scale;
    }
    // The sums over l (and i) run side by side in registers, summed over j (and l) outermost.
    for (int s = 0; s < kSub; ++s) {
      const double* to_chebyshev = maps.interpolation[s].data();
      for (int q = 0; q < quantities; ++q) {
        Vec4 b[d / 4];
        for (Vec4& v : b) v = Vec4{0.0, 0.0, 0.0, 0.0};
        for (int j = 0; j < n; ++j) {
          const double f = values[q * n + j];
          const double* row = to_chebyshev + static_cast<size_t>(j) * d;
          for (int v = 0; v < d / 4; ++v) b[v] += f * LoadVec4(row + 4 * v);
        }
        Vec4 a[d / 4];
        for (Vec4& v : a) v = Vec4{0.0, 0.0, 0.0, 0.0};
        for (int l = 0; l < d; ++l) {
          const double bl = b[l / 4][l % 4];
          const double* row = maps.power.data() + static_cast<size_t>(l) * d;
          for (int v = 0; v <= l / 4; ++v) a[v] += bl * LoadVec4(row + 4 * v);  // T_l: i <= l
        }
        double* out = coefficients_.data() + ((static_cast<size_t>(p) * kSub + s) * 3 + q) * d;
        for (int v = 0; v < d / 4; ++v) StoreVec4(out + 4 * v, a[v]);
      }
    }
  }
}

void AiryDiscProfile::Evaluate(const double* dist, int count, double* value, double* d_dk,
                               double* d_dR) const {
  const Run run{0, count};
  Evaluate(dist, &run, 1, value, d_dk, d_dR);
}

void AiryDiscProfile::Evaluate(const double* dist, const Run* runs, int num_runs, double* value,
                               double* d_dk, double* d_dR) const {
  // Sub-pieces of half-length H / kSub: sub-piece p covers [2 p, 2 p + 2] H / kSub, local
  // variable u = (d - (2 p + 1) H / kSub) / (H / kSub).
  const double sub_half = half_length_ / kSub;
  const double inv_width = 0.5 / sub_half;  // sub-pieces per px
  const double inv_sub_half = 1.0 / sub_half;
  const int last = pieces_ * kSub - 1;
  const auto sub_piece = [&](double d) {
    return std::min(static_cast<int>(std::floor(d * inv_width)), last);
  };
  const auto local = [&](double d, int p) {
    return (d - std::fma(2.0, p, 1.0) * sub_half) * inv_sub_half;
  };
  const bool all = derivs_ && d_dk != nullptr;
#if defined(__AVX2__) && defined(__FMA__)
  // Runs of up to four consecutive points in one sub-piece make one vector sum each (the
  // points are a quadrant column's nodes, whose distances grow smoothly, so runs are long);
  // a sum's unused lanes are masked out of the stores. All sums are listed first, then run
  // several at a time. Every lane does the operations of the scalar Horner<Q>.
  size_t num_items = 0;
  for (int r = 0; r < num_runs; ++r) {
    const int end = runs[r].at + runs[r].count;
    for (int i = runs[r].at; i < end;) {
      const int p = sub_piece(dist[i]);
      int n = 1;
      while (n < 4 && i + n < end && sub_piece(dist[i + n]) == p) ++n;
      // Written in place: an item built on the stack and copied is read back in halves,
      // which stalls on store forwarding (measured ~20 % of Evaluate).
      if (num_items == items_.size()) items_.resize(2 * items_.size() + 64);
      SumItem& item = items_[num_items++];
      for (int l = 0; l < 4; ++l) {
        item.t[l] = l < n ? local(dist[i + l], p) : 0.0;
        item.use[l] = l < n ? -1 : 0;  // the mask's sign bits
      }
      item.c = coefficients_.data() + static_cast<size_t>(p) * 3 * kMonomials;
      item.at = i;
      i += n;
    }
  }
  double* const out[3] = {value, d_dk, d_dR};
  if (all) {
    HornerAll<3, 3>(items_.data(), num_items, out);
  } else {
    HornerAll<1, 8>(items_.data(), num_items, out);
  }
#else
  for (int r = 0; r < num_runs; ++r) {
    for (int i = runs[r].at; i < runs[r].at + runs[r].count; ++i) {
      const int p = sub_piece(dist[i]);
      const double u = local(dist[i], p);
      const double* a = coefficients_.data() + static_cast<size_t>(p) * 3 * kMonomials;
      if (all) {
        double sums[3];
        Horner<3>(a, u, sums);
        value[i] = sums[0];
        d_dk[i] = sums[1];
        d_dR[i] = sums[2];
      } else {
        Horner<1>(a, u, &value[i]);
      }
    }
  }
#endif
}

}  // namespace ccdpsf::internal
