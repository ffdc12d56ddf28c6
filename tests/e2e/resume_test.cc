// Kill and resume, end to end: `fit` and `trend` are killed with SIGKILL part way, rerun with
// --resume into the same folder, and must end with exactly the numbers of a run never
// interrupted (the chain bit for bit; trend.json but for the seconds each group took).
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using testing_support::DemoSet;
using testing_support::FreshDir;
using testing_support::RunAndKill;
using testing_support::RunCcdpsf;
using testing_support::RunResult;

std::string Bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(Resume, AKilledFitResumesToTheChainOfAnUninterruptedRun) {
  const std::string dir = FreshDir("resume", "fit");
  // Never converged (target_ess far out of reach), so every run takes all 3000 steps, with a
  // checkpoint at each convergence check.
  const std::string options = "--walkers=32 --max_steps=3000 --target_ess=1e6 --seed=5 "
                              "--checkpoint_s=0 " + DemoSet() + "/exposure_000.fits ";
  ASSERT_EQ(RunCcdpsf("fit --out=" + dir + "/whole " + options).exit_code, 0);

  const std::string checkpoint = dir + "/.killed.ccdpsf-partial/checkpoints/fit.bin";
  ASSERT_TRUE(RunAndKill("fit --out=" + dir + "/killed " + options,
                         [&] { return fs::exists(checkpoint); }));
  EXPECT_FALSE(fs::exists(dir + "/killed"));  // nothing appears before the run completes
  const RunResult r = RunCcdpsf("fit --resume --out=" + dir + "/killed " + options);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("the MCMC resumed from its checkpoint at step"), std::string::npos)
      << r.output;
  EXPECT_EQ(Bytes(dir + "/killed/chain.fits"), Bytes(dir + "/whole/chain.fits"));
  EXPECT_FALSE(fs::exists(dir + "/killed/checkpoints"));
  EXPECT_FALSE(fs::exists(dir + "/.killed.ccdpsf-partial"));

  // Without --resume a rerun starts over (and still ends with the same chain).
  ASSERT_TRUE(RunAndKill("fit --out=" + dir + "/again " + options,
                         [&] { return fs::exists(dir + "/.again.ccdpsf-partial/checkpoints/fit.bin"); }));
  const RunResult fresh = RunCcdpsf("fit --out=" + dir + "/again " + options);
  ASSERT_EQ(fresh.exit_code, 0) << fresh.output;
  EXPECT_EQ(fresh.output.find("resumed"), std::string::npos) << fresh.output;
  EXPECT_EQ(Bytes(dir + "/again/chain.fits"), Bytes(dir + "/whole/chain.fits"));
}

// trend.json with the seconds each group took left out (the only numbers a rerun changes).
nlohmann::json WithoutSeconds(nlohmann::json j) {
  if (j.is_object()) {
    j.erase("seconds");
    for (auto& [key, value] : j.items()) value = WithoutSeconds(value);
  } else if (j.is_array()) {
    for (auto& value : j) value = WithoutSeconds(value);
  }
  return j;
}

TEST(Resume, AKilledTrendKeepsItsFinishedGroups) {
  const std::string dir = FreshDir("resume", "trend");
  ASSERT_EQ(RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) +
                      "/campaign_tests_tiny.json --out=" + dir + "/data")
                .exit_code,
            0);
  std::ofstream(dir + "/fit.json") << R"({"mcmc": {"target_ess": 100, "min_tau_multiple": 20}})";
  const std::string options = "--sampling=pixel_centre --threads=1 --config=" + dir +
                              "/fit.json " + dir + "/data";
  ASSERT_EQ(RunCcdpsf("trend --out=" + dir + "/whole " + options).exit_code, 0);

  const std::string store = dir + "/.killed.ccdpsf-partial/store";
  auto finished = [&] {
    int n = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(store, ec)) n += e.path().extension() == ".json";
    return n >= 2;
  };
  ASSERT_TRUE(RunAndKill("trend --out=" + dir + "/killed " + options, finished));
  const RunResult r = RunCcdpsf("trend --resume --out=" + dir + "/killed " + options);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int kept = 0;
  for (size_t at = 0; (at = r.output.find("kept from the interrupted run", at)) != std::string::npos;
       ++at) {
    ++kept;
  }
  EXPECT_GE(kept, 2) << r.output;
  EXPECT_LT(kept, 4) << r.output;
  std::ifstream a(dir + "/whole/trend.json"), b(dir + "/killed/trend.json");
  EXPECT_EQ(WithoutSeconds(nlohmann::json::parse(b)), WithoutSeconds(nlohmann::json::parse(a)));
  EXPECT_FALSE(fs::exists(dir + "/killed/store"));
  EXPECT_TRUE(fs::exists(dir + "/killed/groups"));
}

}  // namespace
}  // namespace ccdpsf
