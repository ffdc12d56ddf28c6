// The boundary-shift brighter-fatter effect (model/boundary_shift.h): the shifts against the
// coefficients they must reproduce, the renderer's boundary line densities against the
// independent Fourier reference, and the redistribution's conservation, direction and window.
#include "ccdpsf/model/boundary_shift.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/renderer.h"
#include "gtest/gtest.h"
#include "support/boundary_densities.h"
#include "support/reference_model.h"

namespace ccdpsf::model {
namespace {

// The paper's spot (Airy 0.47 px, Gaussian defocus 0.41 px, CCD 0.291 / 0.335 px) of `flux`
// electrons at (10.07, 9.96) on the 21 x 21 grid at the origin.
SpotParams PaperSpot(double flux) {
  SpotParams p;
  p[kFlux] = flux;
  p[kCentreX] = 10.07;
  p[kCentreY] = 9.96;
  p[kAiryRadius] = 0.47;
  p[kDefocus] = 0.41;
  p[kCcdSigmaX] = 0.291;
  p[kCcdSigmaY] = 0.335;
  return p;
}

// The outward moves of pixel (i, j)'s four sides, per electron in (0, 0), computed directly
// from the shift kernels: they must add up to a_ij. This checks the potential solved by the
// cosine transform with a plain finite divergence, for every lag whose four sides are inside
// the kernels' reach, at 1e-12 of |a_00|.
TEST(BoundaryShift, AreasOfTheShiftsAreTheCoefficients) {
  const BoundaryShiftParams p{2.1e-7, 3.3e-7, 7.0e-8, 2.0e-8};
  const BoundaryShiftKernel k = MakeBoundaryShiftKernel(p);
  const double a00 = BoundaryShiftCoefficient(p, 0, 0);
  EXPECT_LT(a00, 0.0);
  double sum = 0.0;
  for (int j = -kBoundaryShiftLagRange; j <= kBoundaryShiftLagRange; ++j) {
    for (int i = -kBoundaryShiftLagRange; i <= kBoundaryShiftLagRange; ++i) {
      sum += BoundaryShiftCoefficient(p, i, j);
    }
  }
  EXPECT_NEAR(sum, 0.0, 1e-15 * std::fabs(a00)) << "the sum rule";
  EXPECT_DOUBLE_EQ(BoundaryShiftCoefficient(p, 1, 0), p.a_10);
  EXPECT_DOUBLE_EQ(BoundaryShiftCoefficient(p, 0, -1), p.a_01);
  EXPECT_DOUBLE_EQ(BoundaryShiftCoefficient(p, -1, 1), p.a_11);
  EXPECT_DOUBLE_EQ(BoundaryShiftCoefficient(p, 2, 0), p.a_far);
  EXPECT_NEAR(BoundaryShiftCoefficient(p, 3, 4), p.a_far * std::pow(2.0 / 5.0, 4.0), 1e-22);
  EXPECT_EQ(BoundaryShiftCoefficient(p, 6, 0), 0.0);
  const int r = kBoundaryShiftReach - 1;
  for (int j = -r; j <= r; ++j) {
    for (int i = -r; i <= r; ++i) {
      const double area = k.Dx(i, j) - k.Dx(i - 1, j) + k.Dy(i, j) - k.Dy(i, j - 1);
      EXPECT_NEAR(area, BoundaryShiftCoefficient(p, i, j), 1e-12 * std::fabs(a00))
          << "lag (" << i << ", " << j << ")";
    }
  }
  // A charge pulls the boundaries of its own pixel inwards: the upper x boundary of (0, 0)
  // moves to -x, its lower one to +x; likewise along y.
  EXPECT_LT(k.Dx(0, 0), 0.0);
  EXPECT_GT(k.Dx(-1, 0), 0.0);
  EXPECT_LT(k.Dy(0, 0), 0.0);
  EXPECT_GT(k.Dy(0, -1), 0.0);
}

// kBoundaryShiftReach's promise: at the edge of the kernels every shift is below 2e-3 of the
// largest, for each parameter's own pattern (the shifts of a charge-neutral pattern fall as
// the cube of the distance).
// The anisotropy's pattern fades more slowly (its K1 is a quadrupole field of the whole
// coefficient pattern, ~1/r^2, where K0 of a nearly isotropic pattern is nearly local): for
// the catalogue's coefficients at the prior's largest |eta| = 0.6 the kernels' edge stays
// below 5e-3 of their nearest shift (and the 9 x 9 window of the redistribution puts the
// spot's bright charges well inside the reach of the boundaries that carry its light).
TEST(BoundaryShift, ShiftsFadeAtTheReach) {
  auto edge_over_largest = [](auto dx, auto dy) {
    double largest = 0.0, edge = 0.0;
    for (int j = -kBoundaryShiftReach; j <= kBoundaryShiftReach; ++j) {
      for (int i = -kBoundaryShiftReach; i <= kBoundaryShiftReach; ++i) {
        const double m = std::max(std::fabs(dx(i, j)), std::fabs(dy(i, j)));
        largest = std::max(largest, m);
        if (std::abs(i) == kBoundaryShiftReach || std::abs(j) == kBoundaryShiftReach) {
          edge = std::max(edge, m);
        }
      }
    }
    return edge / largest;
  };
  const BoundaryShiftBasis& basis = BoundaryShiftBasis::Get();
  for (int p = 0; p < kNumBoundaryShiftCoefficients; ++p) {
    EXPECT_LT(edge_over_largest([&](int i, int j) { return basis.Dx(p, i, j); },
                                [&](int i, int j) { return basis.Dy(p, i, j); }),
              2e-3)
        << "coefficient " << p;
  }
  for (const double eta : {-0.6, 0.6}) {
    BoundaryShiftParams params;
    params.anisotropy = eta;
    const BoundaryShiftKernel k = MakeBoundaryShiftKernel(params);
    EXPECT_LT(edge_over_largest([&](int i, int j) { return k.Dx(i, j); },
                                [&](int i, int j) { return k.Dy(i, j); }),
              5e-3)
        << "eta " << eta;
  }
}

// The anisotropy against the stiffness it stands for, solved independently: on a 64 x 64
// periodic lattice, conjugate gradients on (1 + eta) dxx K + (1 - eta) dyy K = a for the
// catalogue's coefficients, then Dx = (1 + eta) dx+ K, Dy = (1 - eta) dy+ K. The model keeps
// the first order in eta, so its error is second order: at eta = 0.05 below 0.01 of the
// largest shift (eta^2 = 0.0025 with room for the coefficient), and a quarter of that at
// eta = 0.025 (the ratio 4 +- 30 %, the third order and the two lattices' images, < 1e-4,
// making up the rest). And the pattern moves no area: the divergence of (Ex, Ey) is 0 to
// rounding at every lag.
TEST(BoundaryShift, AnisotropyIsTheStiffnessToFirstOrderAndMovesNoArea) {
  const BoundaryShiftParams base;
  constexpr int n = 64;
  auto wrap = [](int i) { return ((i % n) + n) % n; };
  std::vector<double> a(n * n, 0.0);
  for (int j = -kBoundaryShiftLagRange; j <= kBoundaryShiftLagRange; ++j) {
    for (int i = -kBoundaryShiftLagRange; i <= kBoundaryShiftLagRange; ++i) {
      a[wrap(j) * n + wrap(i)] = BoundaryShiftCoefficient(base, i, j) / base.a_10;  // O(1)
    }
  }
  auto solve = [&](double eta) {
    auto apply = [&](const std::vector<double>& k, std::vector<double>* out) {
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const double c = k[j * n + i];
          (*out)[j * n + i] =
              (1 + eta) * (k[j * n + wrap(i + 1)] + k[j * n + wrap(i - 1)] - 2 * c) +
              (1 - eta) * (k[wrap(j + 1) * n + i] + k[wrap(j - 1) * n + i] - 2 * c);
        }
      }
    };
    // The operator is negative semi-definite with the constants as its null space, and a
    // sums to 0: CG on -A from K = 0 stays orthogonal to the constants.
    std::vector<double> k(n * n, 0.0), r(n * n), p(n * n), ap(n * n);
    for (int e = 0; e < n * n; ++e) r[e] = -a[e];
    p = r;
    double rr = 0.0;
    for (double v : r) rr += v * v;
    for (int it = 0; it < 5000 && rr > 1e-30; ++it) {
      apply(p, &ap);
      double pap = 0.0;
      for (int e = 0; e < n * n; ++e) pap -= p[e] * ap[e];
      const double alpha = rr / pap;
      double next = 0.0;
      for (int e = 0; e < n * n; ++e) {
        k[e] += alpha * p[e];
        r[e] += alpha * ap[e];
        next += r[e] * r[e];
      }
      for (int e = 0; e < n * n; ++e) p[e] = r[e] + (next / rr) * p[e];
      rr = next;
    }
    EXPECT_LT(rr, 1e-24);
    return k;
  };
  auto worst_error = [&](double eta) {
    const std::vector<double> k = solve(eta);
    BoundaryShiftParams p = base;
    p.anisotropy = eta;
    const BoundaryShiftKernel model = MakeBoundaryShiftKernel(p);
    double worst = 0.0, largest = 0.0;
    for (int j = -kBoundaryShiftReach; j <= kBoundaryShiftReach; ++j) {
      for (int i = -kBoundaryShiftReach; i <= kBoundaryShiftReach; ++i) {
        const double dx = (1 + eta) * (k[wrap(j) * n + wrap(i + 1)] - k[wrap(j) * n + wrap(i)]);
        const double dy = (1 - eta) * (k[wrap(j + 1) * n + wrap(i)] - k[wrap(j) * n + wrap(i)]);
        worst = std::max({worst, std::fabs(model.Dx(i, j) / base.a_10 - dx),
                          std::fabs(model.Dy(i, j) / base.a_10 - dy)});
        largest = std::max({largest, std::fabs(dx), std::fabs(dy)});
      }
    }
    return worst / largest;
  };
  const double at_5 = worst_error(0.05), at_2_5 = worst_error(0.025);
  EXPECT_LT(at_5, 0.01);
  EXPECT_NEAR(at_5 / at_2_5, 4.0, 1.2) << at_5 << " " << at_2_5;
  const BoundaryShiftBasis& basis = BoundaryShiftBasis::Get();
  for (int p = 0; p < kNumBoundaryShiftCoefficients; ++p) {
    double largest = 0.0, worst = 0.0;
    for (int j = -kBoundaryShiftReach + 1; j <= kBoundaryShiftReach; ++j) {
      for (int i = -kBoundaryShiftReach + 1; i <= kBoundaryShiftReach; ++i) {
        const double div = basis.Ex(p, i, j) - basis.Ex(p, i - 1, j) + basis.Ey(p, i, j) -
                           basis.Ey(p, i, j - 1);
        worst = std::max(worst, std::fabs(div));
        largest = std::max({largest, std::fabs(basis.Ex(p, i, j)), std::fabs(basis.Ey(p, i, j))});
      }
    }
    EXPECT_LT(worst, 1e-12 * largest) << "coefficient " << p;
    EXPECT_GT(largest, 0.0);
  }
}

// RenderBoundaryDensity against the Fourier reference's line integral along the same
// boundaries (reference_model.h, line_x / line_y: the pixel box replaced by a line), on the
// grid grown by one pixel below as the effect uses it; 1e-9 of the flux is the reference's
// tolerance (1e-12) with the renderer's (1e-10) to spare. Then the Jacobian against central
// differences of the density itself.
TEST(BoundaryShift, BoundaryDensityIsTheLineIntegral) {
  ModelOptions options;
  const SpotRenderer renderer(options);
  const SpotParams p = PaperSpot(1.0);
  const testing_reference::ReferenceSpot ref =
      testing_reference::FromSpotParams(p, DefocusKind::kGaussian);
  for (int axis = 0; axis < 2; ++axis) {
    const PixelGrid grid{9, 9, 6.0 - (axis == 0 ? 1.0 : 0.0), 6.0 - (axis == 1 ? 1.0 : 0.0)};
    std::vector<double> density(grid.size()), jacobian(grid.size() * kNumSpotParams);
    renderer.RenderBoundaryDensity(p, grid, axis, density.data(), jacobian.data());
    testing_reference::ReferenceSpot line = ref;
    line.line_x = axis == 0;
    line.line_y = axis == 1;
    // The boundaries sit half a pixel above each pixel centre on their axis.
    const auto want =
        testing_reference::ReferenceImage(line, grid.nx, grid.ny, grid.x0 + (axis == 0 ? 0.5 : 0.0),
                                          grid.y0 + (axis == 1 ? 0.5 : 0.0));
    ASSERT_TRUE(want.converged);
    double worst = 0.0, largest = 0.0;
    for (int q = 0; q < grid.size(); ++q) {
      worst = std::max(worst, std::fabs(density[q] - want.values[q]));
      largest = std::max(largest, want.values[q]);
    }
    EXPECT_LT(worst, 1e-9) << "axis " << axis;
    EXPECT_GT(largest, 0.2) << "axis " << axis;  // the core's boundaries carry the light
    for (int k = 0; k < kNumSpotParams; ++k) {
      const double h = 1e-6 * std::max(1.0, std::fabs(p[k]));
      SpotParams up = p, down = p;
      up[k] += h;
      down[k] -= h;
      std::vector<double> a(grid.size()), b(grid.size());
      renderer.RenderBoundaryDensity(up, grid, axis, a.data(), nullptr);
      renderer.RenderBoundaryDensity(down, grid, axis, b.data(), nullptr);
      double err = 0.0, col = 0.0;
      for (int q = 0; q < grid.size(); ++q) {
        const double numeric = (a[q] - b[q]) / (2.0 * h);
        col = std::max(col, std::fabs(numeric));
        err = std::max(err, std::fabs(numeric - jacobian[q * kNumSpotParams + k]));
      }
      EXPECT_LT(err, 1e-6 * col) << "axis " << axis << ", parameter " << k;
    }
  }
}

// RenderWithDensities (one render, first passes shared) against the four separate renders it
// replaces, on a 9 x 9 window of the 21 x 21 stamp away from its corner, with and without
// Jacobians, for both defocus models. The passes are the same sums over the same nodes, only
// the weights' abscissae are formed from another grid origin (rounding of 1e-16 px), so
// 1e-12 of each output's largest value bounds the difference with a wide margin.
TEST(BoundaryShift, SharedRenderIsTheSeparateRenders) {
  for (const DefocusKind defocus : {DefocusKind::kGaussian, DefocusKind::kPillbox}) {
    ModelOptions options;
    options.defocus = defocus;
    const SpotRenderer shared(options), separate(options);
    const SpotParams p = PaperSpot(2.0e5);
    const PixelGrid grid;  // 21 x 21 at the origin
    const int i0 = 6, j0 = 5, w = 9;
    const PixelGrid part[3] = {{w + 1, w, grid.x0 - 1.0 + i0, grid.y0 + j0},
                               {w, w + 1, grid.x0 + i0, grid.y0 - 1.0 + j0},
                               {w + 1, w + 1, grid.x0 - 1.0 + i0, grid.y0 - 1.0 + j0}};
    for (const bool with_jacobian : {false, true}) {
      const size_t np = with_jacobian ? kNumSpotParams : 0;
      std::vector<double> image(grid.size()), image_j(grid.size() * np);
      std::vector<double> values[3], jacobians[3];
      SpotRenderer::DensityImage densities[3];
      for (int kind = 0; kind < 3; ++kind) {
        values[kind].resize(part[kind].size());
        jacobians[kind].resize(part[kind].size() * np);
        densities[kind] = {part[kind], values[kind].data(),
                           with_jacobian ? jacobians[kind].data() : nullptr};
      }
      shared.RenderWithDensities(p, grid, image.data(), with_jacobian ? image_j.data() : nullptr,
                                 densities[0], densities[1], densities[2]);
      auto compare = [&](const std::vector<double>& got, const std::vector<double>& want,
                         const char* what) {
        ASSERT_EQ(got.size(), want.size());
        double largest = 0.0, worst = 0.0;
        for (size_t q = 0; q < want.size(); ++q) {
          largest = std::max(largest, std::fabs(want[q]));
          worst = std::max(worst, std::fabs(got[q] - want[q]));
        }
        EXPECT_GT(largest, 0.0) << what;
        EXPECT_LE(worst, 1e-12 * largest)
            << what << ", defocus " << static_cast<int>(defocus) << ", jacobian " << with_jacobian;
      };
      std::vector<double> want(grid.size()), want_j(grid.size() * np);
      separate.Render(p, grid, want.data(), with_jacobian ? want_j.data() : nullptr);
      compare(image, want, "image");
      if (with_jacobian) compare(image_j, want_j, "image jacobian");
      for (int kind = 0; kind < 3; ++kind) {
        std::vector<double> v(part[kind].size()), j(part[kind].size() * np);
        double* jp = with_jacobian ? j.data() : nullptr;
        if (kind < 2) {
          separate.RenderBoundaryDensity(p, part[kind], kind, v.data(), jp);
        } else {
          separate.RenderCornerDensity(p, part[kind], v.data(), jp);
        }
        compare(values[kind], v, kind == 0 ? "x density" : kind == 1 ? "y density" : "corners");
        if (with_jacobian) compare(jacobians[kind], j, "density jacobian");
      }
    }
  }
}

// The spot drawn with and without the effect, on the 21 x 21 grid (the simulator's path,
// RenderSpotWithKernelEffects).
std::vector<double> Draw(const SpotParams& p, const ExposureEffects& effects) {
  const SpotRenderer renderer{ModelOptions()};
  const PixelGrid grid;
  std::vector<double> image(grid.size());
  RenderSpotWithKernelEffects(renderer, effects, p, grid, 0.0, image.data());
  return image;
}

// On a spot with 2e5 e- in its peak: no charge is made or lost (the window lies inside the
// stamp, so every boundary's flow stays on the image: to rounding, 1e-12 of the flux); the
// peak pixel loses; its four edge neighbours gain, and more than the diagonal ones (the
// shape the issue describes, not a wider Gaussian's). The model is the exposure's time series
// to second order, S M / 2 + S^2 M / 6 with S linear in the coefficients, so the change for
// lambda times the coefficients is lambda A + lambda^2 B: with lambda = 1, 2, 3 the changes
// obey f(3) - 3 f(1) = 3 (f(2) - 2 f(1)) (both 6 B), to rounding.
TEST(BoundaryShift, MovesChargeOutwardsAndConservesIt) {
  const SpotParams p = PaperSpot(5.5e5);
  const BoundaryShiftParams d;
  std::vector<std::vector<double>> m;  // lambda = 0, 1, 2, 3
  for (int lambda = 0; lambda <= 3; ++lambda) {
    ExposureEffects e;
    if (lambda > 0) {
      e.boundary_shift =
          BoundaryShiftParams{lambda * d.a_10, lambda * d.a_01, lambda * d.a_11, lambda * d.a_far};
    }
    m.push_back(Draw(p, e));
  }
  const std::vector<double>& m0 = m[0];
  const std::vector<double>& m1 = m[1];
  const int nx = 21, peak = static_cast<int>(std::max_element(m0.begin(), m0.end()) - m0.begin());
  EXPECT_GT(m0[peak], 1.9e5);
  double moved = 0.0, worst_quadratic = 0.0, change_peak = 0.0;
  for (size_t q = 0; q < m0.size(); ++q) {
    moved += m1[q] - m0[q];
    const double f1 = m1[q] - m0[q], f2 = m[2][q] - m0[q], f3 = m[3][q] - m0[q];
    worst_quadratic = std::max(worst_quadratic, std::fabs((f3 - 3.0 * f1) - 3.0 * (f2 - 2.0 * f1)));
    change_peak = std::max(change_peak, std::fabs(f1));
  }
  EXPECT_NEAR(moved, 0.0, 1e-12 * p[kFlux]);
  EXPECT_LT(worst_quadratic, 1e-12 * p[kFlux]);
  auto gain = [&](int di, int dj) {
    const int q = peak + dj * nx + di;
    return (m1[q] - m0[q]) / m0[q];  // fractional change
  };
  EXPECT_LT(gain(0, 0), -1e-3) << "the peak loses";
  for (auto [di, dj] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
    EXPECT_GT(gain(di, dj), 0.0) << di << ", " << dj;
    for (auto [ei, ej] : {std::pair{1, 1}, {1, -1}, {-1, 1}, {-1, -1}}) {
      EXPECT_GT(m1[peak + dj * nx + di] - m0[peak + dj * nx + di],
                m1[peak + ej * nx + ei] - m0[peak + ej * nx + ei]);
    }
  }
  EXPECT_GT(std::fabs(m1[peak] - m0[peak]), 0.99 * change_peak) << "the peak changes most";
}

// The window: the effect computed on the 9 x 9 pixels around the spot against the same on the
// whole 21 x 21 stamp differs by less than 1e-4 of the largest change (the promise of
// kBoundaryShiftWindowHalf), on the spot above.
TEST(BoundaryShift, WindowHoldsTheEffect) {
  const SpotParams p = PaperSpot(5.5e5);
  const SpotRenderer renderer{ModelOptions()};
  const PixelGrid grid;
  DualImage image{grid.nx, grid.ny, 0, std::vector<double>(grid.size())};
  renderer.Render(p, grid, image.data.data(), nullptr);
  const BoundaryDensities densities = testing_support::DrawBoundaryDensities(renderer, p, grid);
  const BoundaryShiftParams a;
  DualImage small = image, whole = image;
  ApplyBoundaryShift(a, densities, BoundaryShiftWindow(10, 10, grid.nx, grid.ny), EffectChannels(),
                     &small);
  ApplyBoundaryShift(a, densities, PixelWindow{0, grid.nx - 1, 0, grid.ny - 1}, EffectChannels(),
                     &whole);
  double largest = 0.0, worst = 0.0;
  for (int q = 0; q < grid.size(); ++q) {
    largest = std::max(largest, std::fabs(whole.data[q] - image.data[q]));
    worst = std::max(worst, std::fabs(whole.data[q] - small.data[q]));
  }
  EXPECT_GT(largest, 100.0);
  EXPECT_LT(worst, 1e-4 * largest) << worst / largest;
}

// The redistribution against the coefficients: charge q in one pixel and a line density of
// 1 e- / px along every boundary (an image so faint that it only probes the boundaries)
// change each other pixel by 1/2 x its area change, 1/2 q a_ij (the 1/2 from the shifts
// growing during the exposure). Coefficients a million times the realistic ones make the
// second-order term (S^2 M / 6, relative size ~ a q) a part in 1e8 of the first, below the
// 1e-7 tolerance, for every pixel within the kernels' reach. The same for the derivative channels
// of the a's, with unit coefficients; the charged pixel gives what its neighbours gain
// (conservation).
TEST(BoundaryShift, PointChargeMovesAreasByTheCoefficients) {
  const int n = 21, c = 10;
  const double q = 1.0e5;
  // The anisotropy moves no area: the same areas at any eta, and no derivative by it.
  const BoundaryShiftParams a{2.1e-13, 3.3e-13, 7.0e-14, 2.0e-14, -0.3};
  EffectChannels channels;
  for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
    channels.Set(EffectKind::kBoundaryShift, p, 1 + p);
  }
  const int s = 1 + kNumBoundaryShiftParams;
  DualImage image{n, n, kNumBoundaryShiftParams, std::vector<double>(n * n * s, 0.0)};
  image.data[(c * n + c) * s] = q;
  DualImage lx{n + 1, n, kNumBoundaryShiftParams, std::vector<double>((n + 1) * n * s, 0.0)};
  DualImage ly{n, n + 1, kNumBoundaryShiftParams, std::vector<double>(n * (n + 1) * s, 0.0)};
  for (size_t e = 0; e < lx.data.size(); e += s) lx.data[e] = 1.0;
  for (size_t e = 0; e < ly.data.size(); e += s) ly.data[e] = 1.0;
  // No light at the corners: their term (second order in the shifts) is left out here.
  DualImage corner{n + 1, n + 1, kNumBoundaryShiftParams,
                   std::vector<double>((n + 1) * (n + 1) * s, 0.0)};
  ApplyBoundaryShift(a, BoundaryDensities{lx, ly, corner}, PixelWindow{0, n - 1, 0, n - 1},
                     channels, &image);
  const double scale = 0.5 * q * std::fabs(BoundaryShiftCoefficient(a, 0, 0));
  double gained = 0.0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      if (i == c && j == c) continue;
      const double* pixel = &image.data[(j * n + i) * s];
      gained += pixel[0];
      // At the kernels' reach one side of the pixel moves and the other, beyond it, does not:
      // the truncation kBoundaryShiftReach bounds, 2e-3 of the nearest shift.
      const int reach = std::max(std::abs(i - c), std::abs(j - c));
      if (reach >= kBoundaryShiftReach) {
        EXPECT_LT(std::fabs(pixel[0]), 2e-3 * scale) << i - c << ", " << j - c;
        continue;
      }
      const bool lag =
          std::abs(i - c) <= kBoundaryShiftLagRange && std::abs(j - c) <= kBoundaryShiftLagRange;
      const double want = lag ? 0.5 * q * BoundaryShiftCoefficient(a, i - c, j - c) : 0.0;
      EXPECT_NEAR(pixel[0], want, 1e-7 * scale) << i - c << ", " << j - c;
      for (int p = 0; p < kNumBoundaryShiftParams; ++p) {
        const double want_p = lag ? 0.5 * q * BoundaryShiftBasisCoefficient(p, i - c, j - c) : 0.0;
        EXPECT_NEAR(pixel[1 + p], want_p, 1e-7 * scale / 1e-13)
            << "d/d parameter " << p << " at " << i - c << ", " << j - c;
      }
    }
  }
  EXPECT_NEAR(image.data[(c * n + c) * s] - q, -gained, 1e-15 * q);
  EXPECT_NEAR(image.data[(c * n + c) * s] - q, 0.5 * q * BoundaryShiftCoefficient(a, 0, 0),
              1e-7 * scale + 1e-15 * q);
}

}  // namespace
}  // namespace ccdpsf::model
