#include "ccdpsf/model/boundary_shift.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "ccdpsf/model/effects.h"
#include "glog/logging.h"

namespace ccdpsf::model {

namespace {

constexpr int kLag = kBoundaryShiftLagRange;
constexpr int kReach = kBoundaryShiftReach;
// The periodic lattice K is solved on (side, in pixels).
constexpr int kLattice = 128;

// Parameter p's coefficient at lag (i, j) without a_00 (which the sum rule sets).
double OffCentre(int p, int i, int j) {
  const int ai = std::abs(i), aj = std::abs(j);
  if (ai > kLag || aj > kLag || (ai == 0 && aj == 0)) return 0.0;
  switch (p) {
    case 0:
      return ai == 1 && aj == 0 ? 1.0 : 0.0;
    case 1:
      return ai == 0 && aj == 1 ? 1.0 : 0.0;
    case 2:
      return ai == 1 && aj == 1 ? 1.0 : 0.0;
    case 3: {
      const double r2 = static_cast<double>(ai * ai + aj * aj);
      return r2 >= 4.0 ? std::pow(4.0 / r2, 0.5 * kBoundaryShiftFarExponent) : 0.0;
    }
    case kBoundaryShiftAnisotropy:
      return 0.0;  // moves boundaries, changes no area
  }
  LOG(FATAL) << "boundary_shift has no parameter " << p;
  return 0.0;
}

}  // namespace

std::array<double, kNumBoundaryShiftParams> BoundaryShiftValues(const BoundaryShiftParams& p) {
  return {p.a_10, p.a_01, p.a_11, p.a_far, p.anisotropy};
}

double BoundaryShiftBasisCoefficient(int parameter, int i, int j) {
  if (i != 0 || j != 0) return OffCentre(parameter, i, j);
  double sum = 0.0;  // the sum rule
  for (int l = -kLag; l <= kLag; ++l) {
    for (int k = -kLag; k <= kLag; ++k) sum += OffCentre(parameter, k, l);
  }
  return -sum;
}

double BoundaryShiftCoefficient(const BoundaryShiftParams& p, int i, int j) {
  const auto values = BoundaryShiftValues(p);
  double a = 0.0;
  for (int q = 0; q < kNumBoundaryShiftCoefficients; ++q) {
    a += values[q] * BoundaryShiftBasisCoefficient(q, i, j);
  }
  return a;
}

// K solves lap K = a on the periodic lattice. Every pattern is even in i and in j, so its
// discrete Fourier transform is the cosine sum a^(u, v) = sum_ij a_ij cos(w u i) cos(w v j),
// w = 2 pi / N; the Laplacian's eigenvalue there is 2 cos(w u) + 2 cos(w v) - 4, and the mean
// (u = v = 0, where a^ = 0 by the sum rule) is set to 0: only differences of K are used.
// The anisotropy's K1 = -lap^-1 (dxx - dyy) K0 has the spectrum
// -(2 cos(w u) - 2 cos(w v)) a^ / eigenvalue^2 (dxx's eigenvalue 2 cos(w u) - 2, dyy's 2 cos(w v) - 2).
BoundaryShiftBasis::BoundaryShiftBasis() {
  constexpr int n = kLattice, side = kSide, reach_k = kReach + 1;
  std::vector<double> cosine(static_cast<size_t>(n) * n);  // cos(w u m), m taken mod n
  for (int u = 0; u < n; ++u) {
    for (int m = 0; m < n; ++m) {
      cosine[static_cast<size_t>(u) * n + m] = std::cos(2.0 * M_PI * ((u * m) % n) / n);
    }
  }
  auto c = [&](int u, int m) { return cosine[static_cast<size_t>(u) * n + ((m % n) + n) % n]; };
  dx_.assign(static_cast<size_t>(kNumBoundaryShiftCoefficients) * side * side, 0.0);
  dy_.assign(dx_.size(), 0.0);
  ex_.assign(dx_.size(), 0.0);
  ey_.assign(dx_.size(), 0.0);
  const int kside = 2 * reach_k + 1;
  std::vector<double> spectrum(static_cast<size_t>(n) * n), half(static_cast<size_t>(n) * kside);
  // K0 and K1 on |i|, |j| <= reach + 1.
  std::vector<double> k0(static_cast<size_t>(kside) * kside), k1(k0.size());
  // K(i, j) = (1 / n^2) sum_uv K^(u, v) cos(w u i) cos(w v j), for |i|, |j| <= reach + 1.
  auto transform = [&](std::vector<double>* potential) {
    for (int u = 0; u < n; ++u) {
      for (int j = -reach_k; j <= reach_k; ++j) {
        double sum = 0.0;
        for (int v = 0; v < n; ++v) sum += spectrum[static_cast<size_t>(u) * n + v] * c(v, j);
        half[static_cast<size_t>(u) * kside + (j + reach_k)] = sum;
      }
    }
    for (int j = -reach_k; j <= reach_k; ++j) {
      for (int i = -reach_k; i <= reach_k; ++i) {
        double sum = 0.0;
        for (int u = 0; u < n; ++u)
          sum += half[static_cast<size_t>(u) * kside + (j + reach_k)] * c(u, i);
        (*potential)[static_cast<size_t>(j + reach_k) * kside + (i + reach_k)] =
            sum / (static_cast<double>(n) * n);
      }
    }
  };
  std::vector<double> coefficient_spectrum(static_cast<size_t>(n) * n);
  for (int p = 0; p < kNumBoundaryShiftCoefficients; ++p) {
    // a^(u, v), then K0^ = a^ / eigenvalue and K1^.
    for (int u = 0; u < n; ++u) {
      for (int v = 0; v < n; ++v) {
        double sum = 0.0;
        for (int j = -kLag; j <= kLag; ++j) {
          double row = 0.0;
          for (int i = -kLag; i <= kLag; ++i)
            row += BoundaryShiftBasisCoefficient(p, i, j) * c(u, i);
          sum += row * c(v, j);
        }
        coefficient_spectrum[static_cast<size_t>(u) * n + v] = sum;
      }
    }
    for (int u = 0; u < n; ++u) {
      for (int v = 0; v < n; ++v) {
        const double eigenvalue = 2.0 * c(u, 1) + 2.0 * c(v, 1) - 4.0;
        const double a_hat = coefficient_spectrum[static_cast<size_t>(u) * n + v];
        spectrum[static_cast<size_t>(u) * n + v] =
            (u == 0 && v == 0) ? 0.0 : a_hat / eigenvalue;
      }
    }
    transform(&k0);
    for (int u = 0; u < n; ++u) {
      for (int v = 0; v < n; ++v) {
        const double eigenvalue = 2.0 * c(u, 1) + 2.0 * c(v, 1) - 4.0;
        const double a_hat = coefficient_spectrum[static_cast<size_t>(u) * n + v];
        spectrum[static_cast<size_t>(u) * n + v] =
            (u == 0 && v == 0)
                ? 0.0
                : -(2.0 * c(u, 1) - 2.0 * c(v, 1)) * a_hat / (eigenvalue * eigenvalue);
      }
    }
    transform(&k1);
    auto at_k = [&](const std::vector<double>& k, int i, int j) {
      return k[static_cast<size_t>(j + reach_k) * kside + (i + reach_k)];
    };
    for (int j = -kReach; j <= kReach; ++j) {
      for (int i = -kReach; i <= kReach; ++i) {
        const size_t at = (static_cast<size_t>(p) * side + (j + kReach)) * side + (i + kReach);
        dx_[at] = at_k(k0, i + 1, j) - at_k(k0, i, j);
        dy_[at] = at_k(k0, i, j + 1) - at_k(k0, i, j);
        ex_[at] = dx_[at] + at_k(k1, i + 1, j) - at_k(k1, i, j);
        ey_[at] = -dy_[at] + at_k(k1, i, j + 1) - at_k(k1, i, j);
      }
    }
  }
}

const BoundaryShiftBasis& BoundaryShiftBasis::Get() {
  static const BoundaryShiftBasis* basis = new BoundaryShiftBasis();
  return *basis;
}

namespace {

// sum_q weight_q (potential_scale Dx(q) + anisotropy_scale Ex(q)), likewise along y.
BoundaryShiftKernel CombineKernels(const std::array<double, kNumBoundaryShiftCoefficients>& weight,
                                   double potential_scale, double anisotropy_scale) {
  const BoundaryShiftBasis& basis = BoundaryShiftBasis::Get();
  constexpr int side = BoundaryShiftBasis::kSide;
  BoundaryShiftKernel kernel;
  kernel.dx.assign(static_cast<size_t>(side) * side, 0.0);
  kernel.dy.assign(kernel.dx.size(), 0.0);
  for (int j = -kReach; j <= kReach; ++j) {
    for (int i = -kReach; i <= kReach; ++i) {
      const size_t at = static_cast<size_t>(j + kReach) * side + (i + kReach);
      for (int q = 0; q < kNumBoundaryShiftCoefficients; ++q) {
        if (weight[q] == 0.0) continue;
        kernel.dx[at] += weight[q] * (potential_scale * basis.Dx(q, i, j) +
                                      anisotropy_scale * basis.Ex(q, i, j));
        kernel.dy[at] += weight[q] * (potential_scale * basis.Dy(q, i, j) +
                                      anisotropy_scale * basis.Ey(q, i, j));
      }
    }
  }
  return kernel;
}

std::array<double, kNumBoundaryShiftCoefficients> Coefficients(const BoundaryShiftParams& p) {
  return {p.a_10, p.a_01, p.a_11, p.a_far};
}

}  // namespace

BoundaryShiftKernel MakeBoundaryShiftKernel(const BoundaryShiftParams& p) {
  return CombineKernels(Coefficients(p), 1.0, p.anisotropy);
}

BoundaryShiftKernel MakeBoundaryShiftDerivativeKernel(const BoundaryShiftParams& p,
                                                      int parameter) {
  CHECK(parameter >= 0 && parameter < kNumBoundaryShiftParams) << parameter;
  if (parameter == kBoundaryShiftAnisotropy) return CombineKernels(Coefficients(p), 0.0, 1.0);
  std::array<double, kNumBoundaryShiftCoefficients> unit{};
  unit[parameter] = 1.0;
  return CombineKernels(unit, 1.0, p.anisotropy);
}

PixelWindow BoundaryShiftWindow(int centre_i, int centre_j, int nx, int ny) {
  constexpr int h = kBoundaryShiftWindowHalf;
  return {std::max(0, centre_i - h), std::min(nx - 1, centre_i + h), std::max(0, centre_j - h),
          std::min(ny - 1, centre_j + h)};
}

// One axis of S(Q), the rate at which charge moves when the boundaries stand as the charge Q
// has them (boundary_shift.h), added into `change`. Boundary b of a line (b = 0 .. n, between
// pixels b - 1 and b of the line; b = 0 the lower edge of pixel 0) moves by the sum over the
// window's charges of the shift kernel, and moves shift x density of charge from pixel b to
// pixel b - 1 (a positive shift enlarges pixel b - 1). For axis 0 the lines are rows j and the
// boundary densities `density` are laid out (nx + 1) x ny; for axis 1 columns i, nx x (ny + 1).
// Derivative channels by the chain rule; the parameters' own channels add the shifts of
// their derivative kernels (`basis`, null when no channel asks).
namespace {

void AddMovesAlongAxis(int axis, const BoundaryShiftKernel& kernel,
                       const std::array<BoundaryShiftKernel, kNumBoundaryShiftParams>* basis,
                       const std::array<int, kNumBoundaryShiftParams>& parameter_channels,
                       const DualImage& density, const PixelWindow& w, const DualImage& charge,
                       DualImage* change) {
  const int nx = charge.nx, s = charge.stride();
  CHECK_EQ(density.stride(), s);
  std::vector<double> shift(s), flow(s);
  std::array<double, kNumBoundaryShiftParams> shift_p{};
  // Boundaries of the window: b from its first pixel's lower edge to its last pixel's upper
  // edge, on every line of the window.
  const int line_lo = axis == 0 ? w.j0 : w.i0, line_hi = axis == 0 ? w.j1 : w.i1;
  const int b_lo = axis == 0 ? w.i0 : w.j0, b_hi = (axis == 0 ? w.i1 : w.j1) + 1;
  for (int line = line_lo; line <= line_hi; ++line) {
    for (int b = b_lo; b <= b_hi; ++b) {
      // The boundary is pixel (b - 1)'s upper edge: X(b - 1, line) in boundary_shift.h.
      const int bi = axis == 0 ? b - 1 : line, bj = axis == 0 ? line : b - 1;
      std::fill(shift.begin(), shift.end(), 0.0);
      shift_p.fill(0.0);
      for (int l = w.j0; l <= w.j1; ++l) {
        for (int k = w.i0; k <= w.i1; ++k) {
          const double d = axis == 0 ? kernel.Dx(bi - k, bj - l) : kernel.Dy(bi - k, bj - l);
          const double* q = charge.data.data() + (static_cast<size_t>(l) * nx + k) * s;
          for (int c = 0; c < s; ++c) shift[c] += d * q[c];
          if (basis == nullptr) continue;
          for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
            if (parameter_channels[p] < 0) continue;
            const BoundaryShiftKernel& bp = (*basis)[p];
            shift_p[p] += (axis == 0 ? bp.Dx(bi - k, bj - l) : bp.Dy(bi - k, bj - l)) * q[0];
          }
        }
      }
      // Density at this boundary: row `line`, entry b (axis 0), or column `line`, entry b.
      const size_t at =
          axis == 0 ? static_cast<size_t>(line) * (nx + 1) + b : static_cast<size_t>(b) * nx + line;
      const double* L = density.data.data() + at * s;
      flow[0] = shift[0] * L[0];
      for (int c = 1; c < s; ++c) flow[c] = shift[0] * L[c] + shift[c] * L[0];
      for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
        if (parameter_channels[p] >= 0) flow[parameter_channels[p]] += shift_p[p] * L[0];
      }
      // Pixel b - 1 gains the flow, pixel b loses it (where they are on the image).
      const int n_line = axis == 0 ? nx : charge.ny;
      for (int side = 0; side < 2; ++side) {
        const int pix = b - 1 + side;
        if (pix < 0 || pix >= n_line) continue;
        const size_t q =
            axis == 0 ? static_cast<size_t>(line) * nx + pix : static_cast<size_t>(pix) * nx + line;
        double* out = change->data.data() + q * s;
        const double sign = side == 0 ? 1.0 : -1.0;
        for (int c = 0; c < s; ++c) out[c] += sign * flow[c];
      }
    }
  }
}

}  // namespace

void ApplyBoundaryShift(const BoundaryShiftParams& params, const DualImage& density_x,
                        const DualImage& density_y, const PixelWindow& window,
                        const EffectChannels& channels, DualImage* image) {
  CHECK_EQ(density_x.nx, image->nx + 1);
  CHECK_EQ(density_x.ny, image->ny);
  CHECK_EQ(density_y.nx, image->nx);
  CHECK_EQ(density_y.ny, image->ny + 1);
  CHECK(window.i0 >= 0 && window.i1 < image->nx && window.j0 >= 0 && window.j1 < image->ny &&
        window.i0 <= window.i1 && window.j0 <= window.j1);
  const BoundaryShiftKernel kernel = MakeBoundaryShiftKernel(params);
  std::array<int, kNumBoundaryShiftParams> parameter_channels;
  bool any = false;
  for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
    parameter_channels[p] = channels.Get(EffectKind::kBoundaryShift, p);
    any = any || parameter_channels[p] >= 0;
  }
  // The kernels' derivatives by each parameter, for their channels: the shifts are linear in
  // the a's at fixed eta, and in eta at fixed a's.
  std::array<BoundaryShiftKernel, kNumBoundaryShiftParams> basis;
  if (any) {
    for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
      if (parameter_channels[p] >= 0) basis[p] = MakeBoundaryShiftDerivativeKernel(params, p);
    }
  }
  // S(Q): the rate of moves at charge Q (the line densities are the incident light's, fixed).
  auto moves = [&](const DualImage& charge) {
    DualImage change{charge.nx, charge.ny, charge.num_derivatives,
                     std::vector<double>(charge.data.size(), 0.0)};
    for (int axis = 0; axis < 2; ++axis) {
      AddMovesAlongAxis(axis, kernel, any ? &basis : nullptr, parameter_channels,
                        axis == 0 ? density_x : density_y, window, charge, &change);
    }
    return change;
  };
  // dQ/dt = M + S(Q(t)), Q(0) = 0, over the exposure t in [0, 1]: Q(1) = M + S M / 2 + S^2 M / 6
  // + ..., the exponential series of the linear S, kept to second order (the third is below
  // 1e-3 of the effect at a 2e5 e- peak).
  const DualImage first = moves(*image);
  const DualImage second = moves(first);
  for (size_t e = 0; e < image->data.size(); ++e) {
    image->data[e] += first.data[e] / 2.0 + second.data[e] / 6.0;
  }
}

}  // namespace ccdpsf::model
