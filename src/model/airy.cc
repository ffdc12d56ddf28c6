#include "ccdpsf/model/airy.h"

#include <cmath>
#include <vector>

namespace ccdpsf::model {
namespace {

// Table spacing in v and range. Quintic Hermite interpolation has error
// <= h^6 / 46080 * max|a^(6)|; |a^(6)| <= 1 (a is band-limited to unit angular frequency),
// so h = 0.05 gives ~3e-13. Beyond kTableMax we fall back to the direct evaluation.
constexpr double kTableStep = 0.05;
constexpr double kTableMax = 1500.0;
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

struct AiryTable {
  AiryTable() {
    const int n = static_cast<int>(kTableMax / kTableStep) + 2;
    a.resize(n);
    da.resize(n);
    d2a.resize(n);
    for (int i = 0; i < n; ++i) {
      const double v = i * kTableStep;
      if (v < kSeriesLimit) {
        AirySeries(v, &a[i], &da[i], &d2a[i]);
      } else {
        AiryAmplitudeDirect(v, &a[i], &da[i]);
        d2a[i] = -a[i] - 3.0 * da[i] / v;  // Bessel equation for a = 2 J1(v) / v.
      }
    }
  }
  std::vector<double> a, da, d2a;
};

const AiryTable& Table() {
  static const AiryTable table;
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
  const double j0 = std::cyl_bessel_j(0.0, v);
  const double j1 = std::cyl_bessel_j(1.0, v);
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
  const AiryTable& t = Table();
  const double s = v * (1.0 / kTableStep);
  const int i = static_cast<int>(s);
  const double u = s - i;  // in [0, 1)
  const double h = kTableStep;
  // Quintic Hermite on [0, 1] in u, with derivatives scaled by h.
  const double p0 = t.a[i], p1 = t.a[i + 1];
  const double m0 = t.da[i] * h, m1 = t.da[i + 1] * h;
  const double c0 = t.d2a[i] * h * h, c1 = t.d2a[i + 1] * h * h;
  const double u2 = u * u, u3 = u2 * u, u4 = u3 * u, u5 = u4 * u;
  const double h00 = 1 - 10 * u3 + 15 * u4 - 6 * u5;
  const double h10 = u - 6 * u3 + 8 * u4 - 3 * u5;
  const double h20 = 0.5 * (u2 - 3 * u3 + 3 * u4 - u5);
  const double h01 = 10 * u3 - 15 * u4 + 6 * u5;
  const double h11 = -4 * u3 + 7 * u4 - 3 * u5;
  const double h21 = 0.5 * (u3 - 2 * u4 + u5);
  *a = h00 * p0 + h10 * m0 + h20 * c0 + h01 * p1 + h11 * m1 + h21 * c1;
  const double d00 = -30 * u2 + 60 * u3 - 30 * u4;
  const double d10 = 1 - 18 * u2 + 32 * u3 - 15 * u4;
  const double d20 = 0.5 * (2 * u - 9 * u2 + 12 * u3 - 5 * u4);
  const double d01 = 30 * u2 - 60 * u3 + 30 * u4;
  const double d11 = -12 * u2 + 28 * u3 - 15 * u4;
  const double d21 = 0.5 * (3 * u2 - 8 * u3 + 5 * u4);
  *da_dv = (d00 * p0 + d10 * m0 + d20 * c0 + d01 * p1 + d11 * m1 + d21 * c1) / h;
}

double AiryAmplitude(double v) {
  double a, da;
  AiryAmplitudeAndDerivative(v, &a, &da);
  return a;
}

}  // namespace ccdpsf::model
