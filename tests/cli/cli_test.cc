// End-to-end tests of the ccdpsf binary: the interface users script against.
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>

#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/quality.h"
#include "fitsio.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"
#include "support/slow_test.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;

using testing_support::RunCcdpsf;
using testing_support::RunResult;

// Per process: ctest runs tests in parallel processes, each of which simulates its own set.
std::string Fresh(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_cli_" +
                          std::to_string(static_cast<long>(::getpid())) + "_" + name;
  fs::remove_all(dir);
  return dir;
}

int Lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

// Simulates the demo-like set once for all tests in this file.
const std::string& SimulatedSet() {
  static const std::string dir = [] {
    const std::string d = Fresh("sim");
    const RunResult r =
        RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) + "/demo_simulation.json --out=" + d);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return d;
  }();
  return dir;
}

// A pillbox defocus of R = 1 px at the paper's signal identifies the CCD widths at one focus
// (docs/trust.md: +-0.004 px over 20 seeds), and fit.json and report.md say so. The truth
// must lie in the 99.7 % intervals (a failure here at 3 sd is a real defect: it held for all
// 20 seeds of the measurement).
TEST(Cli, PillboxFitSaysTheCcdWidthsAreIdentified) {
  CCDPSF_RELEASE_ONLY();  // a fit with MCMC; see Cli.SeparateFitsGetOneFolderEach for the sanitized
  // run
  const std::string sim = Fresh("pillbox_sim"), out = Fresh("pillbox_fit");
  nlohmann::json config;
  {
    std::ifstream in(std::string(CCDPSF_TESTDATA) + "/demo_simulation.json");
    config = nlohmann::json::parse(in);
  }
  config["model"]["defocus"] = {{"kind", "pillbox"}, {"radius_px", 1.0}};
  config["exposures"] = nlohmann::json::array({config["exposures"][0]});
  fs::create_directories(sim + "_config");
  const std::string config_path = sim + "_config/sim.json";
  std::ofstream(config_path) << config.dump();
  ASSERT_EQ(RunCcdpsf("simulate --config=" + config_path + " --out=" + sim).exit_code, 0);
  const RunResult r = RunCcdpsf("fit --defocus=pillbox --target_ess=300 --seed=3 --out=" + out +
                                " " + sim + "/exposure_000.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(out + "/fit.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_TRUE(j["identifiability"]["null_directions"].empty());
  ASSERT_TRUE(j["identifiability"].contains("ccd_widths")) << j["identifiability"].dump();
  EXPECT_EQ(j["identifiability"]["ccd_widths"]["verdict"], "identified");
  EXPECT_LT(j["identifiability"]["ccd_widths"]["relative_half_width"].get<double>(), 0.1);
  const std::pair<const char*, double> truths[] = {
      {"ccd_sigma_x_px", 0.291}, {"ccd_sigma_y_px", 0.335}, {"defocus_radius_px", 1.0}};
  for (const auto& [name, truth] : truths) {
    EXPECT_LE(j["parameters"][name]["lo997"].get<double>(), truth) << name;
    EXPECT_GE(j["parameters"][name]["hi997"].get<double>(), truth) << name;
  }
  std::ifstream report(out + "/report.md");
  const std::string md((std::istreambuf_iterator<char>(report)), std::istreambuf_iterator<char>());
  EXPECT_NE(md.find("## The CCD kernel at one focus"), std::string::npos);
  EXPECT_NE(md.find("CCD widths are **identified**"), std::string::npos);
}

TEST(Cli, HelpListsCommandsAndOptions) {
  RunResult r = RunCcdpsf("help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.output.find("simulate"), std::string::npos);
  EXPECT_NE(r.output.find("fit"), std::string::npos);
  r = RunCcdpsf("fit --help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.output.find("--joint"), std::string::npos);
  EXPECT_NE(r.output.find("--sampling"), std::string::npos);
}

// Every effect the catalogue says can be fitted (`ccdpsf effects --json`, "fittable") is named
// in the --effects help of fit, trend and grid (grid leaves out brighter_fatter, which it
// refuses: one setting is one intensity), and none that cannot be fitted.
TEST(Cli, EffectsHelpNamesEveryFittableEffect) {
  const RunResult catalogue = RunCcdpsf("effects --json");
  ASSERT_EQ(catalogue.exit_code, 0) << catalogue.output;
  const nlohmann::json effects = nlohmann::json::parse(catalogue.output);
  ASSERT_GE(effects.size(), 10u);
  for (const char* command : {"fit", "trend", "grid"}) {
    SCOPED_TRACE(command);
    const RunResult help = RunCcdpsf(std::string(command) + " --help");
    ASSERT_EQ(help.exit_code, 0);
    const size_t at = help.output.find("--effects");
    ASSERT_NE(at, std::string::npos);
    // The flag's text: up to the next flag.
    const std::string text = help.output.substr(at, help.output.find("\n  --", at + 1) - at);
    for (const nlohmann::json& e : effects) {
      const std::string name = e["name"].get<std::string>();
      const bool listed = text.find(" " + name + ",") != std::string::npos ||
                          text.find("(" + name + ",") != std::string::npos ||
                          text.find(" " + name + ";") != std::string::npos;
      const bool expected = e["fittable"].get<bool>() &&
                            !(std::string(command) == "grid" && name == "brighter_fatter");
      EXPECT_EQ(listed, expected) << name << " in: " << text;
    }
  }
}

TEST(Cli, FitWritesTheDocumentedOutputs) {
  CCDPSF_RELEASE_ONLY();  // a fit with MCMC and pictures; see Cli.SeparateFitsGetOneFolderEach for
  // the sanitized run
  const std::string out = Fresh("fit_mcmc");
  const RunResult r = RunCcdpsf("fit --out=" + out +
                          " --max_steps=600 --target_ess=100 --seed=4 " + SimulatedSet() +
                          "/exposure_000.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"fit.json", "residuals.fits", "chain.fits", "run.json", "report.md",
                        "residuals.gp", "corner.gp"}) {
    EXPECT_TRUE(fs::exists(out + "/" + f)) << f;
  }
  std::ifstream in(out + "/fit.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  for (const char* p : {"flux_e", "airy_radius_px", "defocus_sigma_px", "ccd_sigma_x_px",
                        "ccd_sigma_y_px", "x_px_0", "y_px_0"}) {
    ASSERT_TRUE(j["parameters"].contains(p)) << p;
    for (const char* field : {"map", "laplace_sd", "median", "lo68", "hi68", "lo997", "hi997"}) {
      EXPECT_TRUE(j["parameters"][p].contains(field)) << p << "." << field;
    }
  }
  for (const char* d : {"fwhm_um", "fwhm_x_um", "fwhm_y_um", "r2_px2", "ellipticity",
                        "total_sigma_x_px", "total_sigma_y_px", "peak_e"}) {
    EXPECT_TRUE(j["derived"].contains(d)) << d;
  }
  EXPECT_TRUE(j["identifiability"]["null_directions"].is_array());
  EXPECT_EQ(j["identifiability"]["null_directions"].size(), 1u);
  EXPECT_FALSE(j["identifiability"].contains("ccd_widths"));  // pillbox fits only
  EXPECT_TRUE(j["parameters"]["ccd_sigma_x_px"]["laplace_sd"].is_null());
  for (const char* m : {"walkers", "steps", "acceptance_fraction", "tau", "ess", "converged"}) {
    EXPECT_TRUE(j["mcmc"].contains(m)) << m;
  }
  for (const char* f : {"chi2", "dof", "loglike", "seconds"}) EXPECT_TRUE(j["fit"].contains(f));
  // residuals.fits: DATA/MODEL/RESID/NRESID extensions of 21 x 21 for exposure 0.
  for (const char* ext : {"DATA_0", "MODEL_0", "RESID_0", "NRESID_0"}) {
    fitsfile* f = nullptr;
    int status = 0;
    const std::string name = out + "/residuals.fits[" + ext + "]";
    ASSERT_EQ(fits_open_file(&f, name.c_str(), READONLY, &status), 0) << ext;
    long size[2] = {0, 0};
    fits_get_img_size(f, 2, size, &status);
    EXPECT_EQ(size[0], 21);
    EXPECT_EQ(size[1], 21);
    fits_close_file(f, &status);
  }
  // chain.fits: walker, step, log_prob and one column per parameter, walkers x steps rows.
  fitsfile* f = nullptr;
  int status = 0;
  const std::string chain = out + "/chain.fits[CHAIN]";
  ASSERT_EQ(fits_open_file(&f, chain.c_str(), READONLY, &status), 0);
  for (const char* col : {"walker", "step", "log_prob", "flux_e", "ccd_sigma_y_px", "y_px_0"}) {
    int number = 0;
    EXPECT_EQ(fits_get_colnum(f, CASEINSEN, const_cast<char*>(col), &number, &status), 0)
        << col;
    status = 0;
  }
  long rows = 0;
  fits_get_num_rows(f, &rows, &status);
  EXPECT_EQ(rows, j["mcmc"]["walkers"].get<long>() * j["mcmc"]["steps"].get<long>());
  // The run's keywords in the table's own header (astropy's Table.read keeps only those).
  auto key = [&](const char* name) {
    long value = -1;
    int s = 0;
    fits_read_key(f, TLONG, name, &value, nullptr, &s);
    return s == 0 ? value : -1;
  };
  EXPECT_EQ(key("BURNIN"), j["mcmc"]["burn_in"].get<long>());
  EXPECT_EQ(key("WALKERS"), j["mcmc"]["walkers"].get<long>());
  EXPECT_EQ(key("NSTEPS"), j["mcmc"]["steps"].get<long>());
  EXPECT_EQ(key("NPARAM"), static_cast<long>(j["parameters"].size()));
  // Units in TUNITn, named after the column's suffix.
  auto unit_of = [&](const char* col) {
    int number = 0, s = 0;
    fits_get_colnum(f, CASEINSEN, const_cast<char*>(col), &number, &s);
    char card[FLEN_VALUE] = "";
    const std::string keyword = "TUNIT" + std::to_string(number);
    fits_read_key(f, TSTRING, keyword.c_str(), card, nullptr, &s);
    return s == 0 ? std::string(card) : std::string("(none)");
  };
  EXPECT_EQ(unit_of("flux_e"), "electron");
  EXPECT_EQ(unit_of("x_px_0"), "pix");
  EXPECT_EQ(unit_of("fwhm_um"), "um");
  EXPECT_EQ(unit_of("r2_px2"), "pix2");
  EXPECT_EQ(unit_of("log_prob"), "(none)");
  // Derived draws beside the parameters: recomputed here from the closed forms of the
  // Gaussian CCD kernel (FWHM = 2 sqrt(2 ln 2) sigma x pixel; total width = CCD width and
  // Gaussian defocus in quadrature), to rounding (1e-12 relative).
  auto column = [&](const char* col) {
    int number = 0, s = 0;
    fits_get_colnum(f, CASEINSEN, const_cast<char*>(col), &number, &s);
    std::vector<double> v(rows);
    fits_read_col(f, TDOUBLE, number, 1, 1, rows, nullptr, v.data(), nullptr, &s);
    EXPECT_EQ(s, 0) << col;
    return v;
  };
  const double pixel_um = j["exposures"][0]["pixel_um"].get<double>();
  const double k = 2.0 * std::sqrt(2.0 * std::log(2.0));
  const std::vector<double> sx = column("ccd_sigma_x_px"), d = column("defocus_sigma_px"),
                            fx = column("fwhm_x_um"), tx = column("total_sigma_x_px");
  for (long row = 0; row < rows; row += std::max(1L, rows / 50)) {
    EXPECT_NEAR(fx[row], k * sx[row] * pixel_um, 1e-12 * fx[row]) << "row " << row;
    EXPECT_NEAR(tx[row], std::hypot(sx[row], d[row]), 1e-12 * tx[row]) << "row " << row;
  }
  fits_close_file(f, &status);
  // fitsverify (HEASARC's FITS validator) finds neither errors nor warnings in the tables
  // and images written.
  if (std::system("command -v fitsverify > /dev/null 2>&1") != 0) {
    ADD_FAILURE() << "fitsverify is not installed (tools/bootstrap.sh installs it)";
  } else {
    for (const char* file : {"chain.fits", "residuals.fits"}) {
      std::string report;
      const int code = testing_support::Shell("fitsverify -q '" + out + "/" + file + "'", &report);
      EXPECT_EQ(code, 0) << file << ": " << report;
      // With -q fitsverify prints "verification OK" only when it found no warning and no error.
      EXPECT_NE(report.find("verification OK"), std::string::npos) << file << ": " << report;
    }
  }
  // fit.json: the Laplace covariance of the constrained parameters, symmetric, its diagonal
  // the squares of their laplace_sd.
  const nlohmann::json& cov = j["covariance"];
  ASSERT_TRUE(cov["names"].is_array());
  ASSERT_EQ(cov["matrix"].size(), cov["names"].size());
  // flux, airy radius and the two positions at least (at one focus the CCD widths may be
  // prior-bound and so left out)
  EXPECT_GE(cov["names"].size(), 4u);
  for (size_t a = 0; a < cov["names"].size(); ++a) {
    const std::string name = cov["names"][a];
    const double sd = j["parameters"][name]["laplace_sd"].get<double>();
    EXPECT_NEAR(cov["matrix"][a][a].get<double>(), sd * sd, 1e-9 * sd * sd) << name;
    for (size_t b = 0; b < a; ++b) {
      EXPECT_EQ(cov["matrix"][a][b].get<double>(), cov["matrix"][b][a].get<double>());
    }
  }
  std::ifstream run(out + "/run.json");
  const nlohmann::json rj = nlohmann::json::parse(run);
  EXPECT_EQ(rj["seed"], 4);
  EXPECT_TRUE(rj["software"].contains("ceres"));
}

TEST(Cli, SameSeedSameResults) {
  CCDPSF_RELEASE_ONLY();  // two fits with MCMC; the fit command runs sanitized in
  // Cli.BadInputGivesOneLineAndNoResults and Cli.SeparateFitsGetOneFolderEach
  const std::string a = Fresh("seed_a"), b = Fresh("seed_b");
  const std::string common = " --max_steps=300 --target_ess=50 --seed=9 " + SimulatedSet() +
                             "/exposure_001.fits";
  ASSERT_EQ(RunCcdpsf("fit --out=" + a + common).exit_code, 0);
  ASSERT_EQ(RunCcdpsf("fit --out=" + b + common).exit_code, 0);
  std::ifstream ia(a + "/fit.json"), ib(b + "/fit.json");
  nlohmann::json ja = nlohmann::json::parse(ia), jb = nlohmann::json::parse(ib);
  // Timings differ run to run; everything else must not.
  for (auto* j : {&ja, &jb}) {
    (*j)["fit"].erase("seconds");
    (*j)["fit"].erase("map_seconds");
    (*j)["mcmc"].erase("seconds");
  }
  EXPECT_EQ(ja, jb);
}

TEST(Cli, SeparateFitsGetOneFolderEach) {
  const std::string out = Fresh("separate");
  const RunResult r = RunCcdpsf("fit --nomcmc --out=" + out + " " + SimulatedSet() +
                          "/exposure_000.fits " + SimulatedSet() + "/exposure_001.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(out + "/exposure_000/fit.json"));
  EXPECT_TRUE(fs::exists(out + "/exposure_001/fit.json"));
}

// The policy of fit --plots and trend --group_plots: flagged draws where the verdict is not ok.
TEST(Pictures, FlaggedDrawsWhereTheVerdictIsNotOk) {
  Quality ok, noted, suspect, invalid;
  noted.Add("a_note", Severity::kNote, "just so you know");
  suspect.Add("chi2_high", Severity::kSuspect, "misfit");
  invalid.Add("gross_misfit", Severity::kInvalid, "not this source");
  EXPECT_FALSE(fit::DrawsPictures(fit::Pictures::kFlagged, ok));
  EXPECT_FALSE(fit::DrawsPictures(fit::Pictures::kFlagged, noted));
  EXPECT_TRUE(fit::DrawsPictures(fit::Pictures::kFlagged, suspect));
  EXPECT_TRUE(fit::DrawsPictures(fit::Pictures::kFlagged, invalid));
  for (const Quality* q : {&ok, &noted, &suspect, &invalid}) {
    EXPECT_TRUE(fit::DrawsPictures(fit::Pictures::kAll, *q));
    EXPECT_FALSE(fit::DrawsPictures(fit::Pictures::kNone, *q));
  }
  fit::Pictures parsed = fit::Pictures::kAll;
  for (const fit::Pictures p :
       {fit::Pictures::kAll, fit::Pictures::kFlagged, fit::Pictures::kNone}) {
    ASSERT_TRUE(fit::ParsePictures(ToString(p), &parsed));
    EXPECT_EQ(parsed, p);
  }
  EXPECT_FALSE(fit::ParsePictures("some", &parsed));
}

// fit --plots: with flagged, a report's pictures are drawn exactly where its verdict is not
// ok, and every report keeps the data and scripts and says how to draw them; none draws
// nothing; a wrong value is refused in one line before any fitting, with no folder. Separate
// fits of two exposures, residual maps only (--nomcmc), svg (the quickest terminal). Both
// verdicts are ok here; a flagged report drawn through the same policy is checked by
// Pictures.FlaggedDrawsWhereTheVerdictIsNotOk and TrendCli.GroupPicturesAreDrawnWhere...
TEST(Cli, FitDrawsPicturesWhereThePlotsOptionAsks) {
  CCDPSF_RELEASE_ONLY();  // fits with pictures; see Cli.SeparateFitsGetOneFolderEach for the
  // sanitized run
  if (!GnuplotAvailable()) GTEST_SKIP() << "gnuplot is not installed";
  const std::string files =
      " " + SimulatedSet() + "/exposure_000.fits " + SimulatedSet() + "/exposure_001.fits";
  for (const std::string mode : {"flagged", "none"}) {
    const std::string out = Fresh("plots_" + mode);
    const RunResult r =
        RunCcdpsf("fit --nomcmc --plot_format=svg --plots=" + mode + " --out=" + out + files);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(r.output.find("not made"), std::string::npos) << r.output;
    for (const std::string name : {"exposure_000", "exposure_001"}) {
      const std::string dir = out + "/" + name;
      std::ifstream in(dir + "/fit.json");
      const nlohmann::json j = nlohmann::json::parse(in);
      const bool drawn = mode == "flagged" && j["quality"]["verdict"] != "ok";
      EXPECT_TRUE(fs::exists(dir + "/residuals.gp")) << dir;
      EXPECT_EQ(fs::exists(dir + "/residuals.svg"), drawn) << dir;
      std::ifstream md_file(dir + "/report.md");
      const std::string md((std::istreambuf_iterator<char>(md_file)),
                           std::istreambuf_iterator<char>());
      EXPECT_EQ(md.find("`gnuplot residuals.gp`") != std::string::npos, !drawn) << md;
      if (!drawn) {
        EXPECT_NE(md.find("fit --plots=" + mode), std::string::npos) << md;
      }
      // Every picture the report links exists (a report once linked pictures never drawn).
      for (size_t at = md.find("]("); at != std::string::npos; at = md.find("](", at + 2)) {
        if (at == 0 || md.rfind("![", at) == std::string::npos) continue;
        const std::string target = md.substr(at + 2, md.find(')', at) - at - 2);
        if (target.find(".svg") == std::string::npos && target.find(".png") == std::string::npos) {
          continue;
        }
        EXPECT_TRUE(fs::exists(dir + "/" + target)) << "links " << target << "\n" << md;
      }
      // The summary line names the pictures only where they were drawn.
      const size_t line = r.output.find("/" + name + "/fit.json");
      ASSERT_NE(line, std::string::npos) << r.output;
      const std::string rest = r.output.substr(line, r.output.find('\n', line) - line);
      EXPECT_EQ(rest.find("plots") != std::string::npos, drawn) << rest;
      EXPECT_NE(rest.find("report.md"), std::string::npos) << rest;
    }
  }
  const std::string bad = Fresh("plots_bad");
  const RunResult r = RunCcdpsf("fit --plots=some --out=" + bad + files);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(Lines(r.output), 1) << r.output;
  EXPECT_NE(r.output.find("--plots must be all, flagged or none"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(bad));
}

TEST(Cli, JointFitSharesThePsf) {
  CCDPSF_RELEASE_ONLY();  // a joint fit with MCMC; see Cli.SeparateFitsGetOneFolderEach for the
  // sanitized run
  const std::string out = Fresh("joint");
  const RunResult r = RunCcdpsf("fit --nomcmc --joint --out=" + out + " " + SimulatedSet() +
                          "/exposure_000.fits " + SimulatedSet() + "/exposure_001.fits " +
                          SimulatedSet() + "/exposure_002.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(out + "/fit.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_TRUE(j["parameters"].contains("x_px_2"));
  EXPECT_FALSE(j["parameters"].contains("x_px_3"));
  EXPECT_EQ(j["exposures"].size(), 3u);
}

// Bad input: a one-line reason, a non-zero exit, and no fit.json.
TEST(Cli, BadInputGivesOneLineAndNoResults) {
  const std::string dir = Fresh("bad");
  fs::create_directories(dir);
  // A frame too small for the stamp, and a frame with no spot. (Frames of different sizes
  // are fine in a joint fit: every stamp is cut to one size. Stamps of different sizes are
  // refused by FitModel::Create, tested in fit_test.cc.)
  Image small(15, 15, 1000.0), flat(48, 48, 1000.0);
  for (size_t q = 0; q < small.size(); ++q) small.data[q] += (q * 7919 % 13);
  small(7, 7) = 40000;
  for (size_t q = 0; q < flat.size(); ++q) flat.data[q] += (q * 7919 % 5);
  FitsHeader h = {{"GAIN", 3.1, ""}, {"RDNOISE", 4.5, ""}, {"BIASLVL", 1000.0, ""}};
  std::string error;
  ASSERT_TRUE(WriteFitsImageU16(dir + "/small.fits", small, h, &error)) << error;
  ASSERT_TRUE(WriteFitsImageU16(dir + "/flat.fits", flat, h, &error)) << error;
  { std::ofstream(dir + "/text.fits") << "not a FITS file"; }
  const std::string good = SimulatedSet() + "/exposure_000.fits";
  struct Case {
    std::string args;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"fit --out=" + dir + "/o1", "at least one FITS file"},
      {"fit --out=" + dir + "/o2 " + dir + "/missing.fits", "missing.fits"},
      {"fit --out=" + dir + "/o3 " + dir + "/text.fits", "not a FITS file"},
      {"fit --out=" + dir + "/o4 " + dir + "/flat.fits", "spot"},
      {"fit --joint --nomcmc --out=" + dir + "/o5 " + good + " " + dir + "/small.fits",
       "too close to the frame edge"},
      {"fit --sampling=exact --out=" + dir + "/o6 " + good, "--sampling"},
      {"fit --noiseless --out=" + dir + "/o7 " + good, "does not apply"},
      {"fit --out=" + dir + "/o8 --config=" + dir + "/missing.json " + good, "missing.json"},
      {"frobnicate", "unknown command"},
  };
  for (const Case& c : cases) {
    const RunResult r = RunCcdpsf(c.args);
    EXPECT_NE(r.exit_code, 0) << c.args;
    EXPECT_NE(r.output.find(c.message), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_EQ(Lines(r.output), 1) << c.args << "\n" << r.output;
  }
  for (const char* o : {"o1", "o2", "o3", "o4", "o5", "o6", "o7", "o8"}) {
    EXPECT_FALSE(fs::exists(dir + "/" + o + "/fit.json")) << o;
  }
}

}  // namespace
}  // namespace ccdpsf
