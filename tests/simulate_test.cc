#include "ccdpsf/simulate.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <chrono>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/model/renderer.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;

std::string PaperConfig(const std::string& extra_exposure = "") {
  return R"({"seed": 7,
    "image": {"nx": 15, "ny": 13},
    "detector": {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000.0,
                 "pixel_um": 12.0, "saturation_adu": 65535},
    "model": {"sampling": "integrated", "airy_radius_px": 0.47,
              "defocus": {"kind": "gaussian", "sigma_px": 0.41},
              "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335},
    "effects": {},
    "wavelength_nm": 800, "exptime_s": 2.5,
    "exposures": [{"flux_e": 3.0e5, "x_px": 7.07, "y_px": 5.96})" + extra_exposure + "]}";
}

SimulationConfig MustParse(const std::string& text) {
  std::string error;
  auto c = ParseSimulationConfig(text, &error);
  EXPECT_TRUE(c.has_value()) << error;
  return c.value_or(SimulationConfig());
}

std::string TempDir(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_simulate_" + name;
  fs::remove_all(dir);
  return dir;
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Steps 1-4 are the renderer on the image area: checked independently by the renderer
// tests; here we check the frame placement, prescan and units.
TEST(Simulate, ExpectedImageIsTheRendererOnTheImageArea) {
  SimulationConfig c = MustParse(PaperConfig());
  c.prescan_x = 4;
  c.exposures[0].x_px += 4;
  const Image frame = ExpectedElectrons(c, c.exposures[0]);
  ASSERT_EQ(frame.nx, 19);
  ASSERT_EQ(frame.ny, 13);
  model::SpotRenderer renderer(c.model);
  model::PixelGrid grid{15, 13, 4.0, 0.0};
  std::vector<double> m(grid.size());
  renderer.Render(c.Params(c.exposures[0]), grid, m.data(), nullptr);
  for (int y = 0; y < 13; ++y) {
    for (int x = 0; x < 4; ++x) EXPECT_EQ(frame(x, y), 0.0);
    for (int x = 0; x < 15; ++x) EXPECT_EQ(frame(x + 4, y), m[y * 15 + x]);
  }
}

// Steps 5-9: over many realisations, each pixel's mean and variance in ADU must match
// mean = B + m / g and var = m / g^2 + (RN / g)^2 + 1/12 (the last term is the rounding
// to whole ADU, exact for a uniform quantisation error when sigma >> 1 ADU: here sigma >=
// 1.45 ADU, where Sheppard's correction is accurate to exp(-2 pi^2 sigma^2) ~ 1e-18).
// Tolerances: 5 standard errors per pixel, SE(mean) = sqrt(var / n),
// SE(var) = var sqrt(2 / (n - 1)) (near-normal at these counts; the Poisson excess
// kurtosis 1/m is < 1e-2 wherever m is large enough to matter).
TEST(Simulate, NoiseStatisticsMatchTheNoiseModel) {
  SimulationConfig c = MustParse(PaperConfig());
  const Image expected = ExpectedElectrons(c, c.exposures[0]);
  const int n = 3000;
  std::vector<double> s1(expected.size(), 0.0), s2(expected.size(), 0.0);
  std::mt19937_64 engine(123);
  for (int r = 0; r < n; ++r) {
    const Image adu = ObserveAdu(c, expected, engine);
    for (size_t q = 0; q < adu.size(); ++q) {
      const double d = adu.data[q] - c.bias_adu;
      s1[q] += d;
      s2[q] += d * d;
    }
  }
  const double g = c.gain_e_per_adu;
  int checked = 0;
  for (size_t q = 0; q < expected.size(); ++q) {
    const double mean = s1[q] / n;
    const double var = (s2[q] - n * mean * mean) / (n - 1);
    const double want_mean = expected.data[q] / g;
    const double want_var =
        expected.data[q] / (g * g) + c.read_noise_e * c.read_noise_e / (g * g) + 1.0 / 12.0;
    EXPECT_NEAR(mean, want_mean, 5 * std::sqrt(want_var / n)) << "pixel " << q;
    EXPECT_NEAR(var, want_var, 5 * want_var * std::sqrt(2.0 / (n - 1))) << "pixel " << q;
    ++checked;
  }
  EXPECT_EQ(checked, 15 * 13);
}

TEST(Simulate, RoundsAndClipsToSixteenBits) {
  SimulationConfig c = MustParse(PaperConfig());
  // A saturating spot: the peak clips at 65535.
  c.exposures[0].flux_e = 5.0e6;
  const Image expected = ExpectedElectrons(c, c.exposures[0]);
  std::mt19937_64 engine(1);
  const Image adu = ObserveAdu(c, expected, engine);
  int at_max = 0;
  for (double v : adu.data) {
    EXPECT_EQ(v, std::nearbyint(v));
    EXPECT_LE(v, 65535.0);
    at_max += v == 65535.0;
  }
  EXPECT_GE(at_max, 1);
  // No light on a bias of 1 ADU with 1.45 ADU of read noise: about Phi(-0.5 / 1.45) = 37 %
  // of the 195 pixels would round below 0; they must clip to 0.
  SimulationConfig dark = c;
  dark.bias_adu = 1.0;
  const Image nothing(c.FrameNx(), c.ny, 0.0);
  std::mt19937_64 engine_dark(2);
  const Image low = ObserveAdu(dark, nothing, engine_dark);
  int at_zero = 0;
  for (double v : low.data) {
    EXPECT_GE(v, 0.0);
    EXPECT_EQ(v, std::nearbyint(v));
    at_zero += v == 0.0;
  }
  EXPECT_GE(at_zero, 40);  // expectation 72, sd 6.7
  // A saturation level below the ADC range clips there.
  c.saturation_adu = 40000.0;
  std::mt19937_64 engine2(1);
  const Image clipped = ObserveAdu(c, expected, engine2);
  for (double v : clipped.data) EXPECT_LE(v, 40000.0);
}

TEST(Simulate, SameSeedGivesIdenticalBytesAndOtherSeedsDiffer) {
  const SimulationConfig c = MustParse(PaperConfig(R"(, {"flux_e": 2e5, "x_px": 7.0, "y_px": 6.1})"));
  SimulationResult r1, r2, r3;
  std::string error;
  ASSERT_TRUE(RunSimulation(c, TempDir("a"), false, &r1, &error)) << error;
  // Runs a second apart: nothing time-dependent (dates, checksum comments) may enter.
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  ASSERT_TRUE(RunSimulation(c, TempDir("b"), false, &r2, &error)) << error;
  SimulationConfig other = c;
  other.seed = 8;
  ASSERT_TRUE(RunSimulation(other, TempDir("c"), false, &r3, &error)) << error;
  ASSERT_EQ(r1.files.size(), 2u);
  for (size_t k = 0; k < r1.files.size(); ++k) {
    // Compared as booleans so a failure does not print two FITS files.
    EXPECT_TRUE(ReadBytes(r1.files[k]) == ReadBytes(r2.files[k])) << r1.files[k];
    EXPECT_TRUE(ReadBytes(r1.files[k]) != ReadBytes(r3.files[k])) << r1.files[k];
  }
  EXPECT_TRUE(ReadBytes(r1.truth_path) == ReadBytes(r2.truth_path));
}

TEST(Simulate, WritesSixteenBitExposuresWithTheKeywords) {
  SimulationConfig c = MustParse(PaperConfig());
  c.prescan_x = 6;
  c.exposures[0].x_px += 6;
  c.exposures[0].focus_position_um = 125.0;
  SimulationResult r;
  std::string error;
  const std::string dir = TempDir("keywords");
  ASSERT_TRUE(RunSimulation(c, dir, false, &r, &error)) << error;
  auto image = ReadFitsImage(r.files[0], &error);
  ASSERT_TRUE(image.has_value()) << error;
  EXPECT_EQ(image->bitpix, 16);
  EXPECT_EQ(FindNumber(image->header, "BZERO").value_or(0), 0);  // structural: not kept
  EXPECT_EQ(image->pixels.nx, 21);
  EXPECT_EQ(image->pixels.ny, 13);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "GAIN").value(), 3.1);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "RDNOISE").value(), 4.5);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "BIASLVL").value(), 1000.0);
  EXPECT_EQ(FindString(image->header, "BIASSEC").value(), "[1:6,1:13]");
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "SATURATE").value(), 65535.0);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "WAVELEN").value(), 800.0);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "EXPTIME").value(), 2.5);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "PIXSIZE").value(), 12.0);
  EXPECT_DOUBLE_EQ(FindNumber(image->header, "FOCUSPOS").value(), 125.0);
  // Prescan columns hold bias + read noise only: mean within 5 SE of the bias.
  double sum = 0;
  for (int y = 0; y < 13; ++y) {
    for (int x = 0; x < 6; ++x) sum += image->pixels(x, y);
  }
  const double se = std::sqrt((4.5 / 3.1) * (4.5 / 3.1) + 1.0 / 12) / std::sqrt(78.0);
  EXPECT_NEAR(sum / 78.0, 1000.0, 5 * se);
  // truth.json describes the exposure.
  std::ifstream in(r.truth_path);
  const nlohmann::json truth = nlohmann::json::parse(in);
  EXPECT_EQ(truth["exposures"][0]["file"], "exposure_000.fits");
  EXPECT_DOUBLE_EQ(truth["exposures"][0]["flux_e"].get<double>(), 3.0e5);
  EXPECT_DOUBLE_EQ(truth["parameters"]["ccd_sigma_y_px"].get<double>(), 0.335);
}

TEST(Simulate, NoiselessWritesTheExpectedElectronsAsDoubles) {
  const SimulationConfig c = MustParse(PaperConfig());
  SimulationResult r;
  std::string error;
  ASSERT_TRUE(RunSimulation(c, TempDir("noiseless"), true, &r, &error)) << error;
  EXPECT_EQ(fs::path(r.files[0]).filename(), "model_000.fits");
  auto image = ReadFitsImage(r.files[0], &error);
  ASSERT_TRUE(image.has_value()) << error;
  EXPECT_EQ(image->bitpix, -64);
  const Image expected = ExpectedElectrons(c, c.exposures[0]);
  ASSERT_EQ(image->pixels.size(), expected.size());
  for (size_t q = 0; q < expected.size(); ++q) EXPECT_EQ(image->pixels.data[q], expected.data[q]);
}

TEST(Simulate, PixelCentreUsesPeakAndAStampAroundTheSpot) {
  std::string text = PaperConfig();
  text.replace(text.find("\"integrated\""), 12, "\"pixel_centre\"");
  text.replace(text.find("\"flux_e\""), 8, "\"peak_e\"");
  SimulationConfig c = MustParse(text);
  c.nx = c.ny = 31;
  c.stamp_size = 21;
  c.exposures[0].x_px = 12.2;
  c.exposures[0].y_px = 17.9;
  const Image frame = ExpectedElectrons(c, c.exposures[0]);
  // Stamp origin: nearest pixel (12, 18) minus centre index 10 = (2, 8); outside it, zero.
  model::SpotRenderer renderer(c.model);
  model::PixelGrid grid{21, 21, 0.0, 0.0};
  model::SpotParams p = c.Params(c.exposures[0]);
  p[model::kCentreX] -= 2;
  p[model::kCentreY] -= 8;
  std::vector<double> m(grid.size());
  renderer.Render(p, grid, m.data(), nullptr);
  for (int y = 0; y < 31; ++y) {
    for (int x = 0; x < 31; ++x) {
      const bool inside = x >= 2 && x < 23 && y >= 8 && y < 29;
      EXPECT_EQ(frame(x, y), inside ? m[(y - 8) * 21 + (x - 2)] : 0.0) << x << "," << y;
    }
  }
}

TEST(Simulate, ConfigErrorsNameTheProblem) {
  struct Case {
    std::string from, to, message;
  };
  const std::vector<Case> cases = {
      {"\"seed\": 7", "\"sed\": 7", "'seed' is required"},
      {"\"nx\": 15", "\"nx\": 15, \"bogus\": 1", "unknown key 'image.bogus'"},
      {"\"integrated\"", "\"exact\"", "'model.sampling' must be"},
      {"\"kind\": \"gaussian\"", "\"kind\": \"moffat\"", "'model.defocus.kind' must be"},
      {"\"gain_e_per_adu\": 3.1", "\"gain_e_per_adu\": -3.1", "gain"},
      {"\"x_px\": 7.07", "\"x_px\": 40.0", "outside the image area"},
      {"\"flux_e\": 3.0e5", "\"flux_e\": \"lots\"", "'exposures[0].flux_e' must be a finite"},
      {"\"effects\": {}", "\"effects\": {\"ipc\": {\"alpha\": 0.01}}", "effect 'ipc'"},
      {"\"airy_radius_px\": 0.47", "\"airy_radius_px\": 0.0", "airy radius"},
  };
  for (const Case& c : cases) {
    std::string text = PaperConfig();
    const size_t at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from;
    text.replace(at, c.from.size(), c.to);
    std::string error;
    EXPECT_FALSE(ParseSimulationConfig(text, &error).has_value()) << c.to;
    EXPECT_NE(error.find(c.message), std::string::npos) << "got: " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos);
  }
  std::string error;
  EXPECT_FALSE(ParseSimulationConfig("{not json", &error).has_value());
  EXPECT_NE(error.find("not valid JSON"), std::string::npos);
}

TEST(Simulate, FailureLeavesNothingBehind) {
  const SimulationConfig c = MustParse(PaperConfig());
  const std::string blocker = TempDir("blocker");
  { std::ofstream(blocker) << "a file where the folder should be"; }
  SimulationResult r;
  std::string error;
  EXPECT_FALSE(RunSimulation(c, blocker + "/sub", false, &r, &error));
  EXPECT_FALSE(error.empty());
  EXPECT_EQ(ReadBytes(blocker), "a file where the folder should be");
  // A successful run leaves no staging folder behind.
  const std::string dir = TempDir("clean");
  ASSERT_TRUE(RunSimulation(c, dir, false, &r, &error)) << error;
  for (const auto& entry : fs::directory_iterator(dir)) {
    EXPECT_EQ(entry.path().filename().string().find(".ccdpsf-staging"), std::string::npos);
  }
}

}  // namespace
}  // namespace ccdpsf
