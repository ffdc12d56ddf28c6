// `--ptc=DIR/ptc.json` on `fit` and `trend` given what is not a usable prior: one line naming
// the problem, exit code 1, and no --out folder made (the prior is checked before any input
// is read).
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::RunResult;
using testing_support::Touch;

// A ptc.json as `ccdpsf ptc --max_lag=1` writes its "a" and "a_covariance" (lags 00, 10, 01,
// 11; a_00 negative, the others positive, a diagonal covariance).
json GoodPtc() {
  const std::vector<std::string> lags = {"a_00", "a_10", "a_01", "a_11"};
  const std::vector<double> median = {-1.2e-6, 1.5e-7, 2.0e-7, 6.0e-8};
  const std::vector<double> sd = {5e-8, 2e-8, 2e-8, 1e-8};
  json a = json::object(), matrix = json::array();
  for (size_t k = 0; k < lags.size(); ++k) {
    a[lags[k]] = {{"median", median[k]}, {"sd", sd[k]},
                  {"lo68", median[k] - sd[k]}, {"hi68", median[k] + sd[k]}};
    json row = json::array();
    for (size_t l = 0; l < lags.size(); ++l) row.push_back(k == l ? sd[k] * sd[k] : 0.0);
    matrix.push_back(row);
  }
  return {{"a", a},
          {"a_covariance", {{"names", lags}, {"matrix", matrix}, {"unit", "1/e-^2"}}}};
}

int Lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

TEST(PtcPriorCli, BadPriorsAreRefusedWithOneLineBeforeAnyOutput) {
  const std::string dir = FreshDir("ptc_prior", "bad");
  // The spot file is never read: every case fails on its options first.
  const std::string spot = dir + "/spot.fits";
  Touch(spot);
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir + "/" + name) << text;
    return dir + "/" + name;
  };
  const std::string good = write("good.json", GoodPtc().dump());
  json no_a11 = GoodPtc();
  no_a11["a"].erase("a_11");
  json null_sd = GoodPtc();
  null_sd["a"]["a_10"]["sd"] = nullptr;  // ptc.json's NaN: the flats did not measure it
  json negative_sd = GoodPtc();
  negative_sd["a"]["a_01"]["sd"] = -2e-8;
  json not_pd = GoodPtc();  // a correlation of 1.5 between a_10 and a_01
  not_pd["a_covariance"]["matrix"][1][2] = not_pd["a_covariance"]["matrix"][2][1] = 1.5 * 4e-16;
  json edited_sd = GoodPtc();  // an sd that is not the covariance's
  edited_sd["a"]["a_11"]["sd"] = 3e-8;
  struct Case {
    std::string args, message;
  };
  const std::string fit = "fit --nomcmc --effects=boundary_shift ";
  const std::vector<Case> cases = {
      {fit + "--ptc=" + dir + "/missing.json", "cannot read --ptc file"},
      {fit + "--ptc=" + write("text.json", "gain 3.1\n"), "is not a ptc.json"},
      {fit + "--ptc=" + write("other.json", R"({"gain_e_per_adu": {"median": 3.1}})"),
       "is not a ptc.json (`ccdpsf ptc` writes one): no \"a\" object"},
      {fit + "--ptc=" + write("no_a11.json", no_a11.dump()), "no \"a.a_11\""},
      {fit + "--ptc=" + write("null_sd.json", null_sd.dump()),
       "a.a_10.sd must be a positive finite number [1/e-] (got null)"},
      {fit + "--ptc=" + write("negative_sd.json", negative_sd.dump()),
       "a.a_01.sd must be a positive finite number"},
      {fit + "--ptc=" + write("not_pd.json", not_pd.dump()), "is not positive definite"},
      {fit + "--ptc=" + write("edited_sd.json", edited_sd.dump()),
       "a_covariance's variance of a_11"},
      {"fit --nomcmc --ptc=" + good,
       "--ptc is a prior on boundary_shift's a_ij: add --effects=boundary_shift"},
      {"fit --nomcmc --effects=serial_cti --ptc=" + good, "add --effects=boundary_shift"},
      {fit + "--sampling=pixel_centre --ptc=" + good, "'boundary_shift' needs integrated sampling"},
      {"trend --nomcmc --ptc=" + good, "add --effects=boundary_shift"},
      {"trend --nomcmc --effects=boundary_shift --ptc=" + write("trend_null.json", null_sd.dump()),
       "a.a_10.sd must be a positive finite number"},
  };
  int n = 0;
  for (const Case& c : cases) {
    const std::string out = dir + "/out_" + std::to_string(n++);
    const RunResult r = RunCcdpsf(c.args + " --out=" + out + " " + spot);
    EXPECT_EQ(r.exit_code, 1) << c.args << "\n" << r.output;
    EXPECT_NE(r.output.find(c.message), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_EQ(Lines(r.output), 1) << c.args << "\n" << r.output;
    EXPECT_FALSE(fs::exists(out)) << c.args;
  }
}

}  // namespace
}  // namespace ccdpsf
