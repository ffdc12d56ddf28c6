// The Airy amplitude a(v) = 2 J1(v) / v and its derivatives, fast and to ~1e-12.
//
// The Airy intensity of spot_model.h is I(d) = A a(k d)^2 with k = pi Rz / r. The renderer
// evaluates a() at tens of thousands of quadrature nodes per image, so a() is interpolated
// from a table (quintic Hermite on nodes 0.05 apart, using a, a' and a'' at the nodes, which
// follow exactly from the Bessel equation: v a'' + 3 a' + v a = 0). The table is built on
// first use from std::cyl_bessel_j and is read-only afterwards (thread-safe).
#ifndef CCDPSF_MODEL_AIRY_H_
#define CCDPSF_MODEL_AIRY_H_

namespace ccdpsf::model {

// a(v) = 2 J1(v) / v, with a(0) = 1. v >= 0 (the function is even).
double AiryAmplitude(double v);

// a(v) and da/dv together.
void AiryAmplitudeAndDerivative(double v, double* a, double* da_dv);

// Direct evaluation through std::cyl_bessel_j, no table: for tests and for v beyond the
// table's range. Slow (about a microsecond).
void AiryAmplitudeDirect(double v, double* a, double* da_dv);

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_AIRY_H_
