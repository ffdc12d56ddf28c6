// The pixel_centre compatibility mode against the authors' 2015 model, as computed by numpy
// and scipy (tools/make_pixel_centre_reference.py -> testdata/pixel_centre_reference.json; see
// testdata/README.md).
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "ccdpsf/model/renderer.h"
#include "ccdpsf/model/spot_model.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::model {
namespace {

// Tolerance, relative to the stamp's largest value. Both computations evaluate the same
// closed-form expression; they differ only by rounding. Every term of both convolutions is
// non-negative, so each output carries a relative rounding error below (terms summed) x eps
// ~ 441 x 1.1e-16 ~ 5e-14 per convolution. Our a(v) = 2 J1(v) / v comes from the quintic
// table of model/airy.h (error ~1e-12 at worst, usually far less) where scipy calls Cephes'
// J1, and the normalisation amp = m / profile(c, c) amplifies profile errors by at most
// 1 / 0.017 in these cases (the fixture generator asserts profile(c, c) > 1e-3). 1e-10 is
// about that worst case and still five orders below what any
// difference in the model itself (normalising pixel, kernel orientation, 'same' offset for
// even n, Gaussian centring) changes the stamp by 1e-3 of its maximum or much more.
constexpr double kRelativeTolerance = 1e-10;

nlohmann::json LoadFixture() {
  const std::string path = std::string(CCDPSF_TESTDATA) + "/pixel_centre_reference.json";
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << "cannot open " << path;
  if (!in.good()) return nlohmann::json();
  return nlohmann::json::parse(in);
}

TEST(PixelCentreSampling, ReproducesThe2015PythonCode) {
  const nlohmann::json fixture = LoadFixture();
  ASSERT_TRUE(fixture.contains("cases"));
  const nlohmann::json& cases = fixture["cases"];
  ASSERT_GE(cases.size(), 6u);

  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  options.defocus = DefocusKind::kGaussian;
  SpotRenderer renderer(options);

  double worst_of_all = 0.0;
  for (const nlohmann::json& c : cases) {
    const std::string name = c.at("name").get<std::string>();
    const int n = c.at("n").get<int>();
    SpotParams params;
    params[kFlux] = c.at("m").get<double>();
    params[kCentreX] = c.at("x").get<double>();
    params[kCentreY] = c.at("y").get<double>();
    params[kAiryRadius] = c.at("r").get<double>();
    params[kDefocus] = c.at("sigma_f").get<double>();
    params[kCcdSigmaX] = c.at("sigma_x").get<double>();
    params[kCcdSigmaY] = c.at("sigma_y").get<double>();
    const nlohmann::json& expected = c.at("model");
    ASSERT_EQ(expected.size(), static_cast<size_t>(n)) << name;

    PixelGrid grid;
    grid.nx = n;
    grid.ny = n;
    grid.x0 = 0.0;
    grid.y0 = 0.0;
    std::vector<double> model(grid.size());
    renderer.Render(params, grid, model.data(), nullptr);

    double max_expected = 0.0;
    for (const auto& row : expected) {
      for (const auto& v : row) max_expected = std::max(max_expected, v.get<double>());
    }
    ASSERT_GT(max_expected, 0.0) << name;
    double worst = 0.0;
    int worst_x = -1, worst_y = -1;
    for (int y = 0; y < n; ++y) {
      ASSERT_EQ(expected[y].size(), static_cast<size_t>(n)) << name;
      for (int x = 0; x < n; ++x) {
        const double error = std::abs(model[y * n + x] - expected[y][x].get<double>());
        if (!(error <= worst)) {  // also catches NaN
          worst = error;
          worst_x = x;
          worst_y = y;
        }
      }
    }
    EXPECT_LE(worst / max_expected, kRelativeTolerance)
        << name << ": worst pixel (" << worst_x << ", " << worst_y << ") renderer "
        << model[worst_y * n + worst_x] << " vs python "
        << expected[worst_y][worst_x].get<double>() << " (stamp max " << max_expected << ")";
    worst_of_all = std::max(worst_of_all, worst / max_expected);
  }
  // The measured agreement goes to the XML report (--gtest_output=xml), not the console.
  std::ostringstream text;
  text << std::scientific << worst_of_all;
  RecordProperty("max_error_of_max", text.str());
}

// Rendering with and without a Jacobian gives the same pixels: a renderer taking a different
// path when derivatives are requested would make fits disagree with simulations. (The
// Jacobian itself is checked in renderer_test.cc.)
TEST(PixelCentreSampling, ValuesDoNotDependOnJacobianRequest) {
  const nlohmann::json fixture = LoadFixture();
  ASSERT_TRUE(fixture.contains("cases"));
  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  SpotRenderer renderer(options);
  const nlohmann::json& c = fixture["cases"][0];
  SpotParams params = {c.at("m").get<double>(),       c.at("x").get<double>(),
                       c.at("y").get<double>(),       c.at("r").get<double>(),
                       c.at("sigma_f").get<double>(), c.at("sigma_x").get<double>(),
                       c.at("sigma_y").get<double>()};
  PixelGrid grid;
  grid.nx = grid.ny = c.at("n").get<int>();
  std::vector<double> plain(grid.size()), with(grid.size());
  std::vector<double> jacobian(grid.size() * kNumSpotParams);
  renderer.Render(params, grid, plain.data(), nullptr);
  renderer.Render(params, grid, with.data(), jacobian.data());
  for (int p = 0; p < grid.size(); ++p) {
    EXPECT_NEAR(with[p], plain[p], 1e-13 * std::abs(plain[p])) << "pixel " << p;
  }
}

// The 2015 recipe written out directly (docs/conventions.md, Sampling), with the two extensions of
// pixel_centre_renderer.cc: F centred at (x + dx, y + dy), and sigma_f = 0 meaning no F
// step. Full 2-D 'same' convolutions (not the renderer's separable 1-D passes) and J1 from
// the standard library (std::cyl_bessel_j, not the renderer's table): independent code.
std::vector<double> Direct2015(const SpotParams& p, double dx, double dy, int n) {
  const int c = static_cast<int>(n / 2.0 - 0.5);
  const double scale = p[kAiryRadius] / kAiryRz;
  auto profile = [&](double X, double Y) {
    const double q = std::hypot(X - p[kCentreX], Y - p[kCentreY]) / scale;
    if (q == 0.0) return 1.0;
    const double v = M_PI * q;
    const double a = 2.0 * std::cyl_bessel_j(1.0, v) / v;
    return a * a;
  };
  const double amp = p[kFlux] / profile(c, c);
  std::vector<double> airy(n * n), f(n * n), g(n * n);
  for (int Y = 0; Y < n; ++Y) {
    for (int X = 0; X < n; ++X) {
      airy[Y * n + X] = amp * profile(X, Y);
      const double fx = X - p[kCentreX] - dx, fy = Y - p[kCentreY] - dy;
      f[Y * n + X] = std::exp(-(fx * fx + fy * fy) / (2 * p[kDefocus] * p[kDefocus]));
      const double gx = X - n / 2.0 + 0.5, gy = Y - n / 2.0 + 0.5;
      g[Y * n + X] = std::exp(-gx * gx / (2 * p[kCcdSigmaX] * p[kCcdSigmaX]) -
                              gy * gy / (2 * p[kCcdSigmaY] * p[kCcdSigmaY]));
    }
  }
  // scipy's convolve2d(a, k) in 'same' mode: out[i][j] = sum a[l][m] k[i + c - l][j + c - m].
  auto same = [&](const std::vector<double>& a, const std::vector<double>& k) {
    std::vector<double> out(n * n, 0.0);
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        for (int l = 0; l < n; ++l) {
          for (int m = 0; m < n; ++m) {
            const int ki = i + c - l, kj = j + c - m;
            if (ki < 0 || ki >= n || kj < 0 || kj >= n) continue;
            out[i * n + j] += a[l * n + m] * k[ki * n + kj];
          }
        }
      }
    }
    return out;
  };
  return same(p[kDefocus] == 0.0 ? airy : same(airy, f), g);
}

// The defocus offset and the "no defocus step" extensions against the direct recipe, within
// the tolerance of ReproducesThe2015PythonCode (the same argument: rounding of sums of
// non-negative terms, and the table's a(v) against the library's J1). A zero offset is
// bit-identical to Render (the 2015 output is untouched), and an offset is not a shift of
// the whole spot (the Airy stays put), unlike in integrated sampling.
TEST(PixelCentreSampling, DefocusOffsetAndNoDefocusMatchTheDirectRecipe) {
  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  SpotRenderer renderer(options);
  PixelGrid grid;
  grid.nx = grid.ny = 15;
  const SpotParams p = {1.5e5, 7.07, 6.96, 0.47, 0.41, 0.291, 0.335};
  const auto max_of = [](const std::vector<double>& v) {
    return *std::max_element(v.begin(), v.end());
  };
  struct Case {
    double sigma_f, dx, dy;
  };
  for (const Case& c : {Case{0.41, 0.0, 0.0}, Case{0.41, 0.2, -0.15}, Case{0.6, -0.3, 0.25},
                        Case{0.0, 0.0, 0.0}}) {
    SpotParams q = p;
    q[kDefocus] = c.sigma_f;
    std::vector<double> model(grid.size());
    renderer.RenderWithDefocusOffset(q, c.dx, c.dy, grid, model.data(), nullptr);
    const std::vector<double> direct = Direct2015(q, c.dx, c.dy, grid.nx);
    double worst = 0.0;
    for (int k = 0; k < grid.size(); ++k) worst = std::max(worst, std::abs(model[k] - direct[k]));
    EXPECT_LE(worst / max_of(direct), kRelativeTolerance)
        << "sigma_f " << c.sigma_f << " offset " << c.dx << ", " << c.dy;
  }
  std::vector<double> plain(grid.size()), zero(grid.size()), moved(grid.size()),
      offset(grid.size());
  renderer.Render(p, grid, plain.data(), nullptr);
  renderer.RenderWithDefocusOffset(p, 0.0, 0.0, grid, zero.data(), nullptr);
  EXPECT_EQ(plain, zero);
  SpotParams shifted = p;
  shifted[kCentreX] += 0.2;
  renderer.Render(shifted, grid, moved.data(), nullptr);
  renderer.RenderWithDefocusOffset(p, 0.2, 0.0, grid, offset.data(), nullptr);
  double diff = 0.0;
  for (int k = 0; k < grid.size(); ++k) diff = std::max(diff, std::abs(moved[k] - offset[k]));
  EXPECT_GT(diff / max_of(moved), 1e-3);
}

// The Jacobian with a defocus offset against central differences of the values: step
// h = 1e-6 max(|p|, 1), truncation O(h^2) and rounding O(eps / h) both far below the 1e-6
// tolerance, taken relative to the largest derivative with respect to that parameter.
TEST(PixelCentreSampling, DefocusOffsetJacobianMatchesDifferences) {
  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  SpotRenderer renderer(options);
  PixelGrid grid;
  grid.nx = grid.ny = 11;
  const SpotParams p = {1.5e5, 5.07, 4.96, 0.47, 0.41, 0.291, 0.335};
  const double dx = 0.15, dy = -0.1;
  std::vector<double> model(grid.size()), jacobian(grid.size() * kNumSpotParams);
  renderer.RenderWithDefocusOffset(p, dx, dy, grid, model.data(), jacobian.data());
  for (int k = 0; k < kNumSpotParams; ++k) {
    const double h = 1e-6 * std::max(std::abs(p[k]), 1.0);
    SpotParams a = p, b = p;
    a[k] += h;
    b[k] -= h;
    std::vector<double> ma(grid.size()), mb(grid.size());
    renderer.RenderWithDefocusOffset(a, dx, dy, grid, ma.data(), nullptr);
    renderer.RenderWithDefocusOffset(b, dx, dy, grid, mb.data(), nullptr);
    double scale = 0.0, worst = 0.0;
    for (int q = 0; q < grid.size(); ++q) {
      const double numeric = (ma[q] - mb[q]) / (2 * h);
      scale = std::max(scale, std::abs(numeric));
      worst = std::max(worst, std::abs(numeric - jacobian[q * kNumSpotParams + k]));
    }
    EXPECT_LE(worst, 1e-6 * scale) << "parameter " << k;
  }
}

// The derivatives with respect to the offset itself (F's centre alone in pixel_centre, the
// whole spot in integrated sampling), against central differences in dx and dy (step 1e-6 px;
// truncation ~h^2 x third derivative, far below 1e-6 of the largest derivative), and the
// spot parameters' columns unchanged by asking for them.
TEST(PixelCentreSampling, DefocusOffsetDerivativesMatchDifferences) {
  for (const Sampling sampling : {Sampling::kPixelCentre, Sampling::kIntegrated}) {
    ModelOptions options;
    options.sampling = sampling;
    SpotRenderer renderer(options);
    PixelGrid grid;
    grid.nx = grid.ny = 11;
    const SpotParams p = {1.5e5, 5.07, 4.96, 0.47, 0.41, 0.291, 0.335};
    const double dx = 0.15, dy = -0.1;
    const int n = grid.size();
    std::vector<double> model(n), jacobian(n * kNumSpotParams), offset(2 * n);
    std::vector<double> model0(n), jacobian0(n * kNumSpotParams);
    renderer.RenderWithDefocusOffset(p, dx, dy, grid, model.data(), jacobian.data(), offset.data());
    renderer.RenderWithDefocusOffset(p, dx, dy, grid, model0.data(), jacobian0.data());
    EXPECT_EQ(model, model0) << ToString(sampling);
    EXPECT_EQ(jacobian, jacobian0) << ToString(sampling);
    for (int axis = 0; axis < 2; ++axis) {
      const double h = 1e-6;
      std::vector<double> ma(n), mb(n);
      renderer.RenderWithDefocusOffset(p, dx + (axis == 0 ? h : 0), dy + (axis == 1 ? h : 0), grid,
                                       ma.data(), nullptr);
      renderer.RenderWithDefocusOffset(p, dx - (axis == 0 ? h : 0), dy - (axis == 1 ? h : 0), grid,
                                       mb.data(), nullptr);
      double scale = 0.0, worst = 0.0;
      for (int q = 0; q < n; ++q) {
        const double numeric = (ma[q] - mb[q]) / (2 * h);
        scale = std::max(scale, std::abs(numeric));
        worst = std::max(worst, std::abs(numeric - offset[2 * q + axis]));
      }
      EXPECT_GT(scale, 0.0);
      EXPECT_LE(worst, 1e-6 * scale) << ToString(sampling) << " axis " << axis;
    }
  }
}

}  // namespace
}  // namespace ccdpsf::model
