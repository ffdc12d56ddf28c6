// The binary on what users get wrong or what their file systems hold: exit codes as the
// README documents them, limits refused with a message, any path the OS accepts.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <algorithm>
#include <string>

#include "ccdpsf/fits_io.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using testing_support::DemoSet;
using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::RunResult;

int Lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}


// README: 1 for bad input, 2 for usage errors; each with one line on stderr.
TEST(CliReliability, ExitCodesAreAsDocumented) {
  const std::string dir = FreshDir("reliability", "codes");
  const std::string file = DemoSet() + "/exposure_000.fits";
  struct Case {
    std::string args;
    int code;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"", 2, "usage"},
      {"frobnicate", 2, "unknown command"},
      {"fit --bogus=1 " + file, 2, "unknown option --bogus"},
      {"fit --outlier " + file, 2, "did you mean --outliers?"},
      {"fit --wlakers=40 " + file, 2, "did you mean --walkers?"},
      {"fit --efects=halo " + file, 2, "did you mean --effects?"},
      {"fit --walkers=abc --out=" + dir + "/a " + file, 2, "--walkers=abc is not a valid"},
      {"fit --nomcmc --out", 2, "--out needs a value"},
      {"fit --nomcmc " + file, 2, "needs --out"},
      {"fit --out=" + dir + "/b", 2, "at least one FITS file"},
      {"fit --noiseless --out=" + dir + "/c " + file, 2, "does not apply"},
      {"simulate --out=" + dir + "/d", 2, "needs --config"},
      {"trend --out=" + dir + "/e", 2, "needs a campaign"},
      {"diagnose " + file, 2, "needs --out"},
      {"gain", 2, "needs FITS files"},
      {"fit --out=" + dir + "/f " + dir + "/missing.fits", 1, "missing.fits"},
      {"fit --out=" + dir + "/g --walkers=100001 " + file, 1, "--walkers = 100001 is outside"},
      {"fit --out=" + dir + "/h --threads=2000 " + file, 1, "--threads = 2000 is outside"},
      {"fit --out=" + dir + "/i --max_steps=0 " + file, 1, "--max_steps = 0 is outside"},
      {"fit --nomcmc --out=" + DemoSet() + " " + file, 1, "holds the input"},
  };
  for (const Case& c : cases) {
    const RunResult r = RunCcdpsf(c.args);
    EXPECT_EQ(r.exit_code, c.code) << c.args << "\n" << r.output;
    EXPECT_NE(r.output.find(c.message), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_EQ(Lines(r.output), 1) << c.args << "\n" << r.output;
  }
  // Nothing was written for any of them.
  for (const char* sub : {"a", "b", "c", "d", "e", "f", "g", "h", "i"}) {
    EXPECT_FALSE(fs::exists(dir + "/" + sub)) << sub;
  }
}

// A chain too large for memory is refused with the numbers, not attempted.
TEST(CliReliability, AChainBeyondMemoryIsRefused) {
  const std::string dir = FreshDir("reliability", "chain");
  const RunResult r = RunCcdpsf("fit --walkers=50000 --max_steps=10000000 --out=" + dir +
                                "/out " + DemoSet() + "/exposure_000.fits");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("the MCMC chain could reach"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir + "/out"));
}

// simulate with an intensity beyond any lab exposure: refused (it used to write a 0 ADU spot).
TEST(CliReliability, AnAbsurdSimulatedIntensityIsRefused) {
  const std::string dir = FreshDir("reliability", "flux");
  std::ifstream in(std::string(CCDPSF_TESTDATA) + "/demo_simulation.json");
  nlohmann::json config = nlohmann::json::parse(in);
  config["exposures"][0]["flux_e"] = 1e20;
  std::ofstream(dir + "/sim.json") << config.dump();
  const RunResult r = RunCcdpsf("simulate --config=" + dir + "/sim.json --out=" + dir + "/out");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("flux_e = 1e+20 is outside"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir + "/out"));
}

// No MCMC on a source already judged invalid (issue 45: focus-scan frames spent ~25 s sampling
// a source declared not compact): a spot defocused to 2.5 px is no compact source; the fit
// says so, gives the Laplace intervals only, and says why there is no MCMC.
TEST(CliReliability, NoMcmcOnASourceJudgedInvalid) {
  const std::string dir = FreshDir("reliability", "invalid_source");
  std::ifstream in(std::string(CCDPSF_TESTDATA) + "/demo_simulation.json");
  nlohmann::json config = nlohmann::json::parse(in);
  config["model"]["defocus"]["sigma_px"] = 2.5;
  config["exposures"] = nlohmann::json::array({config["exposures"][0]});
  std::ofstream(dir + "/sim.json") << config.dump();
  ASSERT_EQ(RunCcdpsf("simulate --config=" + dir + "/sim.json --out=" + dir + "/sim").exit_code,
            0);
  const RunResult r =
      RunCcdpsf("fit --plots=none --out=" + dir + "/fit " + dir + "/sim/exposure_000.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream f(dir + "/fit/fit.json");
  const nlohmann::json fit = nlohmann::json::parse(f);
  EXPECT_EQ(fit["quality"]["verdict"], "invalid");
  EXPECT_TRUE(fit["mcmc"].is_null());
  EXPECT_EQ(fit["intervals"]["from"], "laplace");
  bool said = false;
  for (const auto& n : fit["quality"]["notes"]) said = said || n["code"] == "mcmc_skipped";
  EXPECT_TRUE(said) << fit["quality"].dump(1);
  EXPECT_NE(r.output.find("no MCMC"), std::string::npos) << r.output;
}

// The terminal on the bundled campaign (issue 46): no "warning:" for good news (the
// through-focus model is a choice, a note), each note's text once however many groups repeat
// it (then counted), and with --quiet only the opening and closing lines of a clean run (and
// fit --quiet its closing line).
TEST(CliReliability, TrendTerminalSaysEachNoteOnceAndQuietIsQuiet) {
  const std::string dir = FreshDir("reliability", "terminal");
  const std::string campaign = std::string(CCDPSF_TESTDATA) + "/campaign_small";
  const RunResult r = RunCcdpsf("trend --nomcmc --nogroup_reports --out=" + dir + "/a " + campaign);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("warning:"), std::string::npos) << r.output;
  std::istringstream lines(r.output);
  std::set<std::string> notes;
  int groups = 0;
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("[", 0) == 0) ++groups;
    if (line.find("note: ") == std::string::npos) continue;
    EXPECT_TRUE(notes.insert(line).second) << "said twice: " << line;
  }
  EXPECT_EQ(groups, 14) << r.output;
  EXPECT_NE(r.output.find("repeated in later groups not shown again"), std::string::npos)
      << r.output;
  const RunResult quiet =
      RunCcdpsf("trend --quiet --nomcmc --nogroup_reports --out=" + dir + "/b " + campaign);
  ASSERT_EQ(quiet.exit_code, 0) << quiet.output;
  EXPECT_EQ(std::count(quiet.output.begin(), quiet.output.end(), '\n'), 2) << quiet.output;
  EXPECT_NE(quiet.output.find("trend of 14 groups"), std::string::npos) << quiet.output;
  // fit --quiet: the closing line alone (the demo set's joint fit notes its flux choice).
  const RunResult fit = RunCcdpsf("fit --joint --quiet --nomcmc --plots=none --out=" + dir +
                                  "/c " + DemoSet() + "/exposure_000.fits " + DemoSet() +
                                  "/exposure_001.fits");
  ASSERT_EQ(fit.exit_code, 0) << fit.output;
  EXPECT_EQ(std::count(fit.output.begin(), fit.output.end(), '\n'), 1) << fit.output;
}

// Non-ASCII names and paths longer than CFITSIO's 1025-byte name buffers, end to end.
TEST(CliReliability, AnyPathTheOsAcceptsWorks) {
  const std::string root = FreshDir("reliability", "paths");
  std::string long_folder = root;
  for (int i = 0; i < 14; ++i) long_folder += "/" + std::string(240, 'd');  // > 3000 bytes
  const std::vector<std::string> folders = {root + "/\xc3\xa9t\xc3\xa9 r\xc3\xa9sultats",
                                            long_folder};
  for (const std::string& folder : folders) {
    SCOPED_TRACE(folder.size());
    fs::create_directories(folder);
    const std::string file = folder + "/\xc3\x9f pot.fits";
    fs::copy_file(DemoSet() + "/exposure_000.fits", file);
    const std::string out = folder + "/r\xc3\xa9sultat";
    const RunResult r = RunCcdpsf("fit --max_steps=200 --target_ess=20 --out='" + out + "' '" +
                                  file + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output.substr(0, 400);
    for (const char* name : {"fit.json", "residuals.fits", "chain.fits", "report.md"}) {
      EXPECT_TRUE(fs::exists(out + "/" + name)) << name;
    }
    // The header records the path in ASCII, percent-encoded, so it can be recovered.
    std::string error;
    const auto residuals = ReadFitsImage(out + "/residuals.fits", "1", &error);
    ASSERT_TRUE(residuals.has_value()) << error;
    const auto source = FindString(residuals->header, "SOURCE");
    ASSERT_TRUE(source.has_value());
    EXPECT_NE(source->find("%C3%9F pot.fits"), std::string::npos) << *source;
  }
}

}  // namespace
}  // namespace ccdpsf
