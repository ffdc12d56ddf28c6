#include "ccdpsf/simulate.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <chrono>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/model/effects.h"
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
      {"\"effects\": {}", "\"effects\": {\"ipc\": {\"alpha\": 0.3}}",
       "'effects.ipc.alpha' must be in [0, 0.25) (got 0.3)"},
      {"\"effects\": {}", "\"effects\": {\"glow\": {}}", "unknown effect 'effects.glow'"},
      {"\"effects\": {}", "\"effects\": {\"halo\": {\"width\": 2}}",
       "unknown key 'effects.halo.width'"},
      {"\"effects\": {}", "\"effects\": {\"defocus\": {\"sigma_px\": 0.3}}",
       "'effects.defocus' cannot be injected"},
      {"\"effects\": {}", "\"effects\": {\"jitter\": {\"sigma_x_px\": [0.1, 0.2]}}",
       "'effects.jitter.sigma_x_px' must be a finite number or a list of 1"},
      {"\"effects\": {}", "\"effects\": []", "'effects' must be a JSON object"},
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

// ------------------------------------------------------------------------------------------
// Injected effects (model/effects.h; the effects themselves are tested in effects_test.cc).

std::string WithEffects(const std::string& effects, const std::string& extra_exposure = "") {
  std::string text = PaperConfig(extra_exposure);
  text.replace(text.find("\"effects\": {}"), 13, "\"effects\": " + effects);
  return text;
}

// "effects": {} is the same as no "effects" key: identical bytes, noisy and noiseless.
TEST(Simulate, EmptyEffectsGiveTheSameBytesAsNoEffectsKey) {
  std::string without = PaperConfig(R"(, {"flux_e": 2e5, "x_px": 7.0, "y_px": 6.1})");
  const std::string with = without;
  without.replace(without.find("\"effects\": {},"), 14, "");
  ASSERT_EQ(without.find("effects"), std::string::npos);
  for (const bool noiseless : {false, true}) {
    SimulationResult a, b;
    std::string error;
    const std::string tag = noiseless ? "n" : "o";
    ASSERT_TRUE(RunSimulation(MustParse(with), TempDir("fx_empty_" + tag), noiseless, &a, &error))
        << error;
    ASSERT_TRUE(
        RunSimulation(MustParse(without), TempDir("fx_none_" + tag), noiseless, &b, &error))
        << error;
    ASSERT_EQ(a.files.size(), 2u);
    for (size_t k = 0; k < a.files.size(); ++k) {
      EXPECT_TRUE(ReadBytes(a.files[k]) == ReadBytes(b.files[k])) << a.files[k];
    }
    EXPECT_TRUE(ReadBytes(a.truth_path) == ReadBytes(b.truth_path));
    std::ifstream in(a.truth_path);
    EXPECT_FALSE(nlohmann::json::parse(in).contains("effects"));
  }
}

// The expected image is the documented composition: kernel effects in the render, then halo,
// nonlinearity, ipc, serial and parallel CTI and the pedestal on the image area only (prescan
// columns stay empty). Built here from the individual effect functions, so it must agree to
// the last bit; in pixel_centre sampling the halo takes its share of the stamp's sum.
TEST(Simulate, ExpectedImageComposesTheEffectsInTheDocumentedOrder) {
  const std::string effects = R"({"brighter_fatter": {}, "jitter": {"sigma_x_px": 0.1},
      "halo": {"fraction": 0.04, "sigma_px": 2.0}, "nonlinearity": {"beta_per_e": 2e-7},
      "ipc": {"alpha": 0.02}, "serial_cti": {"trail_fraction": 1e-3},
      "parallel_cti": {"trail_fraction": 2e-3, "trail_length_px": 0.8},
      "background": {"pedestal_e": 15}})";
  for (const bool pixel_centre : {false, true}) {
    SCOPED_TRACE(pixel_centre ? "pixel_centre" : "integrated");
    std::string text = WithEffects(effects);
    if (pixel_centre) {
      text.replace(text.find("\"integrated\""), 12, "\"pixel_centre\"");
      text.replace(text.find("\"flux_e\": 3.0e5"), 15, "\"peak_e\": 1.5e5");
    }
    SimulationConfig c = MustParse(text);
    c.prescan_x = 3;
    c.exposures[0].x_px += 3;
    const SimulatedExposure& e = c.exposures[0];
    const Image frame = ExpectedElectrons(c, e);
    ASSERT_EQ(frame.nx, 18);

    // The spot, on the image area (integrated) or the 13 x 13 stamp around the spot.
    model::SpotRenderer renderer(c.model);
    model::SpotParams p = c.Params(e);
    model::PixelGrid grid{15, 13, 3.0, 0.0};
    int ox = 3, oy = 0;
    if (pixel_centre) {
      ox = static_cast<int>(std::lround(e.x_px)) - 6;
      oy = static_cast<int>(std::lround(e.y_px)) - 6;
      grid = model::PixelGrid{13, 13, 0.0, 0.0};
      p[model::kCentreX] -= ox;
      p[model::kCentreY] -= oy;
    }
    model::ExposureEffects fx;
    fx.jitter = model::JitterParams{0.1, 0.1, 0.0, 0.0};
    const double peak = model::BrighterFatterSignal(renderer, fx, p, grid);
    fx.brighter_fatter = model::BrighterFatterParams();
    std::vector<double> stamp(grid.size());
    model::RenderSpotWithKernelEffects(renderer, fx, p, grid, peak, stamp.data());
    double stamp_sum = 0.0;
    for (double v : stamp) stamp_sum += v;
    std::vector<double> area(15 * 13, 0.0);
    for (int j = 0; j < grid.ny; ++j) {
      for (int i = 0; i < grid.nx; ++i) {
        area[(oy + j) * 15 + (ox - 3 + i)] = stamp[j * grid.nx + i];
      }
    }
    const model::PixelGrid area_grid{15, 13, 3.0, 0.0};
    const model::SpotReference ref{pixel_centre ? stamp_sum : e.flux_e, e.x_px, e.y_px};
    model::AddHalo({0.04, 2.0}, area_grid, ref, area.data());
    model::ApplyNonlinearity({2e-7}, 15 * 13, area.data());
    model::ApplyIpc({0.02}, 15, 13, area.data());
    model::ApplySerialCti({1e-3, model::CtiParams().trail_length_px}, 15, 13, area.data());
    model::ApplyParallelCti({2e-3, 0.8}, 15, 13, area.data());
    for (double& v : area) v += 15.0;
    for (int y = 0; y < 13; ++y) {
      for (int x = 0; x < 3; ++x) EXPECT_EQ(frame(x, y), 0.0);
      for (int x = 0; x < 15; ++x) EXPECT_EQ(frame(x + 3, y), area[y * 15 + x]) << x << "," << y;
    }
  }
  // defocus_offset in pixel_centre sampling: the 2015 F kernel centred away from the Airy on
  // the stamp (SpotRenderer::RenderWithDefocusOffset), nothing else changed.
  std::string text = WithEffects(R"({"defocus_offset": {"dx_px": 0.2, "dy_px": -0.1}})");
  text.replace(text.find("\"integrated\""), 12, "\"pixel_centre\"");
  text.replace(text.find("\"flux_e\": 3.0e5"), 15, "\"peak_e\": 1.5e5");
  const SimulationConfig c = MustParse(text);
  const SimulatedExposure& e = c.exposures[0];
  model::KernelEffectDetails details;
  const Image frame = ExpectedElectrons(c, e, &details);
  model::SpotRenderer renderer(c.model);
  model::SpotParams p = c.Params(e);
  const int ox = static_cast<int>(std::lround(e.x_px)) - 6;
  const int oy = static_cast<int>(std::lround(e.y_px)) - 6;
  p[model::kCentreX] -= ox;
  p[model::kCentreY] -= oy;
  const model::PixelGrid grid{13, 13, 0.0, 0.0};
  std::vector<double> stamp(grid.size());
  renderer.RenderWithDefocusOffset(p, 0.2, -0.1, grid, stamp.data(), nullptr);
  for (int j = 0; j < 13; ++j) {
    for (int i = 0; i < 13; ++i) EXPECT_EQ(frame(ox + i, oy + j), stamp[j * 13 + i]) << i << "," << j;
  }
  EXPECT_DOUBLE_EQ(details.centre_x_px, e.x_px);  // the Airy stays where it was
  EXPECT_DOUBLE_EQ(details.defocus_centre_x_px, e.x_px + 0.2);
  EXPECT_DOUBLE_EQ(details.defocus_centre_y_px, e.y_px - 0.1);
}

// The pedestal shifts the mean of (ADU - bias) g by pedestal_e: over 15 x 13 pixels x 300
// realisations the mean of (ADU - B) g - m_photo is compared with the pedestal within 4
// standard errors, SE^2 = sum over values of (m_photo + RN^2 + g^2 / 12) / N^2 (shot noise,
// read noise and rounding). It carries no shot noise: on a dark frame with a 200 e- pedestal
// the variance in ADU stays RN^2 / g^2 + 1/12 (shot noise would add 200 / g^2 = 21 ADU^2),
// within 5 standard errors var sqrt(2 / (N - 1)). Prescan columns get no pedestal.
TEST(Simulate, BackgroundShiftsTheMeanByThePedestalWithoutShotNoise) {
  SimulationConfig c = MustParse(WithEffects(R"({"background": {"pedestal_e": 20}})"));
  const double g = c.gain_e_per_adu;
  SimulationConfig plain = c;
  plain.effects = model::ExposureEffects();
  const Image photo = ExpectedElectrons(plain, c.exposures[0]);
  const Image expected = ExpectedElectrons(c, c.exposures[0]);
  for (size_t q = 0; q < photo.size(); ++q) EXPECT_EQ(expected.data[q], photo.data[q] + 20.0);
  std::mt19937_64 engine(99);
  const int n = 300;
  double sum = 0.0, var_sum = 0.0;
  for (int r = 0; r < n; ++r) {
    const Image adu = ObserveAdu(c, expected, engine);
    for (size_t q = 0; q < adu.size(); ++q) {
      sum += (adu.data[q] - c.bias_adu) * g - photo.data[q];
      var_sum += photo.data[q] + c.read_noise_e * c.read_noise_e + g * g / 12.0;
    }
  }
  const double count = static_cast<double>(n) * photo.size();
  EXPECT_NEAR(sum / count, 20.0, 4.0 * std::sqrt(var_sum) / count);

  SimulationConfig dark = MustParse(WithEffects(R"({"background": {"pedestal_e": 200}})"));
  dark.exposures[0].flux_e = 0.0;
  dark.prescan_x = 3;
  dark.exposures[0].x_px += 3;
  const Image flat = ExpectedElectrons(dark, dark.exposures[0]);
  std::mt19937_64 engine2(7);
  double s1 = 0.0, s2 = 0.0, pre = 0.0;
  int values = 0, pre_values = 0;
  for (int r = 0; r < 100; ++r) {
    const Image adu = ObserveAdu(dark, flat, engine2);
    for (int y = 0; y < adu.ny; ++y) {
      for (int x = 0; x < adu.nx; ++x) {
        const double d = adu(x, y) - dark.bias_adu;
        if (x < 3) {
          pre += d;
          ++pre_values;
          continue;
        }
        s1 += d;
        s2 += d * d;
        ++values;
      }
    }
  }
  const double mean = s1 / values, var = (s2 - values * mean * mean) / (values - 1);
  const double want_var = (4.5 / g) * (4.5 / g) + 1.0 / 12.0;
  EXPECT_NEAR(mean, 200.0 / g, 4.0 * std::sqrt(want_var / values));
  EXPECT_NEAR(var, want_var, 5.0 * want_var * std::sqrt(2.0 / (values - 1)));
  EXPECT_NEAR(pre / pre_values, 0.0, 4.0 * std::sqrt(want_var / pre_values));
}

// truth.json records the effects with their resolved parameters and, per exposure, what they
// did; noiseless output is ExpectedElectrons; the same seed gives the same bytes.
TEST(Simulate, TruthRecordsTheInjectedEffects) {
  const std::string effects = R"({"brighter_fatter": {"slope_y_px_per_e": 3e-7},
      "jitter": {"sigma_x_px": [0.0, 0.2], "motion_length_px": [0.0, 0.5]},
      "halo": {}, "serial_cti": {"trail_fraction": 1e-3}})";
  const SimulationConfig c =
      MustParse(WithEffects(effects, R"(, {"flux_e": 1e5, "x_px": 7.3, "y_px": 6.2})"));
  ASSERT_TRUE(c.exposures[1].jitter.has_value());
  EXPECT_EQ(c.exposures[1].jitter->sigma_x_px, 0.2);
  EXPECT_EQ(c.exposures[1].jitter->sigma_y_px, 0.0);  // motion given: sigmas default to 0
  SimulationResult r, r2;
  std::string error;
  ASSERT_TRUE(RunSimulation(c, TempDir("fx_truth"), true, &r, &error)) << error;
  for (size_t k = 0; k < 2; ++k) {
    auto image = ReadFitsImage(r.files[k], &error);
    ASSERT_TRUE(image.has_value()) << error;
    EXPECT_TRUE(image->pixels.data == ExpectedElectrons(c, c.exposures[k]).data) << k;
  }
  std::ifstream in(r.truth_path);
  const nlohmann::json truth = nlohmann::json::parse(in);
  const nlohmann::json& fx = truth["effects"];
  EXPECT_EQ(fx["brighter_fatter"]["slope_x_px_per_e"], model::BrighterFatterParams().slope_x_px_per_e);
  EXPECT_EQ(fx["brighter_fatter"]["slope_y_px_per_e"], 3e-7);
  EXPECT_EQ(fx["halo"]["fraction"], model::HaloParams().fraction);
  EXPECT_EQ(fx["serial_cti"]["trail_fraction"], 1e-3);
  EXPECT_EQ(fx["jitter"]["sigma_x_px"], nlohmann::json({0.0, 0.2}));
  EXPECT_EQ(fx["jitter"]["motion_length_px"], nlohmann::json({0.0, 0.5}));
  EXPECT_FALSE(fx.contains("ipc"));
  // Per exposure: the brighter-fatter signal is the peak of the spot rendered with the jitter
  // alone; the widths follow from it.
  model::SpotRenderer renderer(c.model);
  const model::PixelGrid grid{15, 13, 0.0, 0.0};
  for (size_t k = 0; k < 2; ++k) {
    const nlohmann::json& ek = truth["exposures"][k]["effects"];
    model::ExposureEffects jitter_only;
    jitter_only.jitter = c.exposures[k].jitter;
    std::vector<double> m(grid.size());
    model::RenderSpotWithEffects(renderer, jitter_only, c.Params(c.exposures[k]), grid, m.data());
    const double peak = *std::max_element(m.begin(), m.end());
    EXPECT_EQ(ek["brighter_fatter"]["peak_e"].get<double>(), peak) << k;
    EXPECT_DOUBLE_EQ(ek["brighter_fatter"]["ccd_sigma_x_px"].get<double>(),
                     0.291 + model::BrighterFatterParams().slope_x_px_per_e * peak);
    EXPECT_DOUBLE_EQ(ek["brighter_fatter"]["ccd_sigma_y_px"].get<double>(), 0.335 + 3e-7 * peak);
    EXPECT_DOUBLE_EQ(ek["rendered_ccd_sigma_x_px"].get<double>(),
                     std::hypot(0.291 + model::BrighterFatterParams().slope_x_px_per_e * peak,
                                k == 0 ? 0.0 : 0.2));
    EXPECT_EQ(ek["jitter"]["sigma_x_px"], k == 0 ? 0.0 : 0.2);
    EXPECT_EQ(ek["jitter"]["motion_nodes"].get<int>() > 1, k == 1);
  }
  // Deterministic with effects too.
  ASSERT_TRUE(RunSimulation(c, TempDir("fx_seed_a"), false, &r, &error)) << error;
  ASSERT_TRUE(RunSimulation(c, TempDir("fx_seed_b"), false, &r2, &error)) << error;
  for (size_t k = 0; k < 2; ++k) EXPECT_TRUE(ReadBytes(r.files[k]) == ReadBytes(r2.files[k]));
  EXPECT_TRUE(ReadBytes(r.truth_path) == ReadBytes(r2.truth_path));
}

}  // namespace
}  // namespace ccdpsf
