#include "ccdpsf/campaign_simulation.h"

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <set>
#include <string>

#include "ccdpsf/fits_io.h"
#include "gtest/gtest.h"
#include "support/run_ccdpsf.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Per process, so that parallel ctest processes do not delete each other's folders.
std::string Fresh(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_campaign_" +
                          std::to_string(static_cast<long>(::getpid())) + "_" + name;
  fs::remove_all(dir);
  return dir;
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

json ReadJson(const std::string& path) { return json::parse(ReadBytes(path)); }

CampaignConfig MustParse(const std::string& text) {
  std::string error;
  auto c = ParseCampaignConfig(text, &error);
  EXPECT_TRUE(c.has_value()) << error;
  return c.value_or(CampaignConfig());
}

CampaignConfig MustLoad(const std::string& path) {
  std::string error;
  auto c = LoadCampaignConfig(path, &error);
  EXPECT_TRUE(c.has_value()) << error;
  return c.value_or(CampaignConfig());
}

// A small campaign: two settings and (optionally) a focus series.
std::string SmallConfig(const std::string& sampling, const std::string& extra = "") {
  return R"({"campaign": {"seed": 5, "sampling": ")" + sampling + R"(",
      "settings": [{"wavelength_nm": 600, "peak_e": 7900, "exptime_s": 0.1, "exposures": 2},
                   {"wavelength_nm": 890, "peak_e": 143000, "exptime_s": 2.8, "exposures": 2}],
      "focus_series": [{"wavelength_nm": 800, "peak_e": 100000, "exptime_s": 2.5,
                        "focus_positions_um": [-300, -100, 50, 250],
                        "exposures_per_position": 2, "best_focus_um": 50,
                        "defocus_sigma_px_per_um": 0.002}])" +
         extra + "}}";
}

double MaxPixel(const Image& image) {
  return *std::max_element(image.data.begin(), image.data.end());
}

// Every regular file below `dir`, by path relative to it.
std::map<std::string, std::string> FilesBelow(const std::string& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) {
      files[fs::relative(entry.path(), dir).string()] = ReadBytes(entry.path().string());
    }
  }
  return files;
}

using testing_support::RunCcdpsf;
using testing_support::RunResult;

// The truth widths against the formula evaluated by hand in a different but equivalent
// arrangement, FWHM_x = FWHM_x(I0 at lambda0) (lambda / lambda0)^alpha_x FWHM_x(I) /
// FWHM_x(I0), at two settings: the defaults at (600 nm, 7900 e-) and a non-default truth
// (every key given) at (890 nm, 143000 e-) on 10 um pixels. Tolerance 1e-12 relative: a
// handful of roundings of O(1e-16) each.
TEST(CampaignSimulation, TruthWidthsEqualTheFormulaByHand) {
  const double k = 2.0 * std::sqrt(2.0 * std::log(2.0));
  {
    const CampaignConfig c = MustParse(SmallConfig("pixel_centre"));
    const std::vector<CampaignGroup> groups = PlanCampaign(c);
    ASSERT_EQ(groups.size(), 3u);
    const double fx0 = 6.66 + 1.14e-5 * 157800, fy0 = 6.72 + 1.12e-5 * 157800;
    const double fx = fx0 * std::pow(600.0 / 800.0, -0.237) * (6.66 + 1.14e-5 * 7900) / fx0;
    const double fy = fy0 * std::pow(600.0 / 800.0, -0.307) * (6.72 + 1.12e-5 * 7900) / fy0;
    EXPECT_NEAR(groups[0].ccd_sigma_x_px, fx / (k * 12.0), 1e-12 * fx / (k * 12.0));
    EXPECT_NEAR(groups[0].ccd_sigma_y_px, fy / (k * 12.0), 1e-12 * fy / (k * 12.0));
    EXPECT_EQ(groups[0].simulation.ccd_sigma_x_px, groups[0].ccd_sigma_x_px);
    EXPECT_EQ(groups[0].simulation.ccd_sigma_y_px, groups[0].ccd_sigma_y_px);
    // The derived amplitudes: FWHM_x(lambda0) = c_x + s_x I0.
    EXPECT_NEAR(c.truth.AX() * std::pow(800.0, -0.237), fx0, 1e-12 * fx0);
    EXPECT_NEAR(c.truth.AY() * std::pow(800.0, -0.307), fy0, 1e-12 * fy0);
  }
  {
    const CampaignConfig c = MustParse(R"({"campaign": {"seed": 1,
        "detector": {"pixel_um": 10.0},
        "truth": {"reference_intensity_e": 100000, "reference_wavelength_nm": 700,
                  "alpha_x": -0.3, "alpha_y": -0.2,
                  "intensity_x": {"intercept_um": 7.0, "slope_um_per_e": 2e-5},
                  "intensity_y": {"intercept_um": 6.5, "slope_um_per_e": 1e-5}},
        "settings": [{"wavelength_nm": 890, "peak_e": 143000, "exptime_s": 2.8,
                      "exposures": 1}]}})");
    const std::vector<CampaignGroup> groups = PlanCampaign(c);
    ASSERT_EQ(groups.size(), 1u);
    const double fx0 = 7.0 + 2e-5 * 1e5, fy0 = 6.5 + 1e-5 * 1e5;
    const double fx = fx0 * std::pow(890.0 / 700.0, -0.3) * (7.0 + 2e-5 * 143000) / fx0;
    const double fy = fy0 * std::pow(890.0 / 700.0, -0.2) * (6.5 + 1e-5 * 143000) / fy0;
    EXPECT_NEAR(groups[0].ccd_sigma_x_px, fx / (k * 10.0), 1e-12 * fx / (k * 10.0));
    EXPECT_NEAR(groups[0].ccd_sigma_y_px, fy / (k * 10.0), 1e-12 * fy / (k * 10.0));
  }
}

// At I0 the geometric-mean FWHM sqrt(FWHM_x FWHM_y) is the implied power law
// sqrt(a_x a_y) lambda^((alpha_x + alpha_y) / 2), with a_x, a_y computed here by hand; the
// default exponent is the paper's -0.272. Tolerance 1e-12 relative (rounding only).
TEST(CampaignSimulation, GeometricMeanAtI0FollowsTheImpliedPowerLaw) {
  const CampaignTruth t;
  const double ax = (6.66 + 1.14e-5 * 157800) / std::pow(800.0, -0.237);
  const double ay = (6.72 + 1.12e-5 * 157800) / std::pow(800.0, -0.307);
  EXPECT_NEAR(t.GeometricAlpha(), -0.272, 1e-15);
  EXPECT_NEAR(t.GeometricA(), std::sqrt(ax * ay), 1e-12 * std::sqrt(ax * ay));
  for (double lambda : {550.0, 600.0, 700.0, 800.0, 890.0, 950.0}) {
    const double geometric = std::sqrt(t.FwhmXUm(157800, lambda) * t.FwhmYUm(157800, lambda));
    const double law = std::sqrt(ax * ay) * std::pow(lambda, -0.272);
    EXPECT_NEAR(geometric, law, 1e-12 * law) << lambda;
  }
}

// Each group's intensity parameter gives the noiseless, exactly centred spot a maximum
// pixel equal to the nominal peak, in both samplings (focus series: at best focus).
// Tolerance 1e-9 relative: the renderers are linear in the intensity parameter up to
// rounding.
TEST(CampaignSimulation, NoiselessCentredPeakEqualsTheNominalPeak) {
  for (const std::string sampling : {"integrated", "pixel_centre"}) {
    const CampaignConfig c = MustParse(SmallConfig(sampling));
    for (const CampaignGroup& g : PlanCampaign(c)) {
      SimulatedExposure e;
      e.flux_e = g.intensity_parameter_e;
      e.x_px = 10.0;  // centre pixel of the 21 x 21 default frame
      e.y_px = 10.0;
      e.wavelength_nm = g.wavelength_nm;
      e.exptime_s = g.exptime_s;
      const double peak = MaxPixel(ExpectedElectrons(g.simulation, e));
      EXPECT_NEAR(peak, g.nominal_peak_e, 1e-9 * g.nominal_peak_e) << sampling << " " << g.name;
      // One intensity for the whole group (a stable source); positions within the jitter.
      for (const SimulatedExposure& x : g.simulation.exposures) {
        EXPECT_EQ(x.flux_e, g.intensity_parameter_e);
        EXPECT_LT(std::fabs(x.x_px - 10.0), 0.1);
        EXPECT_LT(std::fabs(x.y_px - 10.0), 0.1);
      }
    }
  }
}

// The manifest of testdata/campaign_small.json lists every file of every group, each file
// exists, and its WAVELEN / EXPTIME keywords match its group (CFITSIO writes doubles with 15
// significant digits: tolerance 1e-14 relative). truth.json has the same groups with the
// metrics of their widths.
TEST(CampaignSimulation, ManifestListsEveryFileWithMatchingKeywords) {
  const CampaignConfig c = MustLoad(std::string(CCDPSF_TESTDATA) + "/campaign_small.json");
  const std::string dir = Fresh("manifest");
  CampaignResult result;
  std::string error;
  ASSERT_TRUE(RunCampaign(c, dir, /*noiseless=*/false, &result, &error)) << error;
  EXPECT_EQ(result.groups, 14);
  EXPECT_EQ(result.exposures, 7 * 3 + 7 * 5);
  EXPECT_EQ(result.manifest_path, dir + "/manifest.json");
  const json manifest = ReadJson(result.manifest_path);
  const json truth = ReadJson(result.truth_path);
  ASSERT_EQ(manifest.size(), 1u);
  ASSERT_EQ(manifest["groups"].size(), 14u);
  ASSERT_EQ(truth["groups"].size(), 14u);
  const std::vector<CampaignGroup> planned = PlanCampaign(c);
  std::set<std::string> listed;
  int files = 0;
  for (size_t k = 0; k < manifest["groups"].size(); ++k) {
    const json& g = manifest["groups"][k];
    std::set<std::string> keys;
    for (auto it = g.begin(); it != g.end(); ++it) keys.insert(it.key());
    EXPECT_EQ(keys, (std::set<std::string>{"name", "wavelength_nm", "nominal_peak_e", "exptime_s",
                                           "focus_series", "files"}));
    EXPECT_EQ(g["name"], planned[k].name);
    EXPECT_EQ(g["focus_series"].get<bool>(), planned[k].focus_series);
    EXPECT_EQ(truth["groups"][k]["name"], g["name"]);
    ASSERT_EQ(g["files"].size(), planned[k].simulation.exposures.size());
    const double wavelength = g["wavelength_nm"], exptime = g["exptime_s"];
    for (const json& f : g["files"]) {
      const std::string rel = f.get<std::string>();
      EXPECT_EQ(rel.rfind(g["name"].get<std::string>() + "/exposure_", 0), 0u) << rel;
      listed.insert(rel);
      ++files;
      auto image = ReadFitsImage(dir + "/" + rel, &error);
      ASSERT_TRUE(image.has_value()) << error;
      const auto w = FindNumber(image->header, "WAVELEN");
      const auto t = FindNumber(image->header, "EXPTIME");
      ASSERT_TRUE(w && t) << rel;
      EXPECT_NEAR(*w, wavelength, 1e-14 * wavelength) << rel;
      EXPECT_NEAR(*t, exptime, 1e-14 * exptime) << rel;
    }
    EXPECT_TRUE(fs::exists(dir + "/" + g["name"].get<std::string>() + "/truth.json"));
    // The true metrics from the widths used (computed here from the paper's definitions).
    const json& tg = truth["groups"][k];
    const double sx = tg["ccd_sigma_x_px"], sy = tg["ccd_sigma_y_px"];
    EXPECT_EQ(sx, planned[k].ccd_sigma_x_px);
    EXPECT_EQ(sy, planned[k].ccd_sigma_y_px);
    const double kf = 2.0 * std::sqrt(2.0 * std::log(2.0));
    EXPECT_NEAR(tg["fwhm_um"].get<double>(), 2 * std::sqrt(2 * std::log(2.0) * sx * sy) * 12,
                1e-12);
    EXPECT_NEAR(tg["fwhm_x_um"].get<double>(), kf * sx * 12, 1e-12);
    EXPECT_NEAR(tg["fwhm_y_um"].get<double>(), kf * sy * 12, 1e-12);
    EXPECT_NEAR(tg["r2_px2"].get<double>(), sx * sx + sy * sy, 1e-14);
    EXPECT_NEAR(tg["ellipticity"].get<double>(), std::fabs(sx * sx - sy * sy) / (sx * sx + sy * sy),
                1e-14);
    if (!planned[k].focus_series) {
      EXPECT_NEAR(tg["total_sigma_x_px"].get<double>(), std::sqrt(0.41 * 0.41 + sx * sx), 1e-14);
      EXPECT_NEAR(tg["total_sigma_y_px"].get<double>(), std::sqrt(0.41 * 0.41 + sy * sy), 1e-14);
    }
  }
  EXPECT_EQ(files, result.exposures);
  // Nothing on disk that the manifest does not list (besides the truth files).
  for (const auto& [rel, bytes] : FilesBelow(dir)) {
    if (rel == "manifest.json" || rel == "truth.json" || fs::path(rel).filename() == "truth.json") {
      continue;
    }
    EXPECT_TRUE(listed.count(rel)) << rel;
  }
  // The relations used, with the derived amplitudes.
  const json& rel = truth["relations"];
  EXPECT_EQ(rel["fwhm_x_um_vs_wavelength"]["a"].get<double>(), c.truth.AX());
  EXPECT_EQ(rel["fwhm_y_um_vs_wavelength"]["a"].get<double>(), c.truth.AY());
  EXPECT_EQ(rel["fwhm_um_vs_wavelength"]["alpha"].get<double>(), c.truth.GeometricAlpha());
  EXPECT_EQ(truth["seed"].get<uint64_t>(), 11u);
  EXPECT_TRUE(truth.contains("software"));
  fs::remove_all(dir);
}

// Focus series: FOCUSPOS holds the stage position, the defocus is rate |z - z0| (exactly the
// same floating-point operations, so tolerance 1e-15 relative), and the total widths add
// defocus and CCD widths in quadrature. In pixel_centre sampling the best-focus exposure is
// rendered at kPixelCentreMinDefocusPx, and truth.json records both values.
TEST(CampaignSimulation, FocusSeriesWritesFocusposAndTheDefocusLaw) {
  const std::vector<double> z = {-300, -100, 50, 250};
  for (const std::string sampling : {"integrated", "pixel_centre"}) {
    const CampaignConfig c = MustParse(SmallConfig(sampling));
    const std::string dir = Fresh("focus_" + sampling);
    CampaignResult result;
    std::string error;
    ASSERT_TRUE(RunCampaign(c, dir, /*noiseless=*/true, &result, &error)) << error;
    const json manifest = ReadJson(result.manifest_path);
    const json truth = ReadJson(result.truth_path);
    const json& g = manifest["groups"][2];
    ASSERT_TRUE(g["focus_series"].get<bool>());
    EXPECT_EQ(g["name"], "f00_800nm_100000e_focus");
    ASSERT_EQ(g["files"].size(), 8u);
    const json& tg = truth["groups"][2];
    const json group_truth = ReadJson(dir + "/f00_800nm_100000e_focus/truth.json");
    const double sx = tg["ccd_sigma_x_px"], sy = tg["ccd_sigma_y_px"];
    for (size_t k = 0; k < 8; ++k) {
      const double zk = z[k / 2];
      const std::string rel = g["files"][k];
      EXPECT_EQ(rel, "f00_800nm_100000e_focus/model_00" + std::to_string(k) + ".fits");
      auto image = ReadFitsImage(dir + "/" + rel, &error);
      ASSERT_TRUE(image.has_value()) << error;
      const auto focus = FindNumber(image->header, "FOCUSPOS");
      ASSERT_TRUE(focus.has_value()) << rel;
      EXPECT_NEAR(*focus, zk, 1e-14 * std::fabs(zk)) << rel;
      const double nominal = 0.002 * std::fabs(zk - 50.0);
      const double rendered =
          sampling == "pixel_centre" ? std::max(nominal, kPixelCentreMinDefocusPx) : nominal;
      const json& e = tg["exposures"][k];
      EXPECT_NEAR(e["focus_position_um"].get<double>(), zk, 0.0);
      EXPECT_NEAR(e["defocus_sigma_nominal_px"].get<double>(), nominal, 1e-15 * nominal);
      EXPECT_NEAR(e["defocus_sigma_px"].get<double>(), rendered, 1e-15 * rendered);
      EXPECT_NEAR(group_truth["exposures"][k]["defocus_px"].get<double>(), rendered,
                  1e-15 * rendered);
      EXPECT_NEAR(e["total_sigma_x_px"].get<double>(), std::sqrt(rendered * rendered + sx * sx),
                  1e-14);
      EXPECT_NEAR(e["total_sigma_y_px"].get<double>(), std::sqrt(rendered * rendered + sy * sy),
                  1e-14);
    }
    // Settings groups carry no FOCUSPOS.
    const std::string first = manifest["groups"][0]["files"][0];
    auto image = ReadFitsImage(dir + "/" + first, &error);
    ASSERT_TRUE(image.has_value()) << error;
    EXPECT_FALSE(FindNumber(image->header, "FOCUSPOS").has_value());
    fs::remove_all(dir);
  }
}

// Same configuration, same bytes (every file, truth and manifest included); another seed
// gives other exposures.
TEST(CampaignSimulation, SameSeedGivesIdenticalBytes) {
  const CampaignConfig c = MustParse(SmallConfig("pixel_centre"));
  CampaignConfig other = c;
  other.seed = c.seed + 1;
  const std::string d1 = Fresh("same1"), d2 = Fresh("same2"), d3 = Fresh("other");
  CampaignResult r;
  std::string error;
  ASSERT_TRUE(RunCampaign(c, d1, false, &r, &error)) << error;
  ASSERT_TRUE(RunCampaign(c, d2, false, &r, &error)) << error;
  ASSERT_TRUE(RunCampaign(other, d3, false, &r, &error)) << error;
  const auto f1 = FilesBelow(d1), f2 = FilesBelow(d2), f3 = FilesBelow(d3);
  EXPECT_EQ(f1.size(), 2u + 3u + 12u);  // manifest + truths + exposures
  EXPECT_TRUE(f1 == f2);
  ASSERT_EQ(f1.size(), f3.size());
  for (const auto& [rel, bytes] : f1) {
    if (rel.find(".fits") != std::string::npos) {
      EXPECT_NE(bytes, f3.at(rel)) << rel;
    }
  }
  for (const std::string& d : {d1, d2, d3}) fs::remove_all(d);
}

// The defaults are the paper's Table 1 (13 settings, 87 exposures), and
// testdata/campaign_table1.json spells out the same settings and truth.
TEST(CampaignSimulation, DefaultSettingsAreTable1) {
  const std::vector<CampaignSetting> table1 = Table1Settings();
  ASSERT_EQ(table1.size(), 13u);
  int exposures = 0;
  for (const CampaignSetting& s : table1) exposures += s.exposures;
  EXPECT_EQ(exposures, 87);
  const CampaignConfig defaults = MustParse(R"({"campaign": {"seed": 3}})");
  const CampaignConfig file = MustLoad(std::string(CCDPSF_TESTDATA) + "/campaign_table1.json");
  for (const CampaignConfig* c : {&defaults, &file}) {
    ASSERT_EQ(c->settings.size(), 13u);
    for (size_t k = 0; k < 13; ++k) {
      EXPECT_EQ(c->settings[k].wavelength_nm, table1[k].wavelength_nm) << k;
      EXPECT_EQ(c->settings[k].peak_e, table1[k].peak_e) << k;
      EXPECT_EQ(c->settings[k].exptime_s, table1[k].exptime_s) << k;
      EXPECT_EQ(c->settings[k].exposures, table1[k].exposures) << k;
    }
    EXPECT_EQ(c->truth.AX(), CampaignTruth().AX());
    EXPECT_EQ(c->truth.AY(), CampaignTruth().AY());
    EXPECT_TRUE(c->focus_series.empty());
  }
  const std::vector<CampaignGroup> groups = PlanCampaign(file);
  EXPECT_EQ(groups.front().name, "g00_600nm_7900e");
  EXPECT_EQ(groups.back().name, "g12_890nm_143000e");
}

TEST(CampaignSimulation, TellsACampaignFromASingleSimulation) {
  EXPECT_TRUE(IsCampaignConfig(R"({"campaign": {}})"));
  EXPECT_FALSE(IsCampaignConfig(ReadBytes(std::string(CCDPSF_TESTDATA) + "/demo_simulation.json")));
  EXPECT_FALSE(IsCampaignConfig("[1, 2]"));
  EXPECT_FALSE(IsCampaignConfig("{not json"));
}

// Bad configurations: a one-line error naming the key, and (through the CLI) nothing
// written.
TEST(CampaignSimulation, BadConfigsGiveOneLineErrorsAndWriteNothing) {
  const std::string s = R"("settings": [{"wavelength_nm": 600, "peak_e": 7900, "exptime_s": 0.1,
                                         "exposures": 2}])";
  struct Case {
    std::string json;
    std::string message;
  };
  const std::vector<Case> cases = {
      {R"({"campaign": {"seed": 1, "colour": "red", )" + s + "}}", "'campaign.colour'"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": 600, "peak_e": 7900,
          "exptime_s": 0.1, "exposures": 2, "gain": 2}]}})",
       "'campaign.settings[0].gain'"},
      {R"({"campaign": {"seed": 1, "truth": {"alpha_z": 1}, )" + s + "}}",
       "'campaign.truth.alpha_z'"},
      {R"({"campaign": {"seed": 1, )" + s + R"(}, "extra": 1})", "'extra'"},
      {R"({"campaign": {"seed": 1, "settings": []}})", "'campaign.settings' must be a non-empty"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": 600, "peak_e": 7900,
          "exptime_s": 0.1, "exposures": 0}]}})",
       "'campaign.settings[0].exposures'"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": 600, "peak_e": -5,
          "exptime_s": 0.1, "exposures": 2}]}})",
       "'campaign.settings[0].peak_e' must be > 0"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": "600", "peak_e": 7900,
          "exptime_s": 0.1, "exposures": 2}]}})",
       "'campaign.settings[0].wavelength_nm' must be a finite number"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": 600, "peak_e": 7900,
          "exptime_s": 0.1, "exposures": 2.5}]}})",
       "'campaign.settings[0].exposures' must be an integer"},
      {R"({"campaign": {"seed": 1, "position_jitter_px": 0.5, )" + s + "}}",
       "'campaign.position_jitter_px'"},
      {R"({"campaign": {"seed": 1, "sampling": "pixel_centre",
          "defocus": {"kind": "pillbox", "radius_px": 0.5}, )" +
           s + "}}",
       "'campaign.defocus.kind'"},
      {R"({"campaign": {"seed": 1, "truth": {"intensity_x": {"intercept_um": -10}}, )" + s + "}}",
       "intensity_x"},
      {R"({"campaign": {"seed": 1, "focus_series": [{"wavelength_nm": 800, "peak_e": 1e5,
          "exptime_s": 1, "focus_positions_um": [], "defocus_sigma_px_per_um": 0.001}], )" +
           s + "}}",
       "'campaign.focus_series[0].focus_positions_um'"},
      {R"({"campaign": {)" + s + "}}", "'campaign.seed' is required"},
      {R"({"campaign": {"seed": 1, "settings": [{"wavelength_nm": 600, "peak_e": 7900,
          "exptime_s": 0.1, "exposures": 2, "focus_position_um": 100}]}})",
       "'campaign.settings[0].focus_position_um' needs a focus series at 600 nm"},
  };
  for (const Case& c : cases) {
    std::string error;
    EXPECT_FALSE(ParseCampaignConfig(c.json, &error).has_value()) << c.json;
    EXPECT_NE(error.find(c.message), std::string::npos) << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
  // Through the CLI: exit code 1, one line, no output folder. (Four of the cases: unknown
  // key, empty settings, exposures < 1, negative peak.)
  const std::string dir = Fresh("bad");
  fs::create_directories(dir);
  for (int k : {0, 4, 5, 6}) {
    const std::string config = dir + "/bad" + std::to_string(k) + ".json";
    { std::ofstream(config) << cases[k].json; }
    const std::string out = dir + "/out" + std::to_string(k);
    const RunResult r = RunCcdpsf("simulate --config=" + config + " --out=" + out);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
    EXPECT_NE(r.output.find(cases[k].message), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(out)) << out;
  }
  fs::remove_all(dir);
}

// A run that cannot create its folder fails with a reason and leaves nothing behind; a
// successful one leaves no staging folder.
TEST(CampaignSimulation, FailureLeavesNothingBehind) {
  const CampaignConfig c = MustParse(SmallConfig("pixel_centre"));
  const std::string blocker = Fresh("blocker");
  { std::ofstream(blocker) << "a file where the folder should be"; }
  CampaignResult r;
  std::string error;
  EXPECT_FALSE(RunCampaign(c, blocker + "/sub", false, &r, &error));
  EXPECT_FALSE(error.empty());
  EXPECT_EQ(ReadBytes(blocker), "a file where the folder should be");
  fs::remove(blocker);
  const std::string dir = Fresh("clean");
  ASSERT_TRUE(RunCampaign(c, dir, false, &r, &error)) << error;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    EXPECT_EQ(entry.path().string().find(".ccdpsf-staging"), std::string::npos) << entry.path();
  }
  fs::remove_all(dir);
}

// The documented command: one line naming the counts and the manifest; --noiseless writes
// model_NNN.fits.
TEST(CampaignSimulation, CommandLineWritesTheSmallCampaign) {
  const std::string dir = Fresh("cli");
  const RunResult r = RunCcdpsf("simulate --noiseless --config=" + std::string(CCDPSF_TESTDATA) +
                                "/campaign_small.json --out=" + dir);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_NE(r.output.find("14 groups, 56 noiseless models"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(dir + "/manifest.json"), std::string::npos) << r.output;
  const json manifest = ReadJson(dir + "/manifest.json");
  for (const json& g : manifest["groups"]) {
    for (const json& f : g["files"]) {
      EXPECT_NE(f.get<std::string>().find("/model_"), std::string::npos) << f;
      EXPECT_TRUE(fs::exists(dir + "/" + f.get<std::string>())) << f;
    }
  }
  EXPECT_TRUE(fs::exists(dir + "/truth.json"));
  EXPECT_TRUE(fs::exists(dir + "/run.json"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ccdpsf
