// Exact pixel integration of the spot model.
//
// Write the model as a radially symmetric image S (the Airy pattern, or the Airy pattern
// convolved with the pillbox) convolved with a separable kernel K = kx(x) ky(y), where kx is
// a Gaussian of total width sX convolved with the unit pixel box (pixel_kernel.h):
//
//   M(a, b) = Integral S(p - c) kx(xa - px) ky(yb - py) dp.
//
// With a Gaussian defocus both Gaussians merge, sX^2 = sigma_f^2 + sigma_x^2 (the origin of
// docs/trust.md, single focus); with a pillbox, sX = sigma_x and S carries the disc.
//
// The integral is evaluated with the uniform (trapezoidal) rule on nodes p = c + (i hX, j hY),
// done as two one-dimensional passes because K is separable:
//   first pass  B(i, b) = hY sum_j S(i, j) ky(yb - cy - j hY)       for every node column i,
//   second pass M(a, b) = hX sum_i kx(xa - cx - i hX) B(i, b).
// Error bound. By Poisson summation the uniform rule's error is the integrand's Fourier
// transform at multiples of 1/h. S is band-limited to the Airy cut-off rho_c = Rz / r (its
// transform is the circular-pupil OTF, zero beyond rho_c), and the kernel's transform is
// exp(-2 pi^2 s^2 f^2) sinc(f). So the error of one pass is at most
//   (8 rho_c^2 / (pi D)) exp(-2 pi^2 s^2 D^2) times the flux,   D = 1/h - rho_c,
// and QuadratureStep picks h so that this is below the tolerance. The rule is exact up to
// that bound for any centre: nodes move with the centre, so S is evaluated at fixed offsets.
// Truncation: a node contributes to pixel a only while |xa - node| <= 1/2 + T sX, with T
// chosen so the Gaussian tail beyond it is below the tolerance. The Airy tail beyond the
// stamp never needs truncating: it reaches the stamp only through the kernel.
//
// Derivatives are those of the quadrature sum itself (the node spacing is piecewise
// constant in the widths: QuadratureStep quantises 1/h), so they are exact for the values
// returned: centre and widths enter only through the kernels, the Airy radius (and pillbox
// radius) only through S.
#include "internal/integrated_renderer.h"

#include <algorithm>
#include <cmath>

#include "ccdpsf/model/airy.h"
#include "glog/logging.h"
#include "internal/gauss_legendre.h"
#include "internal/pixel_kernel.h"

namespace ccdpsf::internal {

using model::kAiryRadius;
using model::kCcdSigmaX;
using model::kCcdSigmaY;
using model::kCentreX;
using model::kCentreY;
using model::kDefocus;
using model::kFlux;
using model::kNumSpotParams;

namespace {

// Largest number of quadrature nodes allowed in one image: guards against parameters far
// outside anything physical turning into gigabytes (ValidSpotParams keeps us well below).
constexpr double kMaxNodes = 3.0e7;

// Half-width of the Gaussian kernel in units of its sigma beyond which its tail mass is
// below `tolerance` (one-sided normal tail bound exp(-T^2/2) / 2).
double KernelHalfWidthSigmas(double tolerance) {
  return std::sqrt(2.0 * std::log(0.5 / tolerance)) + 0.5;
}

// Unit-flux Airy intensity at distance d [px] for wavenumber k = pi Rz / r [1/px], and its
// derivative with respect to k. I = k^2 / (4 pi) a(k d)^2 integrates to 1 over the plane.
inline void AiryIntensity(double d, double k, double* value, double* d_dk) {
  static const double* const table = model::AiryTableCoefficients();
  double a, da;
  model::AiryAmplitudeAndDerivativeInline(k * d, table, &a, &da);
  const double norm = k * k / (4.0 * M_PI);
  *value = norm * a * a;
  *d_dk = k / (2.0 * M_PI) * (a * a + a * da * k * d);
}

// The Airy amplitude a(v) and, when damp is not null, da/dv at n points v >= 0 from the
// table's quintic pieces (airy.h), as AiryAmplitudeAndDerivativeInline computes them; v at
// or past kAiryTableMax reads the last piece and must be redone by the caller. (Scalar: AVX2
// gathers of the coefficients measured slower on the development machine.)
void TablePolynomial(const double* table, int n, const double* v, double* amp, double* damp) {
  constexpr double kInvStep = 1.0 / model::kAiryTableStep;
  const int last = static_cast<int>(std::lround(model::kAiryTableMax * kInvStep)) - 1;
  for (int t = 0; t < n; ++t) {
    const double sv = std::min(v[t], model::kAiryTableMax) * kInvStep;
    const int i = std::min(static_cast<int>(sv), last);
    const double u = sv - i;
    const double* c = table + 6 * static_cast<long>(i);
    amp[t] = c[0] + u * (c[1] + u * (c[2] + u * (c[3] + u * (c[4] + u * c[5]))));
    if (damp != nullptr) {
      damp[t] = (c[1] + u * (2 * c[2] + u * (3 * c[3] + u * (4 * c[4] + u * 5 * c[5])))) * kInvStep;
    }
  }
}

// S for the Gaussian-defocus model: the Airy pattern itself.
// Each quadrant column is done in chunks, in separate vectorised loops: the distances
// (square roots), then the table's polynomials (TablePolynomial), then the rare nodes past the
// table's end (exact Bessel functions) fixed up one by one. The values are those of
// AiryIntensity node by node.
void FillAiryQuadrant(double k, double dk_dr, double hx, double hy, bool derivs,
                      Eigen::MatrixXd* q, Eigen::MatrixXd* q_dr) {
  // With equal spacings S(|i|, |j|) = S(|j|, |i|): compute the lower triangle, mirror the rest.
  static const double* const table = model::AiryTableCoefficients();
  const bool mirror = hx == hy;
  const int rows = static_cast<int>(q->rows());
  const double norm = k * k / (4.0 * M_PI);
  const double dnorm = k / (2.0 * M_PI) * dk_dr;  // d(norm a^2)/dr = dnorm (a^2 + a da k d)
  constexpr int kChunk = 64;
  double v[kChunk], amp[kChunk], damp[kChunk];
  for (int ju = 0; ju < q->cols(); ++ju) {
    const double y2 = (ju * hy) * (ju * hy);
    const int first = (mirror && ju < rows) ? ju : 0;
    double* col = q->data() + static_cast<size_t>(ju) * rows;
    double* col_dr = derivs ? q_dr->data() + static_cast<size_t>(ju) * rows : nullptr;
    for (int start = first; start < rows; start += kChunk) {
      const int n = std::min(kChunk, rows - start);
      for (int t = 0; t < n; ++t) {
        const double x = (start + t) * hx;
        v[t] = k * std::sqrt(x * x + y2);
      }
      // The table's polynomial where v is inside it (index clamped so the loop has no branch;
      // entries past the end are redone below).
      if (!derivs) {
        TablePolynomial(table, n, v, amp, nullptr);
        for (int t = 0; t < n; ++t) {
          if (v[t] >= model::kAiryTableMax) amp[t] = model::AiryAmplitude(v[t]);
        }
        for (int t = 0; t < n; ++t) col[start + t] = norm * amp[t] * amp[t];
        continue;
      }
      TablePolynomial(table, n, v, amp, damp);
      for (int t = 0; t < n; ++t) {
        if (v[t] >= model::kAiryTableMax) {
          model::AiryAmplitudeAndDerivative(v[t], &amp[t], &damp[t]);
        }
      }
      for (int t = 0; t < n; ++t) {
        col[start + t] = norm * amp[t] * amp[t];
        col_dr[start + t] = dnorm * (amp[t] * amp[t] + amp[t] * damp[t] * v[t]);
      }
    }
  }
  if (!mirror) return;
  for (int ju = 1; ju < std::min<int>(q->cols(), rows); ++ju) {
    for (int iu = 0; iu < ju; ++iu) {
      (*q)(iu, ju) = (*q)(ju, iu);
      if (derivs) (*q_dr)(iu, ju) = (*q_dr)(ju, iu);
    }
  }
}

// S for the pillbox model: the mean of the Airy intensity over a disc of radius R around
// each node, by Gauss-Legendre in radius and the (spectrally accurate) midpoint rule in
// angle. The angular integrand has Fourier modes up to about 2 pi rho_c R, the radial one is
// entire; node counts follow with a margin that the reference tests confirm.
void FillPillboxQuadrant(double k, double dk_dr, double rho_c, double radius, double hx,
                         double hy, Eigen::MatrixXd* q, Eigen::MatrixXd* q_dr,
                         Eigen::MatrixXd* q_dR) {
  const int n_full = static_cast<int>(std::ceil(2.0 * M_PI * rho_c * radius * 1.1 + 20.0));
  const int n_theta = (n_full + 1) / 2;  // midpoints on [0, pi]; the integrand is even in theta
  const int n_rho = static_cast<int>(std::ceil(M_PI * rho_c * radius + 10.0));
  const GaussLegendreRule& gl = GaussLegendre(n_rho);
  std::vector<double> cos_theta(n_theta);
  for (int l = 0; l < n_theta; ++l) cos_theta[l] = std::cos(M_PI * (l + 0.5) / n_theta);
  std::vector<double> rho(n_rho), w_rho(n_rho);
  const double area = M_PI * radius * radius;
  for (int m = 0; m < n_rho; ++m) {
    rho[m] = 0.5 * radius * (gl.nodes[m] + 1.0);
    // Integral over the disc = sum_m (R/2) w_m rho_m * (2 pi / n_full_equiv) sum_l A; divided
    // by the disc area to make the mean.
    w_rho[m] = 0.5 * radius * gl.weights[m] * rho[m] * (2.0 * M_PI / (2.0 * n_theta)) * 2.0 / area;
  }
  // With equal spacings S(|i|, |j|) = S(|j|, |i|): compute the lower triangle, mirror the rest
  // (this fill is most of a pillbox render's time).
  const bool mirror = hx == hy;
  const int rows = static_cast<int>(q->rows());
  for (int ju = 0; ju < q->cols(); ++ju) {
    const int first = (mirror && ju < rows) ? ju : 0;
    for (int iu = first; iu < rows; ++iu) {
      const double d = std::hypot(iu * hx, ju * hy);
      double s = 0.0, s_dk = 0.0;
      for (int m = 0; m < n_rho; ++m) {
        double ring = 0.0, ring_dk = 0.0;
        const double base = d * d + rho[m] * rho[m];
        for (int l = 0; l < n_theta; ++l) {
          const double dist = std::sqrt(std::max(0.0, base - 2.0 * d * rho[m] * cos_theta[l]));
          double v, v_dk;
          AiryIntensity(dist, k, &v, &v_dk);
          ring += v;
          ring_dk += v_dk;
        }
        s += w_rho[m] * ring;
        s_dk += w_rho[m] * ring_dk;
      }
      // Edge circle for dS/dR = (2/R) (mean on the circle of radius R - S).
      double circle = 0.0;
      const double base = d * d + radius * radius;
      for (int l = 0; l < n_theta; ++l) {
        const double dist = std::sqrt(std::max(0.0, base - 2.0 * d * radius * cos_theta[l]));
        double v, v_dk;
        AiryIntensity(dist, k, &v, &v_dk);
        circle += v;
      }
      circle /= n_theta;
      (*q)(iu, ju) = s;
      (*q_dr)(iu, ju) = s_dk * dk_dr;
      (*q_dR)(iu, ju) = 2.0 / radius * (circle - s);
    }
  }
  if (!mirror) return;
  for (int ju = 1; ju < std::min<int>(q->cols(), rows); ++ju) {
    for (int iu = 0; iu < ju; ++iu) {
      (*q)(iu, ju) = (*q)(ju, iu);
      (*q_dr)(iu, ju) = (*q_dr)(ju, iu);
      (*q_dR)(iu, ju) = (*q_dR)(ju, iu);
    }
  }
}

// Kernel weights along one axis. With an integer node density Q = 1/h, the nodes seen by
// pixel n + 1 are those seen by pixel n shifted by exactly Q, with the same weights; so one
// window of weights serves every pixel of the axis: pixel n uses nodes first + Q n + m,
// m = 0..size-1, with weights row m.
struct AxisWeights {
  int first = 0;   // first node index seen by pixel 0
  int q = 1;       // node shift per pixel (= 1/h)
  Eigen::MatrixXd w;  // (size x 3): h k, d(h k)/d centre, d(h k)/d width
};

void ComputeAxisWeights(double pixel0, double centre, double h, int q, double half_width,
                        double s, double window, bool derivs, AxisWeights* aw) {
  aw->q = q;
  aw->first = static_cast<int>(std::ceil((pixel0 - centre - half_width) * q));
  const int last = static_cast<int>(std::floor((pixel0 - centre + half_width) * q));
  const int size = last - aw->first + 1;
  aw->w.resize(size, derivs ? 3 : 1);
  for (int m = 0; m < size; ++m) {
    const PixelKernelValue kv = PixelKernel(pixel0 - centre - (aw->first + m) * h, s, window);
    aw->w(m, 0) = h * kv.value;
    if (derivs) {
      aw->w(m, 1) = -h * kv.d_dt;  // t = pixel - centre - node: d/dcentre = -d/dt
      aw->w(m, 2) = h * kv.d_ds;
    }
  }
}

// The inner loops of both passes, as functions whose restrict-qualified arguments tell the
// compiler the arrays do not overlap, so that it vectorises them.
// out += w * x
inline void Axpy(int n, double w, const double* __restrict x, double* __restrict out) {
  for (int i = 0; i < n; ++i) out[i] += w * x[i];
}
// out0 += w0 x, out1 += w1 x, out2 += w2 x: one input with three weights.
inline void Axpy3(int n, double w0, double w1, double w2, const double* __restrict x,
                  double* __restrict out0, double* __restrict out1, double* __restrict out2) {
  for (int i = 0; i < n; ++i) {
    out0[i] += w0 * x[i];
    out1[i] += w1 * x[i];
    out2[i] += w2 * x[i];
  }
}

// Four inputs at once ("register blocking"): each pass of the output then carries four
// weighted inputs instead of one, so the output is loaded and stored a quarter as often.
// out += w[0] x0 + w[1] x1 + w[2] x2 + w[3] x3.
inline void Axpy4(int n, const double* w, const double* __restrict x0, const double* __restrict x1,
                  const double* __restrict x2, const double* __restrict x3,
                  double* __restrict out) {
  const double a = w[0], b = w[1], c = w[2], d = w[3];
  for (int i = 0; i < n; ++i) out[i] += a * x0[i] + b * x1[i] + c * x2[i] + d * x3[i];
}
// The three-weight form of Axpy3 over four inputs: out_r += sum_t w_r[t] x_t, r = 0, 1, 2.
inline void Axpy3x4(int n, const double* w0, const double* w1, const double* w2,
                    const double* __restrict x0, const double* __restrict x1,
                    const double* __restrict x2, const double* __restrict x3,
                    double* __restrict out0, double* __restrict out1, double* __restrict out2) {
  for (int i = 0; i < n; ++i) {
    const double v0 = x0[i], v1 = x1[i], v2 = x2[i], v3 = x3[i];
    out0[i] += w0[0] * v0 + w0[1] * v1 + w0[2] * v2 + w0[3] * v3;
    out1[i] += w1[0] * v0 + w1[1] * v1 + w1[2] * v2 + w1[3] * v3;
    out2[i] += w2[0] * v0 + w2[1] * v1 + w2[2] * v2 + w2[3] * v3;
  }
}

}  // namespace

double QuadratureStep(double rho_c, double s, double tolerance) {
  // Solve 2 pi^2 s^2 D^2 = log(8 rho_c^2 / (pi D tol)) by a few fixed-point steps.
  double delta = 1.0;
  for (int iter = 0; iter < 6; ++iter) {
    const double rhs = std::log(std::max(8.0 * rho_c * rho_c / (M_PI * delta * tolerance), 2.0));
    delta = std::max(std::sqrt(rhs / (2.0 * M_PI * M_PI * s * s)), 0.25);
  }
  // An integer number of nodes per pixel: the spacing is piecewise constant in the widths (so
  // the derivatives are those of the sum), and every pixel sees the same kernel weights.
  return 1.0 / std::ceil(rho_c + delta);
}

void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& p,
                      const model::PixelGrid& grid, double* model_out, double* jacobian,
                      IntegratedWorkspace* ws) {
  const bool pillbox = options.defocus == model::DefocusKind::kPillbox;
  const double cx = p[kCentreX], cy = p[kCentreY];
  const double r = p[kAiryRadius];
  const double defocus = p[kDefocus];
  const double sx = pillbox ? p[kCcdSigmaX] : std::hypot(defocus, p[kCcdSigmaX]);
  const double sy = pillbox ? p[kCcdSigmaY] : std::hypot(defocus, p[kCcdSigmaY]);
  const double rho_c = model::kAiryRz / r;
  const double k = M_PI * model::kAiryRz / r;
  const double dk_dr = -k / r;
  const double tol = options.relative_tolerance;

  const double hx = QuadratureStep(rho_c, sx, tol);
  const double hy = QuadratureStep(rho_c, sy, tol);
  const int qx = static_cast<int>(std::lround(1.0 / hx));
  const int qy = static_cast<int>(std::lround(1.0 / hy));
  const double tw = KernelHalfWidthSigmas(tol);
  const bool derivs = jacobian != nullptr;

  AxisWeights wx, wy;
  // A collecting window narrower than the pixel (ModelOptions::pixel_response_width) only
  // shortens the reach of each node; the error bound holds as it is (|sinc(w f)| <= 1).
  const double window = options.pixel_response_width;
  ComputeAxisWeights(grid.x0, cx, hx, qx, 0.5 * window + tw * sx, sx, window, derivs, &wx);
  ComputeAxisWeights(grid.y0, cy, hy, qy, 0.5 * window + tw * sy, sy, window, derivs, &wy);
  // Node ranges: every node some pixel of the grid sees.
  const int i_lo = wx.first, i_hi = wx.first + qx * (grid.nx - 1) + wx.w.rows() - 1;
  const int j_lo = wy.first, j_hi = wy.first + qy * (grid.ny - 1) + wy.w.rows() - 1;
  const int ni = i_hi - i_lo + 1, nj = j_hi - j_lo + 1;
  CHECK_LE(static_cast<double>(ni) * nj, kMaxNodes) << "quadrature grid too large";

  // Radial image S on the nodes, through the symmetric quadrant.
  const int iu_max = std::max(std::abs(i_lo), std::abs(i_hi));
  const int ju_max = std::max(std::abs(j_lo), std::abs(j_hi));
  ws->quadrant.resize(iu_max + 1, ju_max + 1);
  ws->quadrant_dr.resize(iu_max + 1, ju_max + 1);
  if (pillbox && defocus > 0.0) {
    ws->quadrant_dR.resize(iu_max + 1, ju_max + 1);
    FillPillboxQuadrant(k, dk_dr, rho_c, defocus, hx, hy, &ws->quadrant, &ws->quadrant_dr,
                        &ws->quadrant_dR);
  } else {
    FillAiryQuadrant(k, dk_dr, hx, hy, jacobian != nullptr, &ws->quadrant, &ws->quadrant_dr);
    // A pillbox of zero radius: S = Airy, and dS/dR = 0 there (S - Airy is O(R^2)).
    if (pillbox) ws->quadrant_dR.setZero(iu_max + 1, ju_max + 1);
  }
  const int nh = iu_max + 1;  // rows |i| of the half problem

  // First pass, along y: B(|i|, b) = hy sum_j S(|i|, j) ky(yb - cy - j hy), and the same
  // with d ky / d cy, d ky / d sY, and with dS / dr (and dS / dR): nr right-hand sides.
  // Hand-written loops: at these sizes (~75 x 40 per output row) a general matrix product
  // spends more time packing than multiplying. The inner loop runs down a contiguous column
  // of S; each finished row b is stored transposed, bt[(k * nh + |i|) * ny + b], so that the
  // second pass can run its inner loop over b.
  const int nr = derivs ? (pillbox ? 5 : 4) : 1;
  const int ny = grid.ny;
  ws->row.resize(static_cast<size_t>(nr) * nh);
  ws->bt.resize(static_cast<size_t>(nr) * nh * ny);
  const int wy_size = static_cast<int>(wy.w.rows());
  // Node column j of S is quadrant column |j| (S(i, -j) = S(i, j)), read in place.
  const double* s_val = ws->quadrant.data();
  const double* s_dr = ws->quadrant_dr.data();
  const double* s_dR = pillbox ? ws->quadrant_dR.data() : nullptr;
  double* out = ws->row.data();
  for (int b = 0; b < ny; ++b) {
    std::fill(ws->row.begin(), ws->row.end(), 0.0);
    int m = 0;
    for (; m + 4 <= wy_size; m += 4) {
      size_t col[4];
      double w0[4], w1[4], w2[4];
      for (int t = 0; t < 4; ++t) {
        col[t] = static_cast<size_t>(std::abs(j_lo + qy * b + m + t)) * nh;
        w0[t] = wy.w(m + t, 0);
        if (derivs) w1[t] = wy.w(m + t, 1), w2[t] = wy.w(m + t, 2);
      }
      if (!derivs) {
        Axpy4(nh, w0, s_val + col[0], s_val + col[1], s_val + col[2], s_val + col[3], out);
        continue;
      }
      Axpy3x4(nh, w0, w1, w2, s_val + col[0], s_val + col[1], s_val + col[2], s_val + col[3], out,
              out + nh, out + 2 * nh);
      Axpy4(nh, w0, s_dr + col[0], s_dr + col[1], s_dr + col[2], s_dr + col[3], out + 3 * nh);
      if (pillbox) {
        Axpy4(nh, w0, s_dR + col[0], s_dR + col[1], s_dR + col[2], s_dR + col[3], out + 4 * nh);
      }
    }
    for (; m < wy_size; ++m) {
      const size_t col = static_cast<size_t>(std::abs(j_lo + qy * b + m)) * nh;
      const double* sv = s_val + col;
      const double w0 = wy.w(m, 0);
      if (!derivs) {
        Axpy(nh, w0, sv, out);
        continue;
      }
      Axpy3(nh, w0, wy.w(m, 1), wy.w(m, 2), sv, out, out + nh, out + 2 * nh);
      Axpy(nh, w0, s_dr + col, out + 3 * nh);
      if (pillbox) Axpy(nh, w0, s_dR + col, out + 4 * nh);
    }
    for (size_t q = 0; q < ws->row.size(); ++q) ws->bt[q * ny + b] = out[q];
  }

  // Second pass, along x: M(a, b) = hx sum_i kx(xa - cx - i hx) B(|i|, b), vectorised over b.
  const double flux = p[kFlux];
  const double gx = (!pillbox && sx > 0) ? defocus / sx : 0.0;  // d sX / d sigma_f
  const double gy = (!pillbox && sy > 0) ? defocus / sy : 0.0;
  const double fx = pillbox ? 1.0 : p[kCcdSigmaX] / sx;          // d sX / d sigma_x
  const double fy = pillbox ? 1.0 : p[kCcdSigmaY] / sy;
  const int wx_size = static_cast<int>(wx.w.rows());
  const int nacc = derivs ? (pillbox ? 7 : 6) : 1;
  ws->acc.resize(static_cast<size_t>(nacc) * ny);
  double* acc = ws->acc.data();
  const double* bt = ws->bt.data();
  const size_t plane = static_cast<size_t>(nh) * ny;  // one right-hand side in bt
  for (int a = 0; a < grid.nx; ++a) {
    std::fill(ws->acc.begin(), ws->acc.end(), 0.0);
    const int first = i_lo + qx * a;
    int m = 0;
    for (; m + 4 <= wx_size; m += 4) {
      const double* v[4];
      double w0[4], w1[4], w2[4];
      for (int t = 0; t < 4; ++t) {
        v[t] = bt + static_cast<size_t>(std::abs(first + m + t)) * ny;
        w0[t] = wx.w(m + t, 0);
        if (derivs) w1[t] = wx.w(m + t, 1), w2[t] = wx.w(m + t, 2);
      }
      if (!derivs) {
        Axpy4(ny, w0, v[0], v[1], v[2], v[3], acc);
        continue;
      }
      Axpy3x4(ny, w0, w1, w2, v[0], v[1], v[2], v[3], acc, acc + ny, acc + 2 * ny);
      for (int r = 1; r <= (pillbox ? 4 : 3); ++r) {
        const size_t o = r * plane;
        Axpy4(ny, w0, v[0] + o, v[1] + o, v[2] + o, v[3] + o, acc + (2 + r) * ny);
      }
    }
    for (; m < wx_size; ++m) {
      const double* v = bt + static_cast<size_t>(std::abs(first + m)) * ny;
      const double w0 = wx.w(m, 0);
      // acc rows: value, d/dcx, d/dsX, d/dcy, d/dsY, d/dr, d/dR.
      if (!derivs) {
        Axpy(ny, w0, v, acc);
        continue;
      }
      Axpy3(ny, w0, wx.w(m, 1), wx.w(m, 2), v, acc, acc + ny, acc + 2 * ny);
      Axpy(ny, w0, v + plane, acc + 3 * ny);
      Axpy(ny, w0, v + 2 * plane, acc + 4 * ny);
      Axpy(ny, w0, v + 3 * plane, acc + 5 * ny);
      if (pillbox) Axpy(ny, w0, v + 4 * plane, acc + 6 * ny);
    }
    for (int b = 0; b < ny; ++b) {
      const int pix = b * grid.nx + a;
      model_out[pix] = flux * acc[b];
      if (!derivs) continue;
      double* row = jacobian + static_cast<size_t>(pix) * kNumSpotParams;
      const double d_sx = acc[2 * ny + b], d_sy = acc[4 * ny + b];
      row[kFlux] = acc[b];
      row[kCentreX] = flux * acc[ny + b];
      row[kCentreY] = flux * acc[3 * ny + b];
      row[kAiryRadius] = flux * acc[5 * ny + b];
      row[kDefocus] = pillbox ? flux * acc[6 * ny + b] : flux * (d_sx * gx + d_sy * gy);
      row[kCcdSigmaX] = flux * d_sx * fx;
      row[kCcdSigmaY] = flux * d_sy * fy;
    }
  }
}

}  // namespace ccdpsf::internal
