#include "ccdpsf/model/boundary_shift.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include <Eigen/Dense>

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
  for (int q = 0; q < kNumBoundaryShiftCoefficients; ++q) {
    if (weight[q] == 0.0) continue;
    const double potential = weight[q] * potential_scale, anisotropy = weight[q] * anisotropy_scale;
    const double *dx = basis.DxTable(q), *dy = basis.DyTable(q), *ex = basis.ExTable(q),
                 *ey = basis.EyTable(q);
    for (size_t at = 0; at < kernel.dx.size(); ++at) {
      kernel.dx[at] += potential * dx[at] + anisotropy * ex[at];
      kernel.dy[at] += potential * dy[at] + anisotropy * ey[at];
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

// S(Q), the rate at which charge moves when the boundaries stand as the charge Q has them
// (boundary_shift.h), as matrices. Boundary r of an axis (axis 0: the boundaries x = const of
// the window's rows, axis 1: y = const of its columns; b from the window's first pixel's lower
// edge to its last pixel's upper edge) moves by shift_r = sum_w K(r, w) Q_w over the window's
// pixels w, and moves shift_r x density_r of charge from the pixel above it to the pixel below
// it (a positive shift enlarges the lower pixel). K depends on the parameters only, the
// densities on the spot only, so K is built once per render and applied to every derivative
// channel of Q at once (one matrix product); the parameters' own channels add the shifts of
// their derivative kernels, applied to Q's values.
namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A kernel padded with zeros to |offset| <= half on both axes, so that building a matrix
// needs no bounds checks (the offsets between a window's boundaries and pixels reach the
// window's side, which may exceed kBoundaryShiftReach), and mirrored along i, so that the
// offsets bi - k of a row of window pixels k = i0, i0 + 1, ... are read forwards.
struct PaddedKernel {
  int half = 0, side = 0;
  std::vector<double> mirrored;  // [j + half][half - i]
  PaddedKernel(const BoundaryShiftKernel& kernel, int axis, int half_in)
      : half(std::max(half_in, kBoundaryShiftReach)), side(2 * half + 1) {
    mirrored.assign(static_cast<size_t>(side) * side, 0.0);
    for (int j = -kBoundaryShiftReach; j <= kBoundaryShiftReach; ++j) {
      for (int i = -kBoundaryShiftReach; i <= kBoundaryShiftReach; ++i) {
        mirrored[static_cast<size_t>(j + half) * side + (half - i)] =
            axis == 0 ? kernel.Dx(i, j) : kernel.Dy(i, j);
      }
    }
  }
  // kernel(bi - k, j) for k = k0, k0 + 1, ...: the pointer's [k - k0].
  const double* Run(int bi, int k0, int j) const {
    return mirrored.data() + static_cast<size_t>(j + half) * side + (half - bi + k0);
  }
};

// Where the boundaries of one axis sit: for boundary r, its density's index in the density
// image and the image pixels below (gains) and above (loses) it, -1 off the image.
struct AxisBoundaries {
  int num = 0;
  std::vector<int> bi, bj;  // the pixel whose upper edge it is: X(bi, bj) in boundary_shift.h
  std::vector<size_t> density_at;
  std::vector<int> lower_pixel, upper_pixel;
};

AxisBoundaries ListBoundaries(int axis, const PixelWindow& w, int nx, int ny) {
  AxisBoundaries a;
  const int line_lo = axis == 0 ? w.j0 : w.i0, line_hi = axis == 0 ? w.j1 : w.i1;
  const int b_lo = axis == 0 ? w.i0 : w.j0, b_hi = (axis == 0 ? w.i1 : w.j1) + 1;
  const int n_line = axis == 0 ? nx : ny;
  for (int line = line_lo; line <= line_hi; ++line) {
    for (int b = b_lo; b <= b_hi; ++b) {
      a.bi.push_back(axis == 0 ? b - 1 : line);
      a.bj.push_back(axis == 0 ? line : b - 1);
      a.density_at.push_back(axis == 0 ? static_cast<size_t>(line) * (nx + 1) + b
                                       : static_cast<size_t>(b) * nx + line);
      auto pixel = [&](int pix) {
        if (pix < 0 || pix >= n_line) return -1;
        return axis == 0 ? line * nx + pix : pix * nx + line;
      };
      a.lower_pixel.push_back(pixel(b - 1));
      a.upper_pixel.push_back(pixel(b));
    }
  }
  a.num = static_cast<int>(a.bi.size());
  return a;
}

// K(r, w) = kernel(bi - k, bj - l) for the window's pixels w = (k, l), row-major, as the rows
// of `m`.
void FillShiftRows(const PaddedKernel& kernel, const AxisBoundaries& boundaries,
                   const PixelWindow& w, RowMatrix* m) {
  const int wx = w.i1 - w.i0 + 1;
  for (int r = 0; r < boundaries.num; ++r) {
    double* row = m->row(r).data();
    for (int l = w.j0; l <= w.j1; ++l) {
      const double* run = kernel.Run(boundaries.bi[r], w.i0, boundaries.bj[r] - l);
      std::copy_n(run, wx, row + static_cast<size_t>(l - w.j0) * wx);
    }
  }
}

// The derivative kernels of the parameters with a channel, interleaved: for each offset, the
// kLanes parameters' values side by side (unused lanes 0), padded and mirrored as
// PaddedKernel. Their shifts are needed for Q's values only (one channel), where building a
// matrix per parameter would cost as much as the product; interleaved, one pass over the
// window gives all of them, the lanes vectorised.
constexpr int kLanes = 8;
static_assert(kLanes >= kNumBoundaryShiftParams);
struct InterleavedKernels {
  int half = 0, side = 0;
  std::vector<double> mirrored;  // [j + half][half - i][lane]
  InterleavedKernels(const std::vector<BoundaryShiftKernel>& kernels, int axis, int half_in)
      : half(std::max(half_in, kBoundaryShiftReach)), side(2 * half + 1) {
    CHECK_LE(kernels.size(), static_cast<size_t>(kLanes));
    mirrored.assign(static_cast<size_t>(side) * side * kLanes, 0.0);
    for (size_t lane = 0; lane < kernels.size(); ++lane) {
      for (int j = -kBoundaryShiftReach; j <= kBoundaryShiftReach; ++j) {
        for (int i = -kBoundaryShiftReach; i <= kBoundaryShiftReach; ++i) {
          mirrored[(static_cast<size_t>(j + half) * side + (half - i)) * kLanes + lane] =
              axis == 0 ? kernels[lane].Dx(i, j) : kernels[lane].Dy(i, j);
        }
      }
    }
  }
  const double* Run(int bi, int k0, int j) const {
    return mirrored.data() + (static_cast<size_t>(j + half) * side + (half - bi + k0)) * kLanes;
  }
};

// shift[r * kLanes + lane] = sum_w K_lane(r, w) values[w].
void ShiftsOfParameters(const InterleavedKernels& kernels, const AxisBoundaries& boundaries,
                        const PixelWindow& w, const double* values, double* shift) {
  const int wx = w.i1 - w.i0 + 1;
  for (int r = 0; r < boundaries.num; ++r) {
    Eigen::Matrix<double, kLanes, 1> sum = Eigen::Matrix<double, kLanes, 1>::Zero();
    for (int l = w.j0; l <= w.j1; ++l) {
      const double* run = kernels.Run(boundaries.bi[r], w.i0, boundaries.bj[r] - l);
      const double* v = values + static_cast<size_t>(l - w.j0) * wx;
      for (int k = 0; k < wx; ++k) {
        sum += v[k] * Eigen::Map<const Eigen::Matrix<double, kLanes, 1>>(run + k * kLanes);
      }
    }
    Eigen::Map<Eigen::Matrix<double, kLanes, 1>>(shift + static_cast<size_t>(r) * kLanes) = sum;
  }
}

// What depends on the parameters and the window's shape only (not on where the window is,
// nor on the spot): the shift matrices of both axes and the parameters' kernels. A joint fit
// applies the effect to every exposure at the same parameters, and its windows share their
// shape, so each thread keeps the last set it built and reuses it while the parameters, the
// channels asked for and the shape stay the same (the results are the same bits either way).
struct ShiftMatrices {
  bool valid = false;
  std::array<double, kNumBoundaryShiftParams> values{};
  std::vector<int> active;
  int wx = 0, wy = 0;
  std::array<RowMatrix, 2> shift_of_charge;
  std::vector<InterleavedKernels> parameter_kernels;
};

const ShiftMatrices& CachedShiftMatrices(const BoundaryShiftParams& params,
                                         const std::vector<int>& active, int wx, int wy,
                                         const std::array<AxisBoundaries, 2>& boundaries,
                                         const PixelWindow& window) {
  thread_local ShiftMatrices cache;
  const auto values = BoundaryShiftValues(params);
  if (cache.valid && cache.values == values && cache.active == active && cache.wx == wx &&
      cache.wy == wy) {
    return cache;
  }
  cache.valid = false;
  const int half = std::max(wx, wy);
  const BoundaryShiftKernel kernel = MakeBoundaryShiftKernel(params);
  std::vector<BoundaryShiftKernel> derivative_kernels;
  for (int p : active) derivative_kernels.push_back(MakeBoundaryShiftDerivativeKernel(params, p));
  cache.parameter_kernels.clear();
  for (int axis = 0; axis < 2; ++axis) {
    cache.shift_of_charge[axis].resize(boundaries[axis].num, wx * wy);
    FillShiftRows(PaddedKernel(kernel, axis, half), boundaries[axis], window,
                  &cache.shift_of_charge[axis]);
    if (!active.empty()) cache.parameter_kernels.emplace_back(derivative_kernels, axis, half);
  }
  cache.values = values;
  cache.active = active;
  cache.wx = wx;
  cache.wy = wy;
  cache.valid = true;
  return cache;
}

}  // namespace

namespace {

// The scratch of ApplyBoundaryShift, kept per thread: an MCMC applies the effect to every
// exposure at every step, where allocating these each time cost more than the arithmetic.
// The boundary lists depend on the window and the image's size only, so they are kept while
// those stay the same.
struct ShiftWorkspace {
  PixelWindow window{-1, -1, -1, -1};
  int nx = -1, ny = -1;
  std::array<AxisBoundaries, 2> boundaries;
  RowMatrix charge_window;
  std::array<RowMatrix, 2> shift;
  std::vector<double> values;
  std::array<std::vector<double>, 2> parameter_shift;
  std::vector<double> flow, patches, corner_flow;
  std::array<std::vector<double>, 4> side;  // xb, xa, yl, yr with channels
  // Image-sized changes, stride as the image: first and second order, corners.
  std::vector<double> first, second, corners;
};

}  // namespace

void ApplyBoundaryShift(const BoundaryShiftParams& params, const BoundaryDensities& densities,
                        const PixelWindow& window, const EffectChannels& channels,
                        DualImage* image) {
  const DualImage& density_x = densities.x;
  const DualImage& density_y = densities.y;
  const DualImage& density_corner = densities.corner;
  CHECK_EQ(density_x.nx, image->nx + 1);
  CHECK_EQ(density_x.ny, image->ny);
  CHECK_EQ(density_y.nx, image->nx);
  CHECK_EQ(density_y.ny, image->ny + 1);
  CHECK_EQ(density_corner.nx, image->nx + 1);
  CHECK_EQ(density_corner.ny, image->ny + 1);
  CHECK(window.i0 >= 0 && window.i1 < image->nx && window.j0 >= 0 && window.j1 < image->ny &&
        window.i0 <= window.i1 && window.j0 <= window.j1);
  const int s = image->stride(), nx = image->nx;
  CHECK_EQ(density_x.stride(), s);
  CHECK_EQ(density_y.stride(), s);
  CHECK_EQ(density_corner.stride(), s);
  const int wx = window.i1 - window.i0 + 1, wy = window.j1 - window.j0 + 1;
  const int num_window = wx * wy;
  // The parameters with a channel, and their kernels' derivatives: the shifts are linear in
  // the a's at fixed eta, and in eta at fixed a's.
  std::array<int, kNumBoundaryShiftParams> active_channel{};
  std::vector<int> active;
  active.reserve(kNumBoundaryShiftParams);
  for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
    const int c = channels.Get(EffectKind::kBoundaryShift, p);
    if (c < 0) continue;
    CHECK(c >= 1 && c < s) << "boundary_shift parameter " << p << " channel " << c;
    active_channel[active.size()] = c;
    active.push_back(p);
  }
  const int num_active = static_cast<int>(active.size());
  thread_local ShiftWorkspace ws;
  if (ws.window.i0 != window.i0 || ws.window.i1 != window.i1 || ws.window.j0 != window.j0 ||
      ws.window.j1 != window.j1 || ws.nx != nx || ws.ny != image->ny) {
    for (int axis = 0; axis < 2; ++axis) {
      ws.boundaries[axis] = ListBoundaries(axis, window, nx, image->ny);
    }
    ws.window = window;
    ws.nx = nx;
    ws.ny = image->ny;
  }
  const std::array<AxisBoundaries, 2>& boundaries = ws.boundaries;
  const ShiftMatrices& matrices = CachedShiftMatrices(params, active, wx, wy, boundaries, window);
  const std::array<RowMatrix, 2>& shift_of_charge = matrices.shift_of_charge;
  const std::vector<InterleavedKernels>& parameter_kernels = matrices.parameter_kernels;
  // S(Q) with its channels: the line densities are the incident light's, fixed.
  RowMatrix& charge_window = ws.charge_window;
  charge_window.resize(num_window, s);
  std::array<RowMatrix, 2>& shift = ws.shift;
  for (int axis = 0; axis < 2; ++axis) shift[axis].resize(boundaries[axis].num, s);
  std::vector<double>& values = ws.values;
  values.resize(num_window);
  std::array<std::vector<double>, 2>& parameter_shift = ws.parameter_shift;
  for (int axis = 0; axis < 2; ++axis) {
    parameter_shift[axis].assign(static_cast<size_t>(kLanes) * boundaries[axis].num, 0.0);
  }
  ws.flow.resize(s);
  ws.patches.resize(s);
  ws.corner_flow.resize(s);
  double* f = ws.flow.data();
  // The shifts of every boundary of both axes by the charge `charge` (an image-sized array
  // with the image's stride; all channels; the parameters' own channels in parameter_shift,
  // for the values only).
  auto shifts_of = [&](const double* charge) {
    for (int l = window.j0; l <= window.j1; ++l) {
      std::copy_n(charge + (static_cast<size_t>(l) * nx + window.i0) * s,
                  static_cast<size_t>(wx) * s,
                  charge_window.data() + static_cast<size_t>(l - window.j0) * wx * s);
    }
    for (int axis = 0; axis < 2; ++axis) {
      shift[axis].noalias() = shift_of_charge[axis] * charge_window;
    }
    if (num_active > 0) {
      for (int w = 0; w < num_window; ++w) values[w] = charge_window(w, 0);
      for (int axis = 0; axis < 2; ++axis) {
        ShiftsOfParameters(parameter_kernels[axis], boundaries[axis], window, values.data(),
                           parameter_shift[axis].data());
      }
    }
  };
  // Boundary r of `axis`'s shift with every channel (the parameters' own added), into out.
  auto full_shift = [&](int axis, int r, double* out) {
    const double* sh = shift[axis].row(r).data();
    std::copy(sh, sh + s, out);
    for (int a = 0; a < num_active; ++a) {
      out[active_channel[a]] += parameter_shift[axis][static_cast<size_t>(r) * kLanes + a];
    }
  };
  // The charge moved across the boundaries at the shifts of the last shifts_of (first order),
  // into `change` (image-sized, the image's stride).
  auto moves = [&](std::vector<double>* change) {
    change->assign(image->data.size(), 0.0);
    for (int axis = 0; axis < 2; ++axis) {
      const AxisBoundaries& bd = boundaries[axis];
      const DualImage& density = axis == 0 ? density_x : density_y;
      for (int r = 0; r < bd.num; ++r) {
        const double* L = density.data.data() + bd.density_at[r] * s;
        const double* sh = shift[axis].row(r).data();
        f[0] = sh[0] * L[0];
        for (int c = 1; c < s; ++c) f[c] = sh[0] * L[c] + sh[c] * L[0];
        for (int a = 0; a < num_active; ++a) {
          f[active_channel[a]] +=
              parameter_shift[axis][static_cast<size_t>(r) * kLanes + a] * L[0];
        }
        // The pixel below the boundary gains the flow, the one above loses it.
        if (bd.lower_pixel[r] >= 0) {
          double* out = change->data() + static_cast<size_t>(bd.lower_pixel[r]) * s;
          for (int c = 0; c < s; ++c) out[c] += f[c];
        }
        if (bd.upper_pixel[r] >= 0) {
          double* out = change->data() + static_cast<size_t>(bd.upper_pixel[r]) * s;
          for (int c = 0; c < s; ++c) out[c] -= f[c];
        }
      }
    }
  };
  // dQ/dt = M + S(Q(t)), Q(0) = 0, over the exposure t in [0, 1]: Q(1) = M + S M / 2 + S^2 M / 6
  // + ..., the exponential series of the linear S, kept to second order (the third is below
  // 1e-3 of the effect at a 2e5 e- peak).
  shifts_of(image->data.data());
  moves(&ws.first);
  // The corners (second order in the shifts, at the shifts of M). Each side of a pixel moves
  // rigidly, so where two sides of one pixel both move into it, the patch beyond both (area
  // the product of their shifts) belongs to neither edge neighbour, to which the first order
  // gives it (and takes it from the pixel twice), but to the diagonal one. At the corner
  // between pixels LL = (c - 1, d - 1), LR = (c, d - 1), UL = (c - 1, d), UR = (c, d), with
  // the x boundaries below (xb, LL|LR) and above (xa, UL|UR) it and the y boundaries left (yl,
  // LL|UL) and right (yr, LR|UR), every such patch corrects the four pixels by
  // (+P, -P, -P, +P) x rho(corner): P is the sum of the signed products xb yl (if both < 0:
  // LL's patch), xa yr (both > 0: UR's), xb yr (xb > 0 > yr: LR's), xa yl (xa < 0 < yl: UL's).
  // The area grows as the square of the charge collected, so over the exposure it averages a
  // third of its final value. The corners on the window's edge are left out.
  std::vector<double>& corners = ws.corners;
  corners.assign(image->data.size(), 0.0);
  std::array<std::vector<double>, 4>& side = ws.side;
  for (std::vector<double>& one : side) one.resize(s);
  std::vector<double>& patches = ws.patches;
  std::vector<double>& corner_flow = ws.corner_flow;
  const int row0 = wx + 1, col0 = wy + 1;  // boundaries per row (axis 0) and column (axis 1)
  for (int d = window.j0 + 1; d <= window.j1; ++d) {
    for (int c = window.i0 + 1; c <= window.i1; ++c) {
      // Axis 0: row l, boundary b at r = (l - j0) (wx + 1) + (b - i0); axis 1: column m,
      // boundary b at r = (m - i0) (wy + 1) + (b - j0).
      full_shift(0, (d - 1 - window.j0) * row0 + (c - window.i0), side[0].data());
      full_shift(0, (d - window.j0) * row0 + (c - window.i0), side[1].data());
      full_shift(1, (c - 1 - window.i0) * col0 + (d - window.j0), side[2].data());
      full_shift(1, (c - window.i0) * col0 + (d - window.j0), side[3].data());
      const double xb = side[0][0], xa = side[1][0], yl = side[2][0], yr = side[3][0];
      // P with its channels: the products of the pairs of sides that both move into one pixel.
      std::fill(patches.begin(), patches.end(), 0.0);
      auto add_patch = [&](const std::vector<double>& px, const std::vector<double>& py) {
        patches[0] += px[0] * py[0];
        for (int k = 1; k < s; ++k) patches[k] += px[k] * py[0] + px[0] * py[k];
      };
      if (xb < 0 && yl < 0) add_patch(side[0], side[2]);
      if (xa > 0 && yr > 0) add_patch(side[1], side[3]);
      if (xb > 0 && yr < 0) add_patch(side[0], side[3]);
      if (xa < 0 && yl > 0) add_patch(side[1], side[2]);
      if (patches[0] == 0.0) continue;
      const double* rho =
          density_corner.data.data() + (static_cast<size_t>(d) * (nx + 1) + c) * s;
      corner_flow[0] = patches[0] * rho[0] / 3.0;
      for (int k = 1; k < s; ++k) {
        corner_flow[k] = (patches[k] * rho[0] + patches[0] * rho[k]) / 3.0;
      }
      const int ll = (d - 1) * nx + (c - 1);
      const std::array<std::pair<int, double>, 4> to = {
          std::pair<int, double>{ll, 1.0}, {ll + 1, -1.0}, {ll + nx, -1.0}, {ll + nx + 1, 1.0}};
      for (const auto& [pixel, sign] : to) {
        double* out = corners.data() + static_cast<size_t>(pixel) * s;
        for (int k = 0; k < s; ++k) out[k] += sign * corner_flow[k];
      }
    }
  }
  shifts_of(ws.first.data());
  moves(&ws.second);
  for (size_t e = 0; e < image->data.size(); ++e) {
    image->data[e] += ws.first[e] / 2.0 + ws.second[e] / 6.0 + corners[e];
  }
}

}  // namespace ccdpsf::model
