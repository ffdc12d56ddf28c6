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

}  // namespace
}  // namespace ccdpsf::model
