// Lab frames end to end: simulated exposures with ordinary lab defects added by a separate,
// simple script (tests/support/lab_defects.py: numpy and astropy, no ccdpsf code), and the
// real bench frames (testing_support::RealFramesFolder) when they are present.
//
// The rule each defect is held to (issue "Real laboratory frames"): either the truth is
// recovered within its interval, or the verdict is not "ok" and names the cause. Where the
// tool today does both (recovers the truth and says what it masked), the tests demand both,
// so that a regression in either shows.
//
// Truth: testdata/demo_simulation.json, total widths sqrt(ccd^2 + defocus^2) = 0.5028 px (x)
// and 0.5295 px (y) (the identified quantities in integrated sampling with a Gaussian defocus).
// "Within its interval": within 4 Laplace sds (--nomcmc keeps the tests quick; the MCMC
// intervals agree with Laplace here, fit.json's map_vs_mcmc), which a correct fit misses
// once in 16000.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"
#include "support/slow_test.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing_support::RunCcdpsf;
using testing_support::RunResult;
using testing_support::Shell;

const double kTruthX = std::hypot(0.291, 0.41);
const double kTruthY = std::hypot(0.335, 0.41);

std::string Fresh(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_lab_" +
                          std::to_string(static_cast<long>(::getpid())) + "_" + name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// The defect script needs Debian's python3-numpy and python3-astropy.
bool PythonReady(std::string* why) {
  return Shell("/usr/bin/python3 -c 'import numpy, astropy'", why) == 0;
}

std::string Script() { return std::string(CCDPSF_SOURCE_DIR) + "/tests/support/lab_defects.py"; }

// The clean simulated set, made once per process.
const std::string& CleanSet() {
  static const std::string dir = [] {
    const std::string d = Fresh("clean");
    const RunResult r = RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) +
                                  "/demo_simulation.json --out=" + d);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return d;
  }();
  return dir;
}

// exposure_000 of the clean set with one defect, as `name`.fits in the set's folder.
std::string WithDefect(const std::string& name) {
  const std::string out = CleanSet() + "/" + name + ".fits";
  if (fs::exists(out)) return out;
  std::string output;
  EXPECT_EQ(Shell("/usr/bin/python3 " + Script() + " " + name + " " + CleanSet() +
                      "/exposure_000.fits " + out,
                  &output),
            0)
      << output;
  return out;
}

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  return json::parse(in, nullptr, false);
}

// Fits with the given arguments into a fresh folder; returns fit.json (null on failure, with
// the output in *output).
json Fit(const std::string& name, const std::string& args, std::string* output) {
  const std::string out = Fresh("fit_" + name);
  const int code = RunCcdpsf("fit --nomcmc --out=" + out + " " + args, output);
  if (code != 0) return json();
  return ReadJson(out + "/fit.json");
}

// Whether both total widths lie within 4 Laplace sds of the truth.
bool Recovered(const json& fit, std::string* detail) {
  const json& d = fit["derived"];
  bool ok = true;
  for (const auto& [name, truth] : {std::pair<const char*, double>{"total_sigma_x_px", kTruthX},
                                    {"total_sigma_y_px", kTruthY}}) {
    const double map = d[name]["map"].get<double>();
    const double sd = d[name]["laplace_sd"].get<double>();
    const double z = (map - truth) / sd;
    *detail += std::string(name) + " " + std::to_string(map) + " (" + std::to_string(z) + " sd) ";
    ok = ok && std::fabs(z) < 4.0;
  }
  return ok;
}

std::set<std::string> Codes(const json& fit, const char* list) {
  std::set<std::string> codes;
  for (const json& r : fit["quality"][list]) codes.insert(r["code"].get<std::string>());
  return codes;
}

// The issue's rule, and the stronger statement the tool meets today: the truth recovered and
// every reason for a verdict other than "ok" among `allowed` (the causes of this defect);
// `must` (may be empty) must be among the reasons or notes.
void ExpectHandled(const json& fit, const std::set<std::string>& allowed, const std::string& must,
                   const std::string& output) {
  ASSERT_TRUE(fit.is_object()) << output;
  std::string detail;
  const bool recovered = Recovered(fit, &detail);
  const std::string verdict = fit["quality"]["verdict"];
  const std::set<std::string> reasons = Codes(fit, "reasons");
  // The rule.
  bool names_cause = false;
  for (const std::string& c : reasons) names_cause = names_cause || allowed.count(c) > 0;
  EXPECT_TRUE(recovered || (verdict != "ok" && names_cause))
      << detail << " verdict " << verdict << "\n" << fit["quality"].dump(1);
  // Today's behaviour.
  EXPECT_TRUE(recovered) << detail;
  for (const std::string& c : reasons) {
    EXPECT_TRUE(allowed.count(c)) << "unexpected reason " << c << "\n" << fit["quality"].dump(1);
  }
  if (!must.empty()) {
    const std::set<std::string> notes = Codes(fit, "notes");
    EXPECT_TRUE(reasons.count(must) || notes.count(must)) << must << "\n" << fit["quality"].dump(1);
  }
}

class LabDefects : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    if (!PythonReady(&why)) {
      GTEST_SKIP() << "/usr/bin/python3 with numpy and astropy is needed to add the defects "
                      "(apt install python3-numpy python3-astropy): "
                   << why;
    }
  }
};

TEST_F(LabDefects, CleanExposureIsOk) {
  std::string output;
  const json fit = Fit("clean", CleanSet() + "/exposure_000.fits", &output);
  ExpectHandled(fit, {}, "", output);
  EXPECT_EQ(fit["quality"]["verdict"], "ok") << fit["quality"].dump(1);
}

TEST_F(LabDefects, CosmicRayBesideThePeak) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  // One exposure: a lone spike in the core is masked, and the verdict says so.
  std::string output;
  const json fit = Fit("cr1", WithDefect("cosmic_adjacent"), &output);
  ExpectHandled(fit, {"core_outlier_masked"}, "core_outlier_masked", output);
}

TEST_F(LabDefects, CosmicRayThreePixelsAway) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  std::string output;
  const json fit = Fit("cr3", WithDefect("cosmic_3px"), &output);
  ExpectHandled(fit, {"another_source", "core_outlier_masked"}, "another_source", output);
}

TEST_F(LabDefects, HotColumnThroughTheStamp) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  std::string output;
  const json fit = Fit("hot", WithDefect("hot_column"), &output);
  ExpectHandled(fit, {"column_defect"}, "column_defect", output);
  // The column (x + 4 of the peak pixel) is masked in the stamp.
  const json& masks = fit["exposures"][0]["calibration"]["masks"];
  ASSERT_FALSE(masks.empty());
  EXPECT_NE(masks[0]["reason"].get<std::string>().find("column 36"), std::string::npos)
      << masks.dump();
}

// The same column on a frame no bigger than the stamp (21 x 21, as many bench cameras' cut-outs
// are): no rows lie clear of the stamp, so the columns are judged on the rows away from the
// spot. Before, the column was taken for nine "other sources" and 205 of the 441 pixels were
// masked around them.
TEST_F(LabDefects, HotColumnThroughAStampSizedFrame) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  const std::string dir = Fresh("stamp_sized");
  {
    std::ofstream config(dir + "/sim.json");
    config << R"({"seed": 5, "image": {"nx": 21, "ny": 21},
      "detector": {"gain_e_per_adu": 3.1, "read_noise_e": 4.5, "bias_adu": 1000.0,
                   "pixel_um": 12.0, "saturation_adu": 65535},
      "model": {"sampling": "integrated", "airy_radius_px": 0.47,
                "defocus": {"kind": "gaussian", "sigma_px": 0.41},
                "ccd_sigma_x_px": 0.291, "ccd_sigma_y_px": 0.335},
      "wavelength_nm": 800, "exptime_s": 4.1,
      "exposures": [{"flux_e": 4.26e5, "x_px": 10.07, "y_px": 9.96}]})";
  }
  RunResult r = RunCcdpsf("simulate --config=" + dir + "/sim.json --out=" + dir + "/frames");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::string output;
  ASSERT_EQ(Shell("/usr/bin/python3 " + Script() + " hot_column " + dir +
                      "/frames/exposure_000.fits " + dir + "/hot.fits",
                  &output),
            0)
      << output;
  const json fit = Fit("hot_stamp", dir + "/hot.fits", &output);
  ExpectHandled(fit, {"column_defect"}, "column_defect", output);
  const json& calibration = fit["exposures"][0]["calibration"];
  EXPECT_TRUE(calibration["columns_checked"].get<bool>());
  ASSERT_EQ(calibration["column_defects"].size(), 1u) << calibration["column_defects"].dump();
  EXPECT_EQ(calibration["column_defects"][0]["x"], 14);  // x + 4 of the peak pixel (10, 10)
  EXPECT_FALSE(Codes(fit, "notes").count("another_source")) << fit["quality"].dump(1);
  int masked = 0;
  for (const json& m : calibration["masks"]) masked += m["pixels"].get<int>();
  EXPECT_EQ(masked, 21) << calibration["masks"].dump();
  // And the clean frame has no column defect.
  const json clean = Fit("clean_stamp", dir + "/frames/exposure_000.fits", &output);
  ASSERT_TRUE(clean.is_object()) << output;
  EXPECT_TRUE(clean["exposures"][0]["calibration"]["column_defects"].empty());
}

TEST_F(LabDefects, SecondSpotSixPixelsAway) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  std::string output;
  const json fit = Fit("second", WithDefect("second_spot"), &output);
  ExpectHandled(fit, {"another_source"}, "another_source", output);
  const json& sources = fit["exposures"][0]["calibration"]["other_sources"];
  ASSERT_EQ(sources.size(), 1u) << sources.dump();
  EXPECT_EQ(sources[0]["peak_px"], json({38, 24}));
}

TEST_F(LabDefects, ClippedCoreWithoutSaturate) {
  CCDPSF_RELEASE_ONLY();  // a fit per defect; the screens run sanitized in
  // LabDefects.CleanExposureIsOk, .BlackLevelClippedAtZero and
  // .MultiExtensionSegmentWithItsOwnOverscan
  // One exposure: only the peak pixel is clipped (its neighbours hold < 70 % of it), and
  // alone a clipped peak and a core flatter than the model look alike: the widths come out
  // wrong, and the verdict says why (the issue's rule; the stronger check does not apply).
  std::string output;
  const json one = Fit("clip1", WithDefect("clipped_core"), &output);
  ASSERT_TRUE(one.is_object()) << output;
  EXPECT_NE(one["quality"]["verdict"], "ok");
  EXPECT_TRUE(Codes(one, "reasons").count("peak_deficit")) << one["quality"].dump(1);
  // In a set of five, the same pixel differs from the other exposures' and is masked.
  std::string set = WithDefect("clipped_core");
  for (int k = 1; k < 5; ++k) set += " " + CleanSet() + "/exposure_00" + std::to_string(k) + ".fits";
  const json joint = Fit("clip5", "--joint " + set, &output);
  ExpectHandled(joint, {}, "core_outlier_masked", output);
  ASSERT_EQ(joint["masked_outliers"].size(), 1u) << joint["masked_outliers"].dump();
  EXPECT_EQ(joint["masked_outliers"][0]["exposure"], 0);
  EXPECT_LT(joint["masked_outliers"][0]["z"].get<double>(), -8.0);
}

TEST_F(LabDefects, CosmicRayInOneExposureOfASet) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  std::string output;
  std::string set = WithDefect("cosmic_adjacent");
  for (int k = 1; k < 5; ++k) set += " " + CleanSet() + "/exposure_00" + std::to_string(k) + ".fits";
  const json joint = Fit("cr5", "--joint " + set, &output);
  ExpectHandled(joint, {}, "core_outlier_masked", output);
  EXPECT_EQ(joint["quality"]["verdict"], "ok");
}

TEST_F(LabDefects, EightBitCamera) {
  CCDPSF_RELEASE_ONLY();  // see LabDefects.CleanExposureIsOk for the sanitized runs
  std::string output;
  const json fit = Fit("8bit", WithDefect("quantised_8bit"), &output);
  ExpectHandled(fit, {}, "", output);
  // Read noise 0.006 ADU: every measured pixel takes the interval form, and the flat dark
  // pixels at the black level are censored from below.
  EXPECT_GT(fit["exposures"][0]["censored_pixels"].get<int>(), 400);
}

TEST_F(LabDefects, BlackLevelClippedAtZero) {
  // Without a bias and read noise the clipped background cannot give them: refused, saying why.
  std::string output;
  const std::string file = WithDefect("clipped_black");
  EXPECT_TRUE(Fit("black_refused", file, &output).is_null());
  EXPECT_NE(output.find("clipped"), std::string::npos) << output;
  EXPECT_NE(output.find("--bias_adu and --read_noise_e"), std::string::npos) << output;
  EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 1) << output;
  // Given them, the censored likelihood recovers the truth.
  const json fit = Fit("black", "--bias_adu=0 --read_noise_e=4.5 " + file, &output);
  ExpectHandled(fit, {}, "", output);
  EXPECT_EQ(fit["exposures"][0]["calibration"]["metadata"]["bias_adu"]["source"],
            "flag --bias_adu");
}

// diagnose takes the clipped pixels as fit does: bounds in its likelihood (issue 45: on a real
// frame it masked them and adopted a background that 420 pixels at 0 ADU contradict). Its
// baseline is the fit's model on the same pixels, so its chi^2 and degrees of freedom are the
// fit's (the two MAPs solve one objective from their own starts: 1e-3 of chi^2); and the data
// hold the paper's model alone, so no effect is adopted. Masking the clipped pixels, as
// before, loses the bounds' pull on the MAP: its chi^2 then differs from the fit's (checked).
TEST_F(LabDefects, DiagnoseTakesClippedPixelsAsBoundsLikeFit) {
  CCDPSF_RELEASE_ONLY();  // diagnose refits 50 simulations per round
  std::string output;
  const std::string file = WithDefect("clipped_black");
  const std::string flags = "--bias_adu=0 --read_noise_e=4.5 ";
  const json fit = Fit("black_for_diagnose", flags + file, &output);
  ASSERT_TRUE(fit.is_object()) << output;
  const int censored = fit["exposures"][0]["censored_pixels"].get<int>();
  EXPECT_GT(censored, 100);
  const std::string out = Fresh("diagnose_black");
  ASSERT_EQ(RunCcdpsf("diagnose --out=" + out + " " + flags + file, &output), 0) << output;
  const json d = ReadJson(out + "/diagnose.json");
  ASSERT_TRUE(d.is_object());
  const json& baseline = d["rounds"][0]["fit"];
  EXPECT_EQ(baseline["dof"].get<int>(), fit["fit"]["dof"].get<int>());
  EXPECT_NEAR(baseline["chi2"].get<double>(), fit["fit"]["chi2"].get<double>(),
              1e-3 * fit["fit"]["chi2"].get<double>());
  EXPECT_TRUE(d["named_effects"].empty()) << d["named_effects"].dump();
  bool noted = false;
  for (const json& n : d["quality"]["notes"]) noted = noted || n["code"] == "censored_bounds";
  EXPECT_TRUE(noted) << d["quality"].dump(1);
}

TEST_F(LabDefects, MultiExtensionSegmentWithItsOwnOverscan) {
  std::string output;
  const json fit = Fit("mef", WithDefect("mef_segments"), &output);
  ExpectHandled(fit, {}, "", output);
  const json& meta = fit["exposures"][0]["calibration"]["metadata"];
  EXPECT_EQ(meta["hdu"]["value"], "AMP2");
  EXPECT_NE(meta["hdu"]["source"].get<std::string>().find("auto"), std::string::npos);
  // The bias of AMP2 (1350 ADU) from its own overscan, not AMP1's 1000.
  EXPECT_NEAR(meta["bias_adu"]["value"].get<double>(), 1350.0, 0.5);
  EXPECT_EQ(meta["bias_adu"]["source"].get<std::string>().rfind("bias section [", 0), 0u)
      << meta.dump();
  EXPECT_EQ(meta["bias_section"]["source"], "keyword BIASSEC");
  EXPECT_EQ(meta["data_section"]["source"], "keyword DATASEC");
  // Asked for AMP1, which holds no spot: a one-line refusal.
  EXPECT_TRUE(Fit("mef1", "--hdu=AMP1 " + WithDefect("mef_segments"), &output).is_null());
  EXPECT_NE(output.find("no spot found"), std::string::npos) << output;
}

// ---------------------------------------------------------------------------------------
// The real bench frames (not in the repository; testing_support::RealFramesFolder).

class RealFrames : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(testing_support::RealFramesFolder() + "/pose_de_0.3s_20micron.fits")) {
      GTEST_SKIP() << "the real frames are absent (" << testing_support::RealFramesFolder()
                   << "; set CCDPSF_REALDATA to their folder's parent to run these tests)";
    }
  }
  static std::string File(const std::string& t) {
    return testing_support::RealFramesFolder() + "/pose_de_" + t + "s_20micron.fits";
  }
  // What their headers lack, given as flags: the camera's pixel (4.65 um), a bias at the
  // clipped black level, and the gain `ccdpsf gain` estimates from these frames (41 +- 6.5
  // e-/ADU, single-frame photon transfer) with a read noise of half an ADU (what the 1.5 % of
  // dark pixels reading 1 ADU suggest). They set chi^2 and the intervals, not where the spot
  // is.
  static std::string Flags() {
    return "--pixel_um=4.65 --bias_adu=0 --gain_e_per_adu=41 --read_noise_e=20 ";
  }
};

TEST_F(RealFrames, TheCompactSpotIsFittedNotTheBrightArc) {
  std::string output;
  const json fit = Fit("real03", Flags() + "--exptime_s=0.3 " + File("0.3"), &output);
  ASSERT_TRUE(fit.is_object()) << output;
  const json& spot = fit["exposures"][0]["calibration"]["spot"];
  // The brightest pixel of the frame (249 ADU at (684, 440)) lies on a caustic arc; the
  // pinhole's image is the compact, isolated source at (644, 468).
  EXPECT_EQ(spot["peak_px"], json({644, 468})) << spot.dump();
  EXPECT_EQ(spot["source"], "found");
  bool arc_reported = false;
  for (const json& c : spot["candidates"]) {
    if (c["peak_px"] == json({684, 440})) arc_reported = c["note"] != "chosen";
  }
  EXPECT_TRUE(arc_reported) << spot["candidates"].dump();
  // Every value the headers lack is recorded with the flag that gave it.
  const json& meta = fit["exposures"][0]["calibration"]["metadata"];
  for (const char* q : {"pixel_um", "gain_e_per_adu", "read_noise_e", "bias_adu", "exptime_s"}) {
    EXPECT_EQ(meta[q]["source"], std::string("flag --") + q) << q;
  }
  EXPECT_EQ(meta["wavelength_nm"]["source"], "unknown");
  // The black level clipped at 0: the dark pixels are censored, not fitted as zeros.
  EXPECT_GT(fit["exposures"][0]["censored_pixels"].get<int>(), 300);
  // The spot is narrower than a pixel: whatever the verdict, it is not invalid.
  EXPECT_NE(fit["quality"]["verdict"], "invalid") << fit["quality"].dump(1);
}

TEST_F(RealFrames, SaturatedAndCompressedFramesAreNotOk) {
  // Fitted separately, the ten exposure times (a manifest gives them) are checked as a
  // series: from 0.5 s on the peak holds 11-30 % less of the light than at 0.1-0.3 s and sits
  // within 10 % of the 8-bit full scale. At 0.4 s the deficit is 4 %, a few sd of the counting
  // noise depending on the gain (3 sd at 10 e-/ADU): flagged or not with the gain, so not
  // asserted here.
  const std::string dir = Fresh("real_manifest");
  {
    std::ofstream csv(dir + "/frames.csv");
    csv << "file,exptime_s\n";
    for (const char* t : {"0.1", "0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "0.8", "0.9", "1.0"}) {
      csv << File(t) << "," << t << "\n";
    }
  }
  const std::string out = Fresh("real_series");
  std::string output;
  ASSERT_EQ(RunCcdpsf("fit --nomcmc --out=" + out + " --manifest=" + dir + "/frames.csv " + Flags(),
                      &output),
            0)
      << output;
  for (const char* t : {"0.1", "0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "0.8", "0.9", "1.0"}) {
    const json fit = ReadJson(out + "/pose_de_" + t + "s_20micron/fit.json");
    ASSERT_TRUE(fit.is_object()) << t;
    const std::set<std::string> reasons = Codes(fit, "reasons");
    const double time = std::atof(t);
    if (time >= 0.5) {
      EXPECT_NE(fit["quality"]["verdict"], "ok") << t;
      EXPECT_TRUE(reasons.count("compressed_peak")) << t << fit["quality"].dump(1);
      EXPECT_TRUE(reasons.count("near_full_scale")) << t << fit["quality"].dump(1);
    } else if (time <= 0.3) {
      EXPECT_FALSE(reasons.count("compressed_peak")) << t << fit["quality"].dump(1);
      EXPECT_FALSE(reasons.count("near_full_scale")) << t << fit["quality"].dump(1);
    }
  }
}

TEST_F(RealFrames, JointFitOverDifferentExposureTimes) {
  // 0.1, 0.2 and 0.3 s do not share one flux: the tool chooses the flux model from the data,
  // says which, and the three fluxes follow the exposure times.
  std::string output;
  const json fit = Fit("real_joint",
                       "--joint " + Flags() + "--manifest=" + [] {
                         const std::string dir = Fresh("real_joint_manifest");
                         std::ofstream csv(dir + "/m.csv");
                         csv << "file,exptime_s\n"
                             << File("0.1") << ",0.1\n"
                             << File("0.2") << ",0.2\n"
                             << File("0.3") << ",0.3\n";
                         return dir + "/m.csv";
                       }(),
                       &output);
  ASSERT_TRUE(fit.is_object()) << output;
  const std::string flux = fit["model"]["flux"];
  EXPECT_TRUE(flux == "per_exposure" || flux == "exptime_scaled") << flux;
  EXPECT_NE(output.find("note: flux: " + flux), std::string::npos) << output;
  // Exposure k's flux over exposure 0's follows t_k / t_0 = 2, 3 within 15 % (shutter and
  // lamp; the 8-bit wings are faint).
  const json& e = fit["exposures"];
  EXPECT_NEAR(e[1]["flux_scale"].get<double>(), 2.0, 0.3);
  EXPECT_NEAR(e[2]["flux_scale"].get<double>(), 3.0, 0.45);
  // The same file twice is one exposure, not two.
  EXPECT_TRUE(Fit("real_twice", "--joint " + Flags() + File("0.1") + " " + File("0.1"), &output)
                  .is_null());
  EXPECT_NE(output.find("given twice"), std::string::npos) << output;
}

TEST_F(RealFrames, AllTenJointlyWithoutExposureTimes) {
  // Nothing says the frames differ in light: no exposure times, and the 8-bit wings are too
  // faint to compare. A shared flux there made the 0.1 s spot's whole core an outlier, masked
  // it and failed the run ("no spot to fit"). The spots' cores (76 to 423 ADU in their 5 x 5
  // boxes) show the light differs: a flux each, and a run that completes with a verdict.
  std::string files;
  for (const char* t : {"0.1", "0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "0.8", "0.9", "1.0"}) {
    files += File(t) + " ";
  }
  std::string output;
  const json fit = Fit("real_ten", "--joint --nomcmc " + Flags() + files, &output);
  ASSERT_TRUE(fit.is_object()) << output;
  EXPECT_EQ(fit["model"]["flux"], "per_exposure") << output;
  EXPECT_NE(output.find("5 x 5 cores"), std::string::npos) << output;
  // The 1.0 s spot holds several times the 0.1 s spot's light (its core compressed: not 10x).
  EXPECT_GT(fit["exposures"][9]["flux_scale"].get<double>(), 2.5);
  // Frames from 0.5 s on sit near the 8-bit full scale: not ok.
  EXPECT_NE(fit["quality"]["verdict"], "ok");
  // Told to share one flux, the run still completes: the outlier masking stops before it
  // would mask the faint spot away, and the verdict says why. (At one electron per ADU and of
  // read noise, where the 0.1 s spot's core is its only pixel above 5 sd; at 41 e-/ADU the
  // masking ends earlier and the verdict is a gross misfit.)
  const json shared = Fit("real_ten_shared",
                          "--joint --nomcmc --flux=shared --pixel_um=4.65 --bias_adu=0 "
                          "--gain_e_per_adu=1 --read_noise_e=1 " +
                              files,
                          &output);
  ASSERT_TRUE(shared.is_object()) << output;
  EXPECT_TRUE(Codes(shared, "reasons").count("outlier_masking_stopped"))
      << shared["quality"].dump(1);
  EXPECT_NE(shared["quality"]["verdict"], "ok");
}

}  // namespace
}  // namespace ccdpsf
