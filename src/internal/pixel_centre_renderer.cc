// The 2015 reference discretisation, templated on the scalar so that Ceres Jets give exact
// derivatives. On an nx x ny stamp with integer pixel coordinates X (column), Y (row):
//
//   A = amp [2 J1(pi q) / (pi q)]^2,  q = hypot(X - x, Y - y) / (r / Rz),
//       amp such that A at the centre pixel (cx, cy) equals m, cx = int(nx/2 - 0.5);
//   F = exp(-((X - x)^2 + (Y - y)^2) / (2 sigma_f^2))     (unit peak, on the Airy centre);
//   M1 = convolve2d(A, F, mode='same')                     (zero padding);
//   G = exp(-(X - nx/2 + 0.5)^2 / (2 sigma_x^2) - (Y - ny/2 + 0.5)^2 / (2 sigma_y^2));
//   M = convolve2d(M1, G, mode='same').
//
// Two extensions beyond the 2015 code, neither of which changes its output:
//   - a defocus offset (dx, dy): F is centred on (x + dx, y + dy) instead of the Airy centre
//     (the catalogue's defocus_offset). With dx = dy = 0 the arithmetic is the 2015 one
//     (x + 0.0 is x exactly, for doubles and for Jets alike);
//   - sigma_f = 0 means "no defocus step": M1 = A. The unit-peak F has no useful limit as
//     sigma_f -> 0 (at a non-integer x every sample of it goes to 0), so a model without
//     the defocus component (the paper's first model; diagnose's baseline_defocus = false)
//     leaves the convolution out instead.
//
// Nothing is normalised: m is not the flux. In scipy's 'same' mode the output element (i, j)
// is the full convolution's element (i + cy, j + cx), so kernel index (cy, cx) is the zero
// shift. F and G are separable, so each 2-D convolution is done as two 1-D ones; with zero
// padding this is the same sum, term by term.
#include "internal/pixel_centre_renderer.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ceres/jet.h"
#include "ccdpsf/model/airy.h"
#include "glog/logging.h"

namespace ccdpsf::internal {
namespace {

using model::kAiryRadius;
using model::kCcdSigmaX;
using model::kCcdSigmaY;
using model::kCentreX;
using model::kCentreY;
using model::kDefocus;
using model::kFlux;
using model::kNumSpotParams;

using std::exp;
using std::sqrt;

// [2 J1(pi q) / (pi q)]^2 as a function of q^2, smooth through q = 0 (where sqrt would give
// the Jets an infinite derivative). Away from 0, a(v) = 2 J1(v) / v comes from the table of
// model/airy.h (~1e-12, and ~0.1 us instead of ~1 us for J1 itself: the Bessel function was
// most of a render's cost); the scalar and Jet versions do the same arithmetic on the value,
// so the values-only and with-Jacobian renders agree to rounding.
double AiryAmplitudeOfV(double v, double* da_dv) {
  static const double* const table = model::AiryTableCoefficients();
  double a;
  model::AiryAmplitudeAndDerivativeInline(v, table, &a, da_dv);
  return a;
}
double AiryAmplitudeOfV(double v) {
  static const double* const table = model::AiryTableCoefficients();
  return model::AiryAmplitudeInline(v, table);  // the same polynomial, without the derivative
}
template <typename JetT>
JetT AiryAmplitudeOfV(const JetT& v) {
  double da_dv;
  const double a = AiryAmplitudeOfV(v.a, &da_dv);
  return JetT(a, da_dv * v.v);
}

template <typename T>
T AiryPatternOfQ2(const T& q2) {
  const double kSmall = 1e-6;
  if (q2 < kSmall) {
    // a(v) = 1 - v^2/8 + v^4/192 - ..., v^2 = pi^2 q^2; error O(v^6) ~ 1e-16 here.
    const T v2 = M_PI * M_PI * q2;
    const T a = T(1.0) - v2 / 8.0 + v2 * v2 / 192.0;
    return a * a;
  }
  const T v = M_PI * sqrt(q2);
  const T a = AiryAmplitudeOfV(v);
  return a * a;
}

// The kernels are unit-peak Gaussians of sigma <= ~1 px, so most of a stamp-wide kernel is
// far below rounding: a term whose weight is below kNegligibleWeight (relative to the unit
// peak) changes no output by more than that fraction of the stamp's maximum, far below the
// 1e-10 to which this renderer is checked against the 2015 recipe. Skipping them makes a
// render several times faster.
constexpr double kNegligibleWeight = 1e-18;

inline double ValueOf(double v) { return v; }
template <typename JetT>
double ValueOf(const JetT& v) {
  return v.a;
}

// out[i][j] = sum_l in[i][l] kernel[j + c - l] over 0 <= j + c - l < n: scipy 'same' along
// the fast (x) axis. in/out are ny x nx row-major. Looping over the kernel index outermost
// keeps the inner loop contiguous (vectorisable) and free of bounds tests.
template <typename T>
void ConvolveRowsSame(const std::vector<T>& in, const std::vector<T>& kernel, int nx, int ny,
                      std::vector<T>* out) {
  const int c = (nx - 1) / 2;
  out->assign(static_cast<size_t>(nx) * ny, T(0.0));
  for (int kidx = 0; kidx < nx; ++kidx) {
    const T& w = kernel[kidx];
    if (std::abs(ValueOf(w)) < kNegligibleWeight) continue;
    const int offset = c - kidx;  // l = j + offset
    const int j_begin = std::max(0, -offset), j_end = std::min(nx, nx - offset);
    for (int i = 0; i < ny; ++i) {
      const T* in_row = &in[static_cast<size_t>(i) * nx];
      T* out_row = &(*out)[static_cast<size_t>(i) * nx];
      for (int j = j_begin; j < j_end; ++j) out_row[j] += in_row[j + offset] * w;
    }
  }
}

// The same along the slow (y) axis.
template <typename T>
void ConvolveColumnsSame(const std::vector<T>& in, const std::vector<T>& kernel, int nx, int ny,
                         std::vector<T>* out) {
  const int c = (ny - 1) / 2;
  out->assign(static_cast<size_t>(nx) * ny, T(0.0));
  for (int i = 0; i < ny; ++i) {
    for (int k = 0; k < ny; ++k) {
      const int kidx = i + c - k;
      if (kidx < 0 || kidx >= ny) continue;
      const T& w = kernel[kidx];
      if (std::abs(ValueOf(w)) < kNegligibleWeight) continue;
      for (int j = 0; j < nx; ++j) (*out)[i * nx + j] += in[k * nx + j] * w;
    }
  }
}

template <typename T>
void RenderTemplated(const T* p, const T& defocus_dx, const T& defocus_dy, int nx, int ny,
                     std::vector<T>* model) {
  const T& m = p[kFlux];
  const T& x = p[kCentreX];
  const T& y = p[kCentreY];
  const T scale = p[kAiryRadius] / model::kAiryRz;  // r / Rz [px]
  const int cx = static_cast<int>(nx / 2.0 - 0.5);
  const int cy = static_cast<int>(ny / 2.0 - 0.5);

  const T dxc = double(cx) - x, dyc = double(cy) - y;
  const T peak_q2 = (dxc * dxc + dyc * dyc) / (scale * scale);
  const T amp = m / AiryPatternOfQ2(peak_q2);
  std::vector<T> airy(static_cast<size_t>(nx) * ny);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const T dx = double(i) - x, dy = double(j) - y;
      const T q2 = (dx * dx + dy * dy) / (scale * scale);
      airy[j * nx + i] = amp * AiryPatternOfQ2(q2);
    }
  }

  std::vector<T> tmp, m1;
  if (p[kDefocus] == 0.0) {
    m1 = airy;  // no defocus step
  } else {
    const T two_sf2 = 2.0 * p[kDefocus] * p[kDefocus];
    const T fcx = x + defocus_dx, fcy = y + defocus_dy;  // F's centre
    std::vector<T> fx(nx), fy(ny);
    for (int i = 0; i < nx; ++i) fx[i] = exp(-(double(i) - fcx) * (double(i) - fcx) / two_sf2);
    for (int j = 0; j < ny; ++j) fy[j] = exp(-(double(j) - fcy) * (double(j) - fcy) / two_sf2);
    ConvolveRowsSame(airy, fx, nx, ny, &tmp);
    ConvolveColumnsSame(tmp, fy, nx, ny, &m1);
  }

  const T two_sx2 = 2.0 * p[kCcdSigmaX] * p[kCcdSigmaX];
  const T two_sy2 = 2.0 * p[kCcdSigmaY] * p[kCcdSigmaY];
  std::vector<T> gx(nx), gy(ny);
  for (int i = 0; i < nx; ++i) {
    const double u = i - nx / 2.0 + 0.5;
    gx[i] = exp(-T(u * u) / two_sx2);
  }
  for (int j = 0; j < ny; ++j) {
    const double u = j - ny / 2.0 + 0.5;
    gy[j] = exp(-T(u * u) / two_sy2);
  }
  ConvolveRowsSame(m1, gx, nx, ny, &tmp);
  ConvolveColumnsSame(tmp, gy, nx, ny, model);
}

// The render with derivatives: N = kNumSpotParams, or kNumSpotParams + 2 with the defocus
// offset's (slots kNumSpotParams and kNumSpotParams + 1). Either output may be null.
template <int N>
void RenderWithJets(const model::SpotParams& params, double defocus_dx_px, double defocus_dy_px,
                    const model::PixelGrid& grid, double* model_out, double* jacobian,
                    double* offset_jacobian) {
  using Jet = ceres::Jet<double, N>;
  Jet p[kNumSpotParams];
  for (int k = 0; k < kNumSpotParams; ++k) p[k] = Jet(params[k], k);
  Jet dx(defocus_dx_px), dy(defocus_dy_px);
  if constexpr (N > kNumSpotParams) {
    dx = Jet(defocus_dx_px, kNumSpotParams);
    dy = Jet(defocus_dy_px, kNumSpotParams + 1);
  }
  std::vector<Jet> out;
  RenderTemplated(p, dx, dy, grid.nx, grid.ny, &out);
  for (int q = 0; q < grid.size(); ++q) {
    model_out[q] = out[q].a;
    for (int k = 0; jacobian != nullptr && k < kNumSpotParams; ++k) {
      jacobian[q * kNumSpotParams + k] = out[q].v[k];
    }
    if constexpr (N > kNumSpotParams) {
      offset_jacobian[2 * q] = out[q].v[kNumSpotParams];
      offset_jacobian[2 * q + 1] = out[q].v[kNumSpotParams + 1];
    }
  }
}

}  // namespace

void RenderPixelCentre(const model::SpotParams& params, const model::PixelGrid& grid,
                       double* model_out, double* jacobian, double defocus_dx_px,
                       double defocus_dy_px, double* offset_jacobian) {
  CHECK(grid.x0 == 0.0 && grid.y0 == 0.0) << "pixel_centre sampling works on stamp indices";
  {
    // The Airy table must reach the farthest pixel: v = pi d / (r / Rz).
    const double x = params[kCentreX], y = params[kCentreY];
    const double dx = std::max(std::fabs(x), std::fabs(grid.nx - 1 - x));
    const double dy = std::max(std::fabs(y), std::fabs(grid.ny - 1 - y));
    model::EnsureAiryTable(M_PI * std::hypot(dx, dy) * model::kAiryRz / params[kAiryRadius]);
  }
  if (jacobian == nullptr && offset_jacobian == nullptr) {
    std::vector<double> out;
    RenderTemplated(params.data(), defocus_dx_px, defocus_dy_px, grid.nx, grid.ny, &out);
    std::copy(out.begin(), out.end(), model_out);
    return;
  }
  if (offset_jacobian == nullptr) {
    RenderWithJets<kNumSpotParams>(params, defocus_dx_px, defocus_dy_px, grid, model_out, jacobian,
                                   nullptr);
  } else {
    // Two more derivative slots: the defocus offset's (F's centre alone).
    RenderWithJets<kNumSpotParams + 2>(params, defocus_dx_px, defocus_dy_px, grid, model_out,
                                       jacobian, offset_jacobian);
  }
}

}  // namespace ccdpsf::internal
