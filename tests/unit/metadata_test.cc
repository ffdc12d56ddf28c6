// Tests of per-exposure metadata (metadata.h), manifests (manifest.h), their precedence, and
// how they reach fit, diagnose and trend: every value's source recorded, nothing physical
// silently defaulted, and malformed input refused in one line.
#include "ccdpsf/metadata.h"

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "ccdpsf/exposure.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/trend/campaign.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/fits_fixtures.h"
#include "support/run_ccdpsf.h"
#include "support/slow_test.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test_support::SyntheticFrame;

std::string Fresh(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_meta_" +
                          std::to_string(static_cast<long>(::getpid())) + "_" + name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void Write(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// A synthetic spot frame in ADU with the given header, written as a FITS file.
std::string SpotFile(const std::string& path, const FitsHeader& header, uint64_t seed = 1) {
  SyntheticFrame spec;
  spec.seed = seed;
  std::string error;
  EXPECT_TRUE(WriteFitsImageU16(path, test_support::MakeSpotFrame(spec), header, &error)) << error;
  return path;
}

TEST(KeywordMap, DefaultsOverlaysAndRefusals) {
  KeywordMap map;
  ASSERT_NE(map.Find("gain_e_per_adu"), nullptr);
  EXPECT_EQ(map.Find("gain_e_per_adu")->keyword, "GAIN");
  EXPECT_EQ(map.Find("spot_x_px"), nullptr);  // no default keyword
  std::string error;
  ASSERT_TRUE(map.OverlayText("gain_e_per_adu=egain, exptime_s=EXPMS*0.001", &error)) << error;
  EXPECT_EQ(map.Find("gain_e_per_adu")->keyword, "EGAIN");  // upper-cased
  EXPECT_EQ(map.Find("exptime_s")->scale, 0.001);
  ASSERT_TRUE(map.Overlay(json::parse(R"({"pixel_um": {"keyword": "XPIXSZ"}, "focus_position_um": null})"),
                          &error))
      << error;
  EXPECT_EQ(map.Find("pixel_um")->keyword, "XPIXSZ");
  EXPECT_EQ(map.Find("focus_position_um"), nullptr);  // switched off
  for (const char* bad : {"colour=GAIN", "gain_e_per_adu", "gain_e_per_adu=TOO_LONG_NAME",
                          "exptime_s=T*zero", "bias_section=BSEC*2", "hdu=EXTN"}) {
    KeywordMap m;
    EXPECT_FALSE(m.OverlayText(bad, &error)) << bad;
    EXPECT_EQ(error.find('\n'), std::string::npos);
  }
}

TEST(Metadata, KeywordMapAndPrecedenceReachTheCalibration) {
  // Another lab's names: EGAIN for the gain, EXPMS in milliseconds, no pixel size.
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  FitsImage image;
  image.pixels = frame;
  image.header = {{"EGAIN", 3.1, ""}, {"EXPMS", 250.0, ""}, {"GAIN", 99.0, "wrong one"}};
  CalibrationOptions options;
  std::string error;
  ASSERT_TRUE(options.keywords.OverlayText("gain_e_per_adu=EGAIN,exptime_s=EXPMS*0.001", &error));
  std::optional<Exposure> e = CalibrateExposure(image, "f.fits", options, &error);
  ASSERT_TRUE(e) << error;
  EXPECT_EQ(e->stamp.gain_e_per_adu, 3.1);
  EXPECT_EQ(e->report.Source("gain_e_per_adu"), "keyword EGAIN");
  EXPECT_DOUBLE_EQ(e->stamp.info.exptime_s, 0.25);
  EXPECT_EQ(e->report.Source("exptime_s"), "keyword EXPMS x 0.001");
  // Nothing physical is defaulted: no pixel size anywhere -> unknown.
  EXPECT_TRUE(std::isnan(e->stamp.info.pixel_um));
  EXPECT_EQ(e->report.Source("pixel_um"), "unknown");
  // A given value beats the keyword, and says where it came from.
  options.given.SetNumber("gain_e_per_adu", 2.0, "manifest m.csv line 2");
  e = CalibrateExposure(image, "f.fits", options, &error);
  ASSERT_TRUE(e) << error;
  EXPECT_EQ(e->stamp.gain_e_per_adu, 2.0);
  EXPECT_EQ(e->report.Source("gain_e_per_adu"), "manifest m.csv line 2");
  // A keyword that is there but not a number is an error, not a missing value.
  image.header.push_back({"EXPMS", std::string("soon"), ""});
  image.header.erase(image.header.begin() + 1);
  EXPECT_FALSE(CalibrateExposure(image, "f.fits", options, &error));
  EXPECT_NE(error.find("keyword EXPMS (exptime_s) is not a finite number"), std::string::npos)
      << error;
}

TEST(Manifest, CsvRowsColumnsAndErrors) {
  const std::string dir = Fresh("csv");
  Write(dir + "/m.csv",
        "# a comment line\n"
        "file,setting,exptime_s,search_region,gain_e_per_adu\n"
        "a.fits,s1,0.1,\"[10:20,30:40]\",\n"
        "\n"
        "sub/b.fits,,0.2,,3.1\n");
  Manifest m;
  std::string error;
  ASSERT_TRUE(LoadManifest(dir + "/m.csv", &m, &error)) << error;
  ASSERT_EQ(m.rows.size(), 2u);
  EXPECT_EQ(m.rows[0].file, (fs::path(dir) / "a.fits").lexically_normal().string());
  EXPECT_EQ(m.rows[0].setting, "s1");
  EXPECT_EQ(*m.rows[0].values.Find("search_region")->text, "[10:20,30:40]");
  EXPECT_FALSE(m.rows[0].values.Has("gain_e_per_adu"));  // an empty cell is "not given"
  EXPECT_EQ(m.rows[0].values.Find("exptime_s")->source, "manifest m.csv line 3");
  EXPECT_EQ(*m.rows[1].values.Find("gain_e_per_adu")->number, 3.1);
  EXPECT_NE(m.Find(dir + "/./sub/../sub/b.fits"), nullptr);  // matched by canonical path
  // Saved by a spreadsheet as "CSV UTF-8": a byte-order mark before the header and CRLF line
  // ends; the same rows.
  Write(dir + "/bom.csv", "\xEF\xBB\xBF" "file,exptime_s\r\na.fits,0.1\r\n");
  Manifest bom;
  ASSERT_TRUE(LoadManifest(dir + "/bom.csv", &bom, &error)) << error;
  ASSERT_EQ(bom.rows.size(), 1u);
  EXPECT_EQ(*bom.rows[0].values.Find("exptime_s")->number, 0.1);
  struct Bad {
    const char* text;
    const char* says;
  };
  for (const Bad& bad : {Bad{"file,colour\na.fits,red\n", "unknown column 'colour'"},
                         Bad{"exptime_s\n0.1\n", "no 'file' column"},
                         Bad{"file,exptime_s\na.fits,0.1\na.fits,0.2\n", "listed twice"},
                         Bad{"file,exptime_s\na.fits,fast\n", "line 2: exptime_s must be a finite number"},
                         Bad{"file,exptime_s\na.fits\n", "1 fields, the header has 2"},
                         Bad{"file,hdu\na.fits,\"AMP1\n", "unterminated quote"},
                         Bad{"", "is empty"}}) {
    Write(dir + "/bad.csv", bad.text);
    EXPECT_FALSE(LoadManifest(dir + "/bad.csv", &m, &error)) << bad.text;
    EXPECT_NE(error.find(bad.says), std::string::npos) << error;
    EXPECT_EQ(error.find('\n'), std::string::npos);
  }
}

TEST(Manifest, JsonFormsAndThePrecedenceOfSources) {
  const std::string dir = Fresh("json");
  Write(dir + "/m.json",
        R"({"exposures": [{"file": "a.fits", "exptime_s": 0.1, "gain_e_per_adu": 2.0},
                          {"file": "b.fits", "setting": "x", "hdu": "AMP2"}]})");
  Manifest m;
  std::string error;
  ASSERT_TRUE(LoadManifest(dir + "/m.json", &m, &error)) << error;
  EXPECT_EQ(m.rows[1].setting, "x");
  EXPECT_EQ(*m.rows[1].values.Find("hdu")->text, "AMP2");
  // flag > manifest row > FIT.json.
  GivenMetadata flags;
  flags.SetNumber("gain_e_per_adu", 5.0, "flag --gain_e_per_adu");
  CalibrationOptions config;
  config.given.SetNumber("gain_e_per_adu", 7.0, "FIT.json");
  config.given.SetNumber("pixel_um", 12.0, "FIT.json");
  config.given.SetNumber("exptime_s", 9.0, "FIT.json");
  std::vector<InputFile> inputs;
  ASSERT_TRUE(ResolveInputFiles({}, &m, flags, config, &inputs, &error)) << error;
  ASSERT_EQ(inputs.size(), 2u);
  const GivenMetadata& a = inputs[0].options.given;
  EXPECT_EQ(a.Find("gain_e_per_adu")->source, "flag --gain_e_per_adu");
  EXPECT_EQ(a.Find("exptime_s")->source, "manifest m.json entry 0");
  EXPECT_EQ(a.Find("pixel_um")->source, "FIT.json");
  EXPECT_EQ(inputs[1].options.given.Find("exptime_s")->source, "FIT.json");
  // A file given with a manifest must be in it.
  EXPECT_FALSE(ResolveInputFiles({dir + "/c.fits"}, &m, flags, config, &inputs, &error));
  EXPECT_NE(error.find("is not in the manifest"), std::string::npos) << error;
  for (const char* bad : {R"({"exposures": []})", R"({"exposures": [{"exptime_s": 1}]})",
                          R"({"rows": []})", R"({"exposures": [{"file": "a", "zoom": 2}]})",
                          R"({"groups": [{"name": "g", "files": ["a"]}]})", "[1, 2"}) {
    Write(dir + "/bad.json", bad);
    EXPECT_FALSE(LoadManifest(dir + "/bad.json", &m, &error)) << bad;
    EXPECT_EQ(error.find('\n'), std::string::npos);
  }
}

TEST(Campaign, ASubfolderPerSettingIsReadAsItIs) {
  // Headers without WAVELEN; the wavelength comes from a flag, the settings from the folders.
  const std::string dir = Fresh("campaign");
  for (const char* setting : {"800nm_short", "800nm_long"}) {
    fs::create_directories(dir + "/" + std::string(setting));
    for (int k = 0; k < 2; ++k) {
      SpotFile(dir + "/" + setting + "/e" + std::to_string(k) + ".fits", {{"GAIN", 3.1, ""}},
               10 + k);
    }
  }
  std::vector<trend::CampaignGroup> groups;
  std::string error;
  // Without a wavelength each setting is a gap with the reason.
  ASSERT_TRUE(trend::LoadCampaign({dir}, &groups, &error)) << error;
  ASSERT_EQ(groups.size(), 2u);
  EXPECT_NE(groups[0].problem.find("no wavelength"), std::string::npos) << groups[0].problem;
  trend::CampaignOptions options;
  options.flags.SetNumber("wavelength_nm", 800.0, "flag --wavelength_nm");
  ASSERT_TRUE(trend::LoadCampaign({dir}, options, &groups, &error)) << error;
  ASSERT_EQ(groups.size(), 2u);
  EXPECT_EQ(groups[0].name, "800nm_long");
  EXPECT_EQ(groups[1].name, "800nm_short");
  EXPECT_TRUE(groups[0].problem.empty()) << groups[0].problem;
  EXPECT_EQ(groups[0].files.size(), 2u);
  EXPECT_EQ(groups[0].inputs[0].options.given.Find("wavelength_nm")->source, "flag --wavelength_nm");
}

// The CLI: a manifest and a keyword map instead of rewriting headers; --strict.
TEST(MetadataCli, ManifestKeywordMapAndStrict) {
  CCDPSF_RELEASE_ONLY();  // fits through the binary; the manifest and keyword map run sanitized in
  // Manifest.* and KeywordMap.*
  const std::string dir = Fresh("cli");
  // A frame whose header has another lab's gain keyword and nothing else.
  SpotFile(dir + "/spot.fits", {{"EGAIN", 3.1, ""}});
  Write(dir + "/m.csv", "file,pixel_um,exptime_s,wavelength_nm\nspot.fits,12,0.5,700\n");
  std::string out;
  // Without the keyword map: no gain.
  EXPECT_EQ(testing_support::RunCcdpsf("fit --nomcmc --out=" + dir + "/f0 --manifest=" + dir +
                                           "/m.csv",
                                       &out),
            1);
  EXPECT_NE(out.find("no gain"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir + "/f0/fit.json"));
  ASSERT_EQ(testing_support::RunCcdpsf("fit --nomcmc --keywords=gain_e_per_adu=EGAIN --out=" +
                                           dir + "/f1 --manifest=" + dir + "/m.csv",
                                       &out),
            0)
      << out;
  std::ifstream in(dir + "/f1/fit.json");
  const json fit = json::parse(in);
  const json& meta = fit["exposures"][0]["calibration"]["metadata"];
  EXPECT_EQ(meta["gain_e_per_adu"]["source"], "keyword EGAIN");
  EXPECT_EQ(meta["pixel_um"]["source"], "manifest m.csv line 2");
  EXPECT_EQ(meta["wavelength_nm"]["value"], 700.0);
  ASSERT_TRUE(fit.contains("quality"));
  EXPECT_NE(out.find("verdict " + fit["quality"]["verdict"].get<std::string>()), std::string::npos);
  // No pixel size at all: refused, saying how to give it.
  EXPECT_EQ(testing_support::RunCcdpsf("fit --nomcmc --gain_e_per_adu=3.1 --out=" + dir + "/f2 " +
                                           dir + "/spot.fits",
                                       &out),
            1);
  EXPECT_NE(out.find("no pixel size: give --pixel_um"), std::string::npos) << out;
  // --strict: a suspect verdict (a cosmic ray beside the core, masked) exits 3.
  {
    SyntheticFrame spec;
    Image frame = test_support::MakeSpotFrame(spec);
    const int px = static_cast<int>(std::lround(spec.spot_x_px));
    const int py = static_cast<int>(std::lround(spec.spot_y_px));
    frame(px + 1, py) += 3000.0;
    std::string error;
    ASSERT_TRUE(WriteFitsImageU16(dir + "/cr.fits", frame, {{"GAIN", 3.1, ""}}, &error));
  }
  const std::string args = "fit --nomcmc --pixel_um=12 --out=" + dir + "/f3 " + dir + "/cr.fits";
  ASSERT_EQ(testing_support::RunCcdpsf(args, &out), 0) << out;
  EXPECT_NE(out.find("verdict suspect"), std::string::npos) << out;
  EXPECT_EQ(testing_support::RunCcdpsf(args + " --strict", &out), 3) << out;
}

TEST(MetadataCli, SeparateFitsOfSameNamedFilesDoNotCollide) {
  const std::string dir = Fresh("collide");
  fs::create_directories(dir + "/a");
  fs::create_directories(dir + "/b");
  SpotFile(dir + "/a/exposure_000.fits", {{"GAIN", 3.1, ""}, {"PIXSIZE", 12.0, ""}}, 1);
  SpotFile(dir + "/b/exposure_000.fits", {{"GAIN", 3.1, ""}, {"PIXSIZE", 12.0, ""}}, 2);
  std::string out;
  ASSERT_EQ(testing_support::RunCcdpsf("fit --nomcmc --out=" + dir + "/f " + dir +
                                           "/a/exposure_000.fits " + dir + "/b/exposure_000.fits",
                                       &out),
            0)
      << out;
  EXPECT_TRUE(fs::exists(dir + "/f/a_exposure_000/fit.json"));
  EXPECT_TRUE(fs::exists(dir + "/f/b_exposure_000/fit.json"));
}

}  // namespace
}  // namespace ccdpsf
