// Properties of SpotRenderer that hold whatever its quadrature: exact derivatives, linearity
// in the flux, translation invariance and the x <-> y symmetry. Accuracy against an
// independent reference is in renderer_accuracy_test.cc, the pixel_centre mode against the
// 2015 Python code in pixel_centre_test.cc.
#include "ccdpsf/model/renderer.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "ccdpsf/model/spot_model.h"
#include "ceres/cost_function.h"
#include "ceres/gradient_checker.h"
#include "ceres/manifold.h"
#include "ceres/numeric_diff_options.h"
#include "gtest/gtest.h"

namespace ccdpsf::model {
namespace {

ModelOptions Options(Sampling sampling, DefocusKind defocus) {
  ModelOptions options;
  options.sampling = sampling;
  options.defocus = defocus;
  return options;
}

std::string Describe(const ModelOptions& options, const SpotParams& p) {
  std::ostringstream out;
  out.precision(17);
  out << ToString(options.sampling) << "/" << ToString(options.defocus) << " flux=" << p[kFlux]
      << " x=" << p[kCentreX] << " y=" << p[kCentreY] << " r=" << p[kAiryRadius]
      << " defocus=" << p[kDefocus] << " sx=" << p[kCcdSigmaX] << " sy=" << p[kCcdSigmaY];
  return out.str();
}

PixelGrid Grid(int nx, int ny, double x0 = 0.0, double y0 = 0.0) {
  PixelGrid grid;
  grid.nx = nx;
  grid.ny = ny;
  grid.x0 = x0;
  grid.y0 = y0;
  return grid;
}

// The renderer as a Ceres cost function: residuals are the model pixels, one parameter block
// holds the 7 SpotParams. Parameters outside the model's domain make Evaluate return false
// (as a fit's cost function should) instead of reaching the renderer's CHECK.
class RendererCostFunction : public ceres::CostFunction {
 public:
  RendererCostFunction(const ModelOptions& options, const PixelGrid& grid)
      : renderer_(options), grid_(grid) {
    set_num_residuals(grid.size());
    mutable_parameter_block_sizes()->push_back(kNumSpotParams);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    SpotParams params;
    std::copy(parameters[0], parameters[0] + kNumSpotParams, params.begin());
    std::string error;
    if (!ValidSpotParams(renderer_.options(), params, &error)) return false;
    renderer_.Render(params, grid_, residuals,
                     jacobians != nullptr ? jacobians[0] : nullptr);
    return true;
  }

 private:
  SpotRenderer renderer_;
  PixelGrid grid_;
};

// Jacobian check against Ridders' extrapolated central differences (what GradientChecker
// uses). Steps: Ridders starts at 32 x max(h, h |p|) and halves up to ten times. The default
// h = 1e-2 would step r = 0.3 or sigma = 0.15 out of the domain, and even h = 1e-3 (first
// step 0.17 px on a centre) is too coarse for pixel_centre sampling, whose unit-peak
// Gaussian sampled 5 px from its centre with sigma_f = 0.25 px changes by e^13 over such a
// step, so Ridders' tableau stalls at ~1e-3 error. h = 1e-4 (first steps 3.2e-3 px on
// widths, ~0.02 px on centres) resolves every mode.
//
// Two bounds are checked on the same probe:
//  - GradientChecker's element-wise relative error, 1e-5. Ridders' absolute error is
//    <= ~1e-10 of a column's largest entry (measured), so an element's relative error is
//    that divided by how small the element is compared with its column; elements pass
//    through zero between pixels (a derivative changes sign across the spot), and the
//    smallest here is 2.5e-5 of its column's maximum (measured worst element-wise error
//    4.5e-7, pillbox, d/d sigma_y). Entries that are exactly zero by symmetry are avoided
//    by placing the spot off the pixel centres with sigma_x != sigma_y, on small stamps
//    (11 x 11, 12 x 12) where every pixel carries signal.
//  - |J - J_numeric| <= 1e-6 x (largest |J| in the column), insensitive to zero crossings.
//    The integrated model is an adaptive quadrature whose error (<= relative_tolerance =
//    1e-10 of the flux) need not be smooth in the parameters; over Ridders' first steps
//    (~3e-3 px) that is ~3e-8 of the flux per px, and the columns' largest entries are
//    >= 0.1 flux per px (flux column: 1 / flux x peak) -- so ~1e-6 is what the quadrature
//    guarantees; the measured error is <= 1.2e-10.
// A wrong derivative (a missing chain-rule term, a sign, a swapped column) is off by order
// one on many elements and fails both.
constexpr double kJacobianRelativePrecision = 1e-5;
constexpr double kJacobianColumnPrecision = 1e-6;

struct JacobianErrors {
  double element_relative = 0.0;  // GradientChecker's maximum relative error
  double column_relative = 0.0;   // max |J - J_numeric| / max |J column|
};

JacobianErrors CheckJacobian(const ModelOptions& options, const SpotParams& params,
                             const PixelGrid& grid) {
  RendererCostFunction cost(options, grid);
  ceres::NumericDiffOptions numeric_options;
  numeric_options.ridders_relative_initial_step_size = 1e-4;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(&cost, no_manifolds, numeric_options);
  // The probe's results are allocated inside Debian's libceres, which is built for generic
  // x86-64; this project builds for x86-64-v3 (CCDPSF_NATIVE). Destroying a ProbeResults
  // here crashed in free() even with Eigen's alignment pinned to 16 bytes (the cause is in
  // the ABI between the two builds, not in this code). One ProbeResults is therefore kept
  // for the whole run and never destroyed; Probe() clears and refills it from inside
  // libceres, and this file only reads it.
  static ceres::GradientChecker::ProbeResults* const probe_results =
      new ceres::GradientChecker::ProbeResults;
  ceres::GradientChecker::ProbeResults& results = *probe_results;
  SpotParams p = params;
  const double* blocks[] = {p.data()};
  const bool ok = checker.Probe(blocks, kJacobianRelativePrecision, &results);
  EXPECT_TRUE(ok) << Describe(options, params) << "\n" << results.error_log;
  JacobianErrors errors;
  errors.element_relative = results.maximum_relative_error;
  if (results.jacobians.empty() || results.numeric_jacobians.empty()) {
    ADD_FAILURE() << "no Jacobians from the probe: " << Describe(options, params);
    return errors;
  }
  const auto& analytic = results.jacobians[0];
  const auto& numeric = results.numeric_jacobians[0];
  for (int k = 0; k < kNumSpotParams; ++k) {
    const double scale = analytic.col(k).cwiseAbs().maxCoeff();
    EXPECT_GT(scale, 0.0) << Describe(options, params) << " parameter " << k;
    const double error = (analytic.col(k) - numeric.col(k)).cwiseAbs().maxCoeff() / scale;
    EXPECT_LE(error, kJacobianColumnPrecision)
        << Describe(options, params) << " parameter " << k;
    errors.column_relative = std::max(errors.column_relative, error);
  }
  return errors;
}

struct JacobianCase {
  SpotParams params;
  PixelGrid grid;
};

// Checks every case and records the worst errors in the XML report (--gtest_output=xml).
void CheckJacobians(const ModelOptions& options, const std::vector<JacobianCase>& cases) {
  JacobianErrors worst;
  for (const JacobianCase& c : cases) {
    const JacobianErrors errors = CheckJacobian(options, c.params, c.grid);
    worst.element_relative = std::max(worst.element_relative, errors.element_relative);
    worst.column_relative = std::max(worst.column_relative, errors.column_relative);
  }
  std::ostringstream element, column;
  element << std::scientific << worst.element_relative;
  column << std::scientific << worst.column_relative;
  ::testing::Test::RecordProperty("max_element_relative_error", element.str());
  ::testing::Test::RecordProperty("max_column_relative_error", column.str());
}

// ValidSpotParams accepts what the renderers can draw and names the first problem of what
// they cannot: each case below breaks one rule (values chosen by hand about the limits of
// spot_model.h: total Gaussian width and Airy radius >= 0.05 px for integrated sampling).
TEST(ValidSpotParams, AcceptsDrawableParametersAndNamesTheProblem) {
  ModelOptions integrated, pixel_centre, pillbox;
  pixel_centre.sampling = Sampling::kPixelCentre;
  pillbox.defocus = DefocusKind::kPillbox;
  const SpotParams good = {4.0e5, 10.0, 10.0, 0.47, 0.41, 0.29, 0.33};
  std::string error;
  for (const ModelOptions* o : {&integrated, &pixel_centre, &pillbox}) {
    EXPECT_TRUE(ValidSpotParams(*o, good, &error)) << error;
  }
  // A Gaussian defocus makes up for a CCD width of 0 in integrated sampling, not a pillbox.
  SpotParams no_ccd = good;
  no_ccd[kCcdSigmaX] = 0.0;
  EXPECT_TRUE(ValidSpotParams(integrated, no_ccd, &error)) << error;
  EXPECT_FALSE(ValidSpotParams(pillbox, no_ccd, &error));
  EXPECT_NE(error.find("total Gaussian width >= 0.05"), std::string::npos) << error;
  EXPECT_FALSE(ValidSpotParams(pixel_centre, no_ccd, &error));
  EXPECT_NE(error.find("pixel_centre sampling needs ccd sigmas > 0"), std::string::npos) << error;
  // The pixel-centre renderer draws radii below the quadrature's limit.
  SpotParams small_radius = good;
  small_radius[kAiryRadius] = 0.04;
  EXPECT_TRUE(ValidSpotParams(pixel_centre, small_radius, &error)) << error;
  EXPECT_FALSE(ValidSpotParams(integrated, small_radius, &error));
  EXPECT_NE(error.find("airy radius must be >= 0.05"), std::string::npos) << error;
  const std::pair<int, double> broken[] = {{kFlux, -1.0},    {kAiryRadius, 0.0},
                                           {kDefocus, -0.1}, {kCcdSigmaY, -0.1},
                                           {kCentreX, NAN},  {kFlux, INFINITY}};
  const char* expected[] = {"flux must be >= 0",         "airy radius must be > 0",
                            "defocus must be >= 0",      "ccd sigmas must be >= 0",
                            "parameter x is not finite", "parameter flux is not finite"};
  for (size_t i = 0; i < std::size(broken); ++i) {
    SpotParams p = good;
    p[broken[i].first] = broken[i].second;
    for (const ModelOptions* o : {&integrated, &pixel_centre, &pillbox}) {
      error.clear();
      EXPECT_FALSE(ValidSpotParams(*o, p, &error)) << expected[i];
      EXPECT_NE(error.find(expected[i]), std::string::npos) << error;
    }
  }
  ModelOptions narrow = integrated;
  narrow.pixel_response_width = 1.5;
  EXPECT_FALSE(ValidSpotParams(narrow, good, &error));
  EXPECT_NE(error.find("pixel response width must lie in (0, 1]"), std::string::npos) << error;
}

TEST(Renderer, JacobianMatchesNumericDerivativesIntegratedGaussian) {
  CheckJacobians(Options(Sampling::kIntegrated, DefocusKind::kGaussian),
                 {{{1.5e5, 5.07, 4.96, 0.47, 0.41, 0.291, 0.335}, Grid(11, 11)},
                  {{3.0e4, 5.31, 5.22, 0.33, 0.15, 0.18, 0.45}, Grid(11, 11)},
                  {{8.0e5, 104.62, 49.71, 0.85, 0.7, 0.6, 0.75}, Grid(11, 10, 100.0, 45.0)}});
}

TEST(Renderer, JacobianMatchesNumericDerivativesIntegratedPillbox) {
  CheckJacobians(Options(Sampling::kIntegrated, DefocusKind::kPillbox),
                 {{{1.0e5, 5.12, 4.81, 0.6, 0.9, 0.3, 0.25}, Grid(11, 11)},
                  {{2.0e5, 5.4, 5.3, 0.35, 0.3, 0.15, 0.22}, Grid(11, 11)},
                  {{5.0e4, 4.77, 5.08, 0.8, 1.4, 0.55, 0.7}, Grid(11, 11)}});
}

// Stamp centre pixel c = int(n / 2 - 0.5): 5 for n = 11 and for n = 12 (even). The model is
// normalised by the Airy profile at (c, c), so the spot is kept where that profile is far
// from its first zero (q = 1.22): near a zero, amp = m / profile(c, c) varies so fast that
// Ridders' first steps straddle the pole and the numeric derivative, not the renderer, is
// wrong.
TEST(Renderer, JacobianMatchesNumericDerivativesPixelCentre) {
  CheckJacobians(Options(Sampling::kPixelCentre, DefocusKind::kGaussian),
                 {{{1.5e5, 5.07, 4.96, 0.47, 0.41, 0.291, 0.335}, Grid(11, 11)},
                  {{4.0e4, 5.21, 5.4, 0.72, 0.25, 0.5, 0.2}, Grid(12, 12)}});
}

// The model is linear in the flux: scaling it scales every pixel and every derivative except
// d/dflux, which is model / flux. Exact up to rounding (1e-13 relative),
// since the flux is only a multiplier; a renderer whose quadrature refinement depended on
// the flux in absolute terms would show differences of its tolerance (1e-10) here.
TEST(Renderer, ModelIsLinearInTheFlux) {
  const ModelOptions all[] = {Options(Sampling::kIntegrated, DefocusKind::kGaussian),
                              Options(Sampling::kIntegrated, DefocusKind::kPillbox),
                              Options(Sampling::kPixelCentre, DefocusKind::kGaussian)};
  const PixelGrid grid = Grid(13, 12);
  for (const ModelOptions& options : all) {
    SpotRenderer renderer(options);
    SpotParams p1 = {2.0e4, 6.13, 5.71, 0.52, 0.45, 0.31, 0.27};
    SpotParams p2 = p1;
    const double factor = 7.25;
    p2[kFlux] *= factor;
    std::vector<double> m1(grid.size()), m2(grid.size());
    std::vector<double> j1(grid.size() * kNumSpotParams), j2(grid.size() * kNumSpotParams);
    renderer.Render(p1, grid, m1.data(), j1.data());
    renderer.Render(p2, grid, m2.data(), j2.data());
    for (int p = 0; p < grid.size(); ++p) {
      ASSERT_GT(m1[p], 0.0) << Describe(options, p1) << " pixel " << p;
      EXPECT_NEAR(m2[p], factor * m1[p], 1e-13 * factor * m1[p])
          << Describe(options, p1) << " pixel " << p;
      EXPECT_NEAR(j1[p * kNumSpotParams + kFlux], m1[p] / p1[kFlux], 1e-13 * m1[p] / p1[kFlux])
          << Describe(options, p1) << " pixel " << p;
      for (int k = 1; k < kNumSpotParams; ++k) {
        const double a = j1[p * kNumSpotParams + k];
        EXPECT_NEAR(j2[p * kNumSpotParams + k], factor * a, 1e-13 * std::abs(factor * a))
            << Describe(options, p1) << " pixel " << p << " parameter " << k;
      }
    }
  }
}

// A renderer reuses the radially symmetric image of its last render when the Airy radius and
// the widths are the same (the exposures of a joint fit): a sequence of renders on one
// renderer (other centres, grids, with and without the Jacobian, a changed radius and back)
// must give exactly, bit for bit, what a new renderer gives for each.
TEST(Renderer, ReusedWorkspaceGivesTheValuesOfAFreshRenderer) {
  struct Step {
    SpotParams p;
    PixelGrid grid;
    bool jacobian;
  };
  const SpotParams a = {2.0e4, 6.13, 5.71, 0.52, 0.45, 0.31, 0.27};
  SpotParams shifted = a, moved = a, other_radius = a, pillbox_disc = a;
  shifted[kCentreX] += 0.37;  // same stamp, another centre: the same S
  shifted[kCentreY] -= 0.21;
  moved[kCentreX] += 3.6;  // a stamp further on: more node columns
  moved[kCentreY] += 2.2;
  other_radius[kAiryRadius] = 0.53;  // the same node spacings, another S
  pillbox_disc[kDefocus] = 0.7;
  const std::vector<Step> steps = {{a, Grid(13, 12), false},
                                   {shifted, Grid(13, 12), true},
                                   {a, Grid(13, 12), true},
                                   {shifted, Grid(13, 12), false},
                                   {moved, Grid(15, 14, 1.0, -1.0), false},
                                   {shifted, Grid(11, 10), false},
                                   {other_radius, Grid(13, 12), false},
                                   {a, Grid(13, 12), true},
                                   {pillbox_disc, Grid(13, 12), true},
                                   {a, Grid(13, 12), false}};
  for (DefocusKind kind : {DefocusKind::kGaussian, DefocusKind::kPillbox}) {
    const ModelOptions options = Options(Sampling::kIntegrated, kind);
    SpotRenderer reused(options);
    for (size_t i = 0; i < steps.size(); ++i) {
      const Step& step = steps[i];
      const int n = step.grid.size();
      std::vector<double> m1(n), m2(n), j1(n * kNumSpotParams), j2(n * kNumSpotParams);
      reused.Render(step.p, step.grid, m1.data(), step.jacobian ? j1.data() : nullptr);
      SpotRenderer fresh(options);
      fresh.Render(step.p, step.grid, m2.data(), step.jacobian ? j2.data() : nullptr);
      for (int q = 0; q < n; ++q) {
        ASSERT_EQ(m1[q], m2[q]) << Describe(options, step.p) << " step " << i << " pixel " << q;
      }
      if (step.jacobian) {
        for (size_t q = 0; q < j1.size(); ++q) {
          ASSERT_EQ(j1[q], j2[q]) << Describe(options, step.p) << " step " << i << " entry " << q;
        }
      }
    }
  }
}

// Moving the spot by exactly one pixel moves the integrated image by one pixel: the model
// depends only on pixel centre - spot centre. Compared away from the stamp edges (two
// pixels), to 2 x relative_tolerance x flux: each render is within relative_tolerance x flux
// of the exact values. Also moving the spot and the grid together changes nothing.
TEST(Renderer, IntegratedImageShiftsWithTheCentre) {
  for (DefocusKind kind : {DefocusKind::kGaussian, DefocusKind::kPillbox}) {
    const ModelOptions options = Options(Sampling::kIntegrated, kind);
    SpotRenderer renderer(options);
    const PixelGrid grid = Grid(15, 14);
    const SpotParams base = {1.0e5, 6.37, 6.82, 0.44, 0.5, 0.22, 0.36};
    const double tolerance = 2.0 * options.relative_tolerance * base[kFlux];
    std::vector<double> m0(grid.size());
    renderer.Render(base, grid, m0.data(), nullptr);
    for (int axis : {kCentreX, kCentreY}) {
      SpotParams moved = base;
      moved[axis] += 1.0;
      std::vector<double> m1(grid.size());
      renderer.Render(moved, grid, m1.data(), nullptr);
      const int di = axis == kCentreX ? 1 : 0;
      const int dj = axis == kCentreY ? 1 : 0;
      for (int j = 2; j + dj < grid.ny - 2; ++j) {
        for (int i = 2; i + di < grid.nx - 2; ++i) {
          EXPECT_NEAR(m1[(j + dj) * grid.nx + i + di], m0[j * grid.nx + i], tolerance)
              << Describe(options, base) << " axis " << axis << " pixel " << i << "," << j;
        }
      }
    }
    // Spot and grid moved together by (3, -2) px.
    SpotParams moved = base;
    moved[kCentreX] += 3.0;
    moved[kCentreY] -= 2.0;
    std::vector<double> m2(grid.size());
    renderer.Render(moved, Grid(grid.nx, grid.ny, 3.0, -2.0), m2.data(), nullptr);
    for (int p = 0; p < grid.size(); ++p) {
      EXPECT_NEAR(m2[p], m0[p], tolerance) << Describe(options, base) << " pixel " << p;
    }
  }
}

// Swapping x and y (centre coordinates and CCD sigmas) transposes the image and swaps the
// corresponding Jacobian columns, in every mode (pixel_centre included: its stamp-centred
// kernels are symmetric on a square stamp). Values to 2 x relative_tolerance x flux for the
// integrated mode and 1e-12 of the maximum (rounding) for pixel_centre; derivatives to 1e-8
// of each column's largest entry.
TEST(Renderer, SwappingXAndYTransposesTheImage) {
  const ModelOptions all[] = {Options(Sampling::kIntegrated, DefocusKind::kGaussian),
                              Options(Sampling::kIntegrated, DefocusKind::kPillbox),
                              Options(Sampling::kPixelCentre, DefocusKind::kGaussian)};
  const int n = 13;
  const PixelGrid grid = Grid(n, n);
  for (const ModelOptions& options : all) {
    SpotRenderer renderer(options);
    const SpotParams p1 = {5.0e4, 6.21, 5.64, 0.58, 0.33, 0.17, 0.52};
    SpotParams p2 = p1;
    std::swap(p2[kCentreX], p2[kCentreY]);
    std::swap(p2[kCcdSigmaX], p2[kCcdSigmaY]);
    std::vector<double> m1(grid.size()), m2(grid.size());
    std::vector<double> j1(grid.size() * kNumSpotParams), j2(grid.size() * kNumSpotParams);
    renderer.Render(p1, grid, m1.data(), j1.data());
    renderer.Render(p2, grid, m2.data(), j2.data());
    const double max_value = *std::max_element(m1.begin(), m1.end());
    const double tolerance = options.sampling == Sampling::kIntegrated
                                 ? 2.0 * options.relative_tolerance * p1[kFlux]
                                 : 1e-12 * max_value;
    // Column k of the swapped render corresponds to column swapped[k] of the original.
    int swapped[kNumSpotParams];
    for (int k = 0; k < kNumSpotParams; ++k) swapped[k] = k;
    std::swap(swapped[kCentreX], swapped[kCentreY]);
    std::swap(swapped[kCcdSigmaX], swapped[kCcdSigmaY]);
    double column_max[kNumSpotParams] = {};
    for (int p = 0; p < grid.size(); ++p) {
      for (int k = 0; k < kNumSpotParams; ++k) {
        column_max[k] = std::max(column_max[k], std::abs(j1[p * kNumSpotParams + k]));
      }
    }
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const int a = j * n + i;  // pixel (i, j) of the original
        const int b = i * n + j;  // pixel (j, i) of the swapped render
        EXPECT_NEAR(m2[b], m1[a], tolerance)
            << Describe(options, p1) << " pixel " << i << "," << j;
        for (int k = 0; k < kNumSpotParams; ++k) {
          EXPECT_NEAR(j2[b * kNumSpotParams + k], j1[a * kNumSpotParams + swapped[k]],
                      1e-8 * column_max[swapped[k]])
              << Describe(options, p1) << " pixel " << i << "," << j << " parameter " << k;
        }
      }
    }
  }
}

}  // namespace
}  // namespace ccdpsf::model
