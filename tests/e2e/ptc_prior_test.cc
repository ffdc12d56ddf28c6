// `fit --effects=boundary_shift --ptc=DIR/ptc.json` as a job: fit.json records the prior and
// the spots against the flats, report.md shows the table, OUT/config.json repeats the run,
// and without --ptc none of it is written. (Three MAP-only fits of one demo exposure with
// boundary_shift, ~10 s: the prior's numbers are checked by tests/unit/gaussian_prior_test.cc.)
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing_support::DemoSet;
using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::RunResult;

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  return json::parse(in, nullptr, false);
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(PtcPrior, FitRecordsThePriorAndTheComparisonAndItsConfigRepeatsIt) {
  const std::string dir = FreshDir("ptc_prior", "fit");
  // The catalogue's coefficients with 20 % sds and a correlation of 0.3 between a_10 and
  // a_01, as `ccdpsf ptc --max_lag=1` lays them out.
  const std::vector<std::string> lags = {"a_00", "a_10", "a_01", "a_11"};
  const std::vector<double> median = {-1.2e-6, 1.5e-7, 2.0e-7, 6.0e-8};
  json a = json::object(), matrix = json::array();
  for (size_t k = 0; k < lags.size(); ++k) {
    const double sd_k = 0.2 * std::fabs(median[k]);
    a[lags[k]] = {{"median", median[k]}, {"sd", sd_k}};
    json row = json::array();
    for (size_t l = 0; l < lags.size(); ++l) {
      const double sd_l = 0.2 * std::fabs(median[l]);
      row.push_back(k == l ? sd_k * sd_k : (k + l == 3 && k * l == 2 ? 0.3 * sd_k * sd_l : 0.0));
    }
    matrix.push_back(row);
  }
  const std::string ptc = dir + "/ptc.json";
  std::ofstream(ptc) << json{{"a", a}, {"a_covariance", {{"names", lags}, {"matrix", matrix}}}};
  const std::string file = DemoSet() + "/exposure_000.fits";
  const std::string common = "fit --nomcmc --plots=none --effects=boundary_shift ";
  const RunResult r = RunCcdpsf(common + "--ptc=" + ptc + " --out=" + dir + "/a " + file);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json fit = ReadJson(dir + "/a/fit.json");
  ASSERT_TRUE(fit.is_object());
  const json& prior = fit["gaussian_prior"];
  EXPECT_EQ(prior["source"], fs::absolute(ptc).lexically_normal().string());
  EXPECT_EQ(prior["parameters"], json({"boundary_shift.a_10", "boundary_shift.a_01",
                                       "boundary_shift.a_11"}));
  EXPECT_EQ(prior["mean"], json({1.5e-7, 2.0e-7, 6.0e-8}));
  EXPECT_DOUBLE_EQ(prior["covariance"][0][1].get<double>(), 0.3 * 0.2 * 1.5e-7 * 0.2 * 2.0e-7);
  EXPECT_EQ(fit["priors"]["boundary_shift.a_10"]["kind"], "truncated_gaussian");
  EXPECT_EQ(fit["priors"]["boundary_shift.a_far"]["kind"], "flat");
  EXPECT_TRUE(fit["fit"]["log_prior"].is_number());
  const json& versus = fit["boundary_shift_vs_flats"];
  for (const char* lag : {"a_10", "a_01", "a_11"}) {
    ASSERT_TRUE(versus.contains(lag)) << versus.dump();
    const json& v = versus[lag];
    EXPECT_EQ(v["flat"]["median"], a[lag]["median"]) << lag;
    EXPECT_EQ(v["spots_and_flats"]["map"], fit["parameters"][std::string("boundary_shift.") + lag]["map"]);
    // One exposure may or may not constrain a coefficient: either the spots' value with the
    // difference in sd, or null with the reason.
    if (v["spot"].is_null()) {
      EXPECT_TRUE(v["spot_unavailable_because"].is_string()) << lag;
      EXPECT_TRUE(v["difference_sd"].is_null()) << lag;
    } else {
      const double spot = v["spot"]["median"], sd = v["spot"]["sd"];
      const double flat = v["flat"]["median"], flat_sd = v["flat"]["sd"];
      EXPECT_NEAR(v["difference_sd"].get<double>(),
                  (spot - flat) / std::sqrt(sd * sd + flat_sd * flat_sd), 1e-12)
          << lag;
    }
  }
  const std::string report = ReadText(dir + "/a/report.md");
  EXPECT_NE(report.find("## boundary_shift: spots against flats"), std::string::npos);
  EXPECT_NE(report.find(fs::absolute(ptc).lexically_normal().string()), std::string::npos);
  const json config = ReadJson(dir + "/a/config.json");
  EXPECT_EQ(config["flags"]["ptc"], fs::absolute(ptc).lexically_normal().string());

  // The same run from its config.json alone.
  const RunResult b =
      RunCcdpsf("fit --config=" + dir + "/a/config.json --out=" + dir + "/b " + file);
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const json fit_b = ReadJson(dir + "/b/fit.json");
  EXPECT_EQ(fit_b["parameters"], fit["parameters"]);
  EXPECT_EQ(fit_b["gaussian_prior"], fit["gaussian_prior"]);
  EXPECT_EQ(fit_b["boundary_shift_vs_flats"], fit["boundary_shift_vs_flats"]);

  // Without --ptc: nothing of it, and flat priors everywhere.
  const RunResult c = RunCcdpsf(common + "--out=" + dir + "/c " + file);
  ASSERT_EQ(c.exit_code, 0) << c.output;
  const json fit_c = ReadJson(dir + "/c/fit.json");
  EXPECT_FALSE(fit_c.contains("gaussian_prior"));
  EXPECT_FALSE(fit_c.contains("boundary_shift_vs_flats"));
  EXPECT_FALSE(fit_c["fit"].contains("log_prior"));
  EXPECT_EQ(fit_c["priors"]["boundary_shift.a_10"]["kind"], "flat");
  EXPECT_EQ(ReadText(dir + "/c/report.md").find("spots against flats"), std::string::npos);
  EXPECT_EQ(ReadJson(dir + "/c/config.json")["flags"]["ptc"], "");
}

}  // namespace
}  // namespace ccdpsf
