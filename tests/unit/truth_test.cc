#include "ccdpsf/truth.h"

#include <cmath>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "support/fits_fixtures.h"

namespace ccdpsf {
namespace {

using nlohmann::json;
using test_support::ScopedTempDir;

// A truth.json as `ccdpsf simulate` writes it (simulate.cc), three exposures.
json SimulateTruth() {
  json t;
  t["parameters"] = {{"airy_radius_px", 0.47},
                     {"defocus_sigma_px", 0.41},
                     {"ccd_sigma_x_px", 0.291},
                     {"ccd_sigma_y_px", 0.335}};
  t["exposures"] = json::array();
  const double xs[] = {32.07, 31.98, 32.02}, ys[] = {23.96, 24.05, 23.91};
  const double fluxes[] = {4.26e5, 4.26e5, 8.52e5};
  for (int k = 0; k < 3; ++k) {
    t["exposures"].push_back({{"file", "exposure_00" + std::to_string(k) + ".fits"},
                              {"x_px", xs[k]},
                              {"y_px", ys[k]},
                              {"flux_e", fluxes[k]}});
  }
  return t;
}

TEST(Truth, MapsSharedParametersPositionsAndFluxByName) {
  const json t = SimulateTruth();
  // The fit saw exposures 2 and 0 (in that order), from some folder.
  const std::vector<std::string> names = {
      "flux_e", "airy_radius_px", "defocus_sigma_px", "ccd_sigma_x_px", "ccd_sigma_y_px", "x_px_0",
      "y_px_0", "x_px_1",         "y_px_1",           "flux_ratio_1",   "best_focus_um"};
  const std::vector<std::string> sources = {"/data/set/exposure_002.fits",
                                            "/data/set/exposure_000.fits"};
  const std::vector<double> v = FitParameterTruths(t, names, sources, /*flux_shared=*/false);
  ASSERT_EQ(v.size(), names.size());
  EXPECT_EQ(v[0], 8.52e5);  // fit exposure 0 is the truth's exposure 2
  EXPECT_EQ(v[1], 0.47);
  EXPECT_EQ(v[2], 0.41);
  EXPECT_EQ(v[3], 0.291);
  EXPECT_EQ(v[4], 0.335);
  EXPECT_EQ(v[5], 32.02);
  EXPECT_EQ(v[6], 23.91);
  EXPECT_EQ(v[7], 32.07);
  EXPECT_EQ(v[8], 23.96);
  EXPECT_DOUBLE_EQ(v[9], 4.26e5 / 8.52e5);
  EXPECT_TRUE(std::isnan(v[10]));  // not in this truth
  // A shared flux over exposures of different true flux has no single true value.
  EXPECT_TRUE(std::isnan(FitParameterTruths(t, names, sources, true)[0]));
  // Over exposures of one true flux it has.
  EXPECT_EQ(
      FitParameterTruths(t, {"flux_e"}, {"a/exposure_000.fits", "a/exposure_001.fits"}, true)[0],
      4.26e5);
}

TEST(Truth, InjectedEffectsWithholdTheKernelWidthsAndUnknownFilesMatchNothing) {
  json t = SimulateTruth();
  t["effects"] = {{"brighter_fatter", {{"coefficient", 1e-6}}}};
  const std::vector<double> v =
      FitParameterTruths(t, {"airy_radius_px", "ccd_sigma_x_px", "defocus_sigma_px", "x_px_0"},
                         {"elsewhere/other.fits"}, false);
  EXPECT_EQ(v[0], 0.47);
  EXPECT_TRUE(std::isnan(v[1]));
  EXPECT_TRUE(std::isnan(v[2]));
  EXPECT_TRUE(std::isnan(v[3]));
  // A campaign-level truth (no "parameters") maps nothing.
  json campaign = {{"groups", json::array()}, {"relations", json::object()}};
  for (double x : FitParameterTruths(campaign, {"airy_radius_px"}, {}, false)) {
    EXPECT_TRUE(std::isnan(x));
  }
}

TEST(Truth, FoundBesideAllInputsOrGivenAndNotGuessedAcrossFolders) {
  ScopedTempDir dir;
  std::ofstream(dir.File("truth.json")) << SimulateTruth().dump();
  std::ofstream(dir.File("exposure_000.fits")) << "x";
  std::optional<TruthFile> truth;
  std::string error;
  ASSERT_TRUE(FindTruth("", {dir.File("exposure_000.fits")}, &truth, &error)) << error;
  ASSERT_TRUE(truth.has_value());
  EXPECT_EQ(truth->document["parameters"]["airy_radius_px"], 0.47);
  ASSERT_TRUE(FindTruth("", {dir.path()}, &truth, &error)) << error;  // the folder itself
  EXPECT_TRUE(truth.has_value());
  // Inputs in two folders: no single truth.
  ASSERT_TRUE(FindTruth("", {dir.File("exposure_000.fits"), "/tmp"}, &truth, &error));
  EXPECT_FALSE(truth.has_value());
  // A given file that is missing or not JSON is an error with a one-line reason.
  EXPECT_FALSE(FindTruth(dir.File("missing.json"), {}, &truth, &error));
  EXPECT_NE(error.find("missing.json"), std::string::npos);
  std::ofstream(dir.File("bad.json")) << "[1, 2";
  EXPECT_FALSE(FindTruth(dir.File("bad.json"), {}, &truth, &error));
  EXPECT_EQ(error.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace ccdpsf
