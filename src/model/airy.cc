#include "ccdpsf/model/airy.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <mutex>
#include <vector>

namespace ccdpsf::model {
namespace {

// Table spacing in v and range. Quintic Hermite interpolation has error
// <= h^6 / 46080 * max|a^(6)|; |a^(6)| <= 1 (a is band-limited to unit angular frequency),
// so h = 0.05 gives ~3e-13. Beyond kTableMax we fall back to the direct evaluation.
constexpr double kTableStep = kAiryTableStep;
constexpr double kTableMax = kAiryTableMax;
// Below this v the closed forms lose digits to cancellation; use the power series.
constexpr double kSeriesLimit = 0.5;

// Power series of a, a', a'' about 0: a(v) = sum_k (-1)^k (v/2)^(2k) / (k! (k+1)!).
void AirySeries(double v, double* a, double* da, double* d2a) {
  const double t = 0.5 * v;
  const double t2 = t * t;
  double term = 1.0;  // (-1)^k t^(2k) / (k! (k+1)!)
  double sa = 0.0, sda = 0.0, sd2a = 0.0;
  for (int k = 0; k < 12; ++k) {
    if (k > 0) term *= -t2 / (static_cast<double>(k) * (k + 1));
    sa += term;
    // d/dv t^(2k) = k t^(2k-1); d2/dv2 = k (2k-1) t^(2k-2) / 2.
    if (k >= 1) {
      sda += term * k / t;
      sd2a += term * k * (2.0 * k - 1.0) / (2.0 * t2);
    }
  }
  *a = sa;
  *da = (v == 0.0) ? 0.0 : sda;
  *d2a = (v == 0.0) ? -0.25 : sd2a;
}

// The values, first and second derivatives of a function at node v, for the table's
// Hermite data.
using NodeData = void (*)(double v, double* f, double* df, double* d2f);

void AmplitudeNode(double v, double* a, double* da, double* d2a) {
  if (v < kSeriesLimit) {
    AirySeries(v, a, da, d2a);
    return;
  }
  AiryAmplitudeDirect(v, a, da);
  *d2a = -*a - 3.0 * *da / v;  // Bessel equation for a = 2 J1(v) / v.
}

// Below this v, e(v) = E(v) / v^2 comes from its power series: there 1 - J0^2 - J1^2 cancels
// to ~v^2 / 4 and would lose digits.
constexpr double kEncircledSeriesBelow = 2.0;

// e = sum_{m >= 0} c_m x^m, x = v^2 / 4, c_m = (-1)^m (2m + 2)! / ((m + 1)!^4 (m + 2)) / 4
// (from the power series of J0^2 and J1^2, whose terms combine): c_0 = 1 / 4,
// c_{m+1} / c_m = -2 (2m + 3) / ((m + 2)^2 (m + 3)). At x <= 1 the 18th term is ~1e-23 of the
// first. de/dv = e_x v / 2 and d2e/dv2 = e_xx v^2 / 4 + e_x / 2.
void EncircledRatioSeries(double v, double* e, double* de, double* d2e) {
  constexpr int kTerms = 18;
  static const std::array<double, kTerms> c = [] {
    std::array<double, kTerms> out{};
    out[0] = 0.25;
    for (int m = 0; m + 1 < kTerms; ++m) {
      out[m + 1] = -out[m] * 2.0 * (2.0 * m + 3.0) / ((m + 2.0) * (m + 2.0) * (m + 3.0));
    }
    return out;
  }();
  const double x = 0.25 * v * v;
  double f = c[kTerms - 1], fx = 0.0, fxx = 0.0;
  for (int m = kTerms - 2; m >= 0; --m) {  // Horner's rule for the sum and its derivatives
    fxx = fxx * x + 2.0 * fx;
    fx = fx * x + f;
    f = f * x + c[m];
  }
  *e = f;
  *de = fx * 0.5 * v;
  *d2e = fxx * 0.25 * v * v + 0.5 * fx;
}

void EncircledRatioNode(double v, double* e, double* de, double* d2e) {
  if (v < kEncircledSeriesBelow) {
    EncircledRatioSeries(v, e, de, d2e);
    return;
  }
  double a, da;
  AiryAmplitudeDirect(v, &a, &da);
  // J1 = v a / 2, J0 = a + v a' / 2; dE/dv = v a^2 / 2 (the intensity's ring), so
  // e' = a^2 / (2 v) - 2 e / v and e'' = a a' / v - a^2 / (2 v^2) - 2 e' / v + 2 e / v^2.
  const double j1 = 0.5 * v * a, j0 = a + 0.5 * v * da;
  *e = (1.0 - j0 * j0 - j1 * j1) / (v * v);
  *de = a * a / (2.0 * v) - 2.0 * *e / v;
  *d2e = a * da / v - a * a / (2.0 * v * v) - 2.0 * *de / v + 2.0 * *e / (v * v);
}

// Per-interval quintic polynomials in u = (v - v_i) / h, coefficients c0..c5, equal to the
// quintic Hermite interpolant through f, f', f'' at both ends of the interval; stored
// contiguously so one evaluation touches one cache line.
// The table, built on demand in blocks of intervals from v = 0 up to the largest v asked
// for: building all of it (60 000 Bessel-function calls) took ~0.15 s with
// std::cyl_bessel_j, a tenth of a complete fit at the time, while renders rarely need v
// beyond ~300. The storage is allocated whole at once, so the pointer handed out never
// changes; `built` counts the intervals ready, published with release semantics after they
// are written, and readers never read past what they have seen (Ensure before use), so no
// reader races a writer. Every interval's coefficients depend only on its two nodes, so the
// values do not depend on the order of the requests.
class QuinticTable {
 public:
  explicit QuinticTable(NodeData node)
      : node_(node), coefficients_(static_cast<size_t>(kIntervals) * 6) {}

  const double* data() const { return coefficients_.data(); }

  void Ensure(double v_max) {
    const int needed =
        std::min(kIntervals, static_cast<int>(std::max(v_max, 0.0) / kTableStep) + 1);
    if (needed <= built_.load(std::memory_order_acquire)) return;
    std::lock_guard<std::mutex> lock(mutex_);
    int built = built_.load(std::memory_order_relaxed);
    if (needed <= built) return;
    const int target = std::min(kIntervals, (needed + kBlock - 1) / kBlock * kBlock);
    Build(built, target);
    built_.store(target, std::memory_order_release);
  }

 private:
  static constexpr int kIntervals = static_cast<int>(kTableMax / kTableStep) + 1;
  static constexpr int kBlock = 1024;  // intervals built at once (v = 51.2 apart)

  // The quintic Hermite interpolants on intervals [first, last).
  void Build(int first, int last) {
    const int n = last - first + 1;  // nodes
    std::vector<double> f(n), df(n), d2f(n);
    for (int l = 0; l < n; ++l) node_((first + l) * kTableStep, &f[l], &df[l], &d2f[l]);
    const double h = kTableStep;
    for (int l = 0; l + 1 < n; ++l) {
      // Hermite data scaled to the unit interval.
      const double p0 = f[l], p1 = f[l + 1];
      const double m0 = df[l] * h, m1 = df[l + 1] * h;
      const double c0 = d2f[l] * h * h, c1 = d2f[l + 1] * h * h;
      double* c = &coefficients_[static_cast<size_t>(first + l) * 6];
      c[0] = p0;
      c[1] = m0;
      c[2] = 0.5 * c0;
      c[3] = -10 * p0 - 6 * m0 - 1.5 * c0 + 10 * p1 - 4 * m1 + 0.5 * c1;
      c[4] = 15 * p0 + 8 * m0 + 1.5 * c0 - 15 * p1 + 7 * m1 - c1;
      c[5] = -6 * p0 - 3 * m0 - 0.5 * c0 + 6 * p1 - 3 * m1 + 0.5 * c1;
    }
  }

  NodeData node_;
  std::vector<double> coefficients_;
  std::atomic<int> built_{0};
  std::mutex mutex_;
};

QuinticTable& Table() {
  static QuinticTable table(AmplitudeNode);
  return table;
}

QuinticTable& EncircledTable() {
  static QuinticTable table(EncircledRatioNode);
  return table;
}

}  // namespace

void AiryAmplitudeDirect(double v, double* a, double* da_dv) {
  v = std::fabs(v);
  if (v < kSeriesLimit) {
    double d2a;
    AirySeries(v, a, da_dv, &d2a);
    return;
  }
  // glibc's POSIX j0/j1: ~1e-17 absolute error against mpmath up to v = 1500, where
  // std::cyl_bessel_j errs by up to ~5e-13, and ~25 times faster (through std::cyl_bessel_j
  // the table's build took ~40 ms of a single fit's 56 ms MAP).
  const double j0 = ::j0(v);
  const double j1 = ::j1(v);
  *a = 2.0 * j1 / v;
  // d/dv [2 J1 / v] = 2 J1' / v - 2 J1 / v^2 with J1' = J0 - J1 / v.
  *da_dv = 2.0 * j0 / v - 4.0 * j1 / (v * v);
}

void AiryAmplitudeAndDerivative(double v, double* a, double* da_dv) {
  v = std::fabs(v);
  if (v >= kTableMax) {
    AiryAmplitudeDirect(v, a, da_dv);
    return;
  }
  const double s = v * (1.0 / kTableStep);
  const int i = static_cast<int>(s);
  const double u = s - i;  // in [0, 1)
  QuinticTable& table = Table();
  table.Ensure(v);
  const double* c = table.data() + static_cast<size_t>(i) * 6;
  *a = c[0] + u * (c[1] + u * (c[2] + u * (c[3] + u * (c[4] + u * c[5]))));
  *da_dv = (c[1] + u * (2 * c[2] + u * (3 * c[3] + u * (4 * c[4] + u * 5 * c[5])))) *
           (1.0 / kTableStep);
}

const double* AiryTableCoefficients() { return Table().data(); }

void EnsureAiryTable(double v_max) { Table().Ensure(v_max); }

const double* EncircledRatioTableCoefficients() { return EncircledTable().data(); }

void EnsureEncircledRatioTable(double v_max) { EncircledTable().Ensure(v_max); }

void EncircledRatioDirect(double v, double* e) {
  double de, d2e;
  EncircledRatioNode(std::fabs(v), e, &de, &d2e);
}

double AiryAmplitude(double v) {
  double a, da;
  AiryAmplitudeAndDerivative(v, &a, &da);
  return a;
}

}  // namespace ccdpsf::model
