// The Airy amplitude a(v) = 2 J1(v) / v and its derivatives, fast and to ~1e-12.
//
// The Airy intensity of spot_model.h is I(d) = A a(k d)^2 with k = pi Rz / r. The renderer
// evaluates a() at tens of thousands of quadrature nodes per image, so a() is interpolated
// from a table (quintic Hermite on nodes 0.05 apart, using a, a' and a'' at the nodes, which
// follow exactly from the Bessel equation: v a'' + 3 a' + v a = 0). The table is built from
// glibc's POSIX j0 and j1 (~1e-17 absolute error) on demand, up to the largest v asked for
// (EnsureAiryTable; thread-safe), and never changes once built.
#ifndef CCDPSF_MODEL_AIRY_H_
#define CCDPSF_MODEL_AIRY_H_

namespace ccdpsf::model {

// a(v) = 2 J1(v) / v, with a(0) = 1. v >= 0 (the function is even).
double AiryAmplitude(double v);

// a(v) and da/dv together.
void AiryAmplitudeAndDerivative(double v, double* a, double* da_dv);

// Direct evaluation through POSIX j0 and j1, no table: for the table's nodes and for v
// beyond its range (~0.1 us).
void AiryAmplitudeDirect(double v, double* a, double* da_dv);

// The table behind AiryAmplitudeAndDerivative, for the inline fast paths below: per-interval
// quintic coefficients c0..c5 in u = (v - i h) / h, interval i at [6 i, 6 i + 6). The
// pointer is the same for the whole run; the intervals up to v are ready once
// EnsureAiryTable(v) has returned (on any thread), and must not be read before.
constexpr double kAiryTableStep = 0.05;
constexpr double kAiryTableMax = 1500.0;
const double* AiryTableCoefficients();
void EnsureAiryTable(double v_max);

// The encircled-energy ratio e(v) = E(v) / v^2, where E(v) = 1 - J0(v)^2 - J1(v)^2 is the
// fraction of the Airy pattern's flux within v (Born & Wolf 8.5.2; e(0) = 1 / 4), tabulated
// like a(v) (same step, range, layout and rules: EnsureEncircledRatioTable(v) before reading
// up to v) from e, e' = a^2 / (2 v) - 2 e / v and e'' at the nodes (the power series below
// v = 2, where 1 - J0^2 - J1^2 cancels). For the pillbox model's disc averages
// (internal/airy_disc_average.h), which need e alone where a and a' gave it with a division.
// Its pieces are good to ~2e-14 (a script against the series and scipy's Bessel functions at
// 5 points per piece, v < 200, while this was written; tests/unit/airy_disc_average_test.cc checks).
const double* EncircledRatioTableCoefficients();
void EnsureEncircledRatioTable(double v_max);
// e(v) without the table (Bessel functions or the series): for tests and for v past the
// table's range.
void EncircledRatioDirect(double v, double* e);

// Inline versions for the renderer's inner loop (a call per node costs more than the
// polynomial). 0 <= v, and EnsureAiryTable(v) called before. Same values as
// AiryAmplitudeAndDerivative.
inline double AiryAmplitudeInline(double v, const double* table) {
  if (v >= kAiryTableMax) return AiryAmplitude(v);
  const double s = v * (1.0 / kAiryTableStep);
  const int i = static_cast<int>(s);
  const double u = s - i;
  const double* c = table + 6 * static_cast<long>(i);
  return c[0] + u * (c[1] + u * (c[2] + u * (c[3] + u * (c[4] + u * c[5]))));
}
inline void AiryAmplitudeAndDerivativeInline(double v, const double* table, double* a,
                                             double* da_dv) {
  if (v >= kAiryTableMax) {
    AiryAmplitudeAndDerivative(v, a, da_dv);
    return;
  }
  const double s = v * (1.0 / kAiryTableStep);
  const int i = static_cast<int>(s);
  const double u = s - i;
  const double* c = table + 6 * static_cast<long>(i);
  *a = c[0] + u * (c[1] + u * (c[2] + u * (c[3] + u * (c[4] + u * c[5]))));
  *da_dv = (c[1] + u * (2 * c[2] + u * (3 * c[3] + u * (4 * c[4] + u * 5 * c[5])))) *
           (1.0 / kAiryTableStep);
}

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_AIRY_H_
