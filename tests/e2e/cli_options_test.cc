// The binary's options per command (`ccdpsf <command> --help` lists what that command takes,
// with its own description and the default the command really uses), --version, the exit
// codes of README's Usage, terminal summaries that agree with the files, and OUT/config.json
// read back by --config.
#include <cmath>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

using nlohmann::json;
using testing_support::DemoSet;
using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::RunResult;

const std::vector<std::string> kCommands = {"simulate", "fit", "trend", "diagnose", "gain",
                                            "ptc"};

struct HelpOption {
  std::string type;
  std::optional<std::string> default_value;  // nullopt: "no default"
  std::string description;
};

// The options `ccdpsf <command> --help` lists, by name (--help and --version left out).
std::map<std::string, HelpOption> HelpOptions(const std::string& command) {
  const RunResult r = RunCcdpsf(command + " --help");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  std::map<std::string, HelpOption> options;
  std::istringstream lines(r.output);
  std::string line;
  const std::regex head(R"re(^  --(\w+) \((\w+); (?:default "(.*)"|no default)\)$)re");
  std::smatch m;
  std::string last;
  while (std::getline(lines, line)) {
    if (std::regex_match(line, m, head)) {
      last = m[1];
      HelpOption o;
      o.type = m[2];
      if (m[3].matched && line.find("no default") == std::string::npos) o.default_value = m[3];
      options[last] = o;
    } else if (!last.empty() && line.rfind("      ", 0) == 0) {
      options[last].description += line.substr(6);
      last.clear();
    }
  }
  return options;
}

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  return json::parse(in, nullptr, /*allow_exceptions=*/false);
}

// `j` without its timings (keys naming seconds), which differ run to run.
json WithoutTimings(const json& j) {
  if (j.is_array()) {
    json out = json::array();
    for (const json& e : j) out.push_back(WithoutTimings(e));
    return out;
  }
  if (!j.is_object()) return j;
  json out = json::object();
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (it.key().find("seconds") == std::string::npos) out[it.key()] = WithoutTimings(it.value());
  }
  return out;
}

// The command an option foreign to some command is tried on: the first after (cyclically)
// the first command listing it that does not list it; "" if every command lists it.
std::string TriedOn(const std::map<std::string, std::map<std::string, HelpOption>>& help,
                    const std::string& name) {
  const int n = static_cast<int>(kCommands.size());
  int owner = 0;
  while (owner < n && help.at(kCommands[owner]).count(name) == 0) ++owner;
  for (int step = 1; step < n; ++step) {
    const std::string& c = kCommands[(owner + step) % n];
    if (help.at(c).count(name) == 0) return c;
  }
  return "";
}

// A value each option type parses, for probing whether a command accepts the option.
std::string ProbeArgument(const std::string& name, const HelpOption& o) {
  if (o.type == "bool") return "--" + name;
  if (o.type == "string") return "--" + name + "=x";
  return "--" + name + "=1";
}

// Each command lists options written for it, accepts every one it lists, and refuses (exit
// 2, "does not apply") options that only other commands list. The refusal is one table
// look-up whatever the pair, so every foreign option is tried on one command that lacks it
// (the next in kCommands' order after the first that has it), and every command on at least
// one foreign option: ~100 runs where every pair would be ~600, for the same code.
TEST(CliOptions, EachCommandListsAndTakesOnlyItsOwnOptions) {
  std::map<std::string, std::map<std::string, HelpOption>> help;
  for (const std::string& c : kCommands) help[c] = HelpOptions(c);
  ASSERT_FALSE(help["fit"].empty());
  const std::regex per_command_part("(^|; |\\()(simulate|fit|trend|diagnose|gain|ptc)[:,]");
  std::map<std::string, int> foreign_tried;
  for (const std::string& c : kCommands) {
    for (const auto& [name, o] : help[c]) {
      EXPECT_FALSE(o.description.empty()) << c << " --" << name;
      // A description for this command, not one shared by several with per-command parts
      // ("fit: random seed of the MCMC" under diagnose, "fit: ...; trend: ...", "(fit,
      // trend) exptime_scaled").
      EXPECT_FALSE(std::regex_search(o.description, per_command_part))
          << c << " --" << name << ": " << o.description;
      // Accepted: whatever else the run says (no --out, no input), not that the option is
      // foreign or unknown.
      const RunResult r = RunCcdpsf(c + " " + ProbeArgument(name, o));
      EXPECT_EQ(r.output.find("does not apply"), std::string::npos) << c << " --" << name;
      EXPECT_EQ(r.output.find("unknown option"), std::string::npos) << c << " --" << name;
    }
    for (const std::string& other : kCommands) {
      for (const auto& [name, o] : help[other]) {
        if (help[c].count(name) > 0 || TriedOn(help, name) != c) continue;
        ++foreign_tried[c];
        const RunResult r = RunCcdpsf(c + " " + ProbeArgument(name, o));
        EXPECT_EQ(r.exit_code, 2) << c << " --" << name << "\n" << r.output;
        EXPECT_NE(r.output.find("--" + name + " does not apply to '" + c + "'"), std::string::npos)
            << r.output;
      }
    }
  }
  for (const std::string& c : kCommands) EXPECT_GT(foreign_tried[c], 0) << c;
  // gflags' own flags are not options of any command.
  for (const char* flag : {"--flagfile=x", "--helpfull", "--fromenv=seed", "--logtostderr"}) {
    const RunResult r = RunCcdpsf(std::string("fit ") + flag);
    EXPECT_EQ(r.exit_code, 2) << flag << "\n" << r.output;
    EXPECT_NE(r.output.find("unknown option"), std::string::npos) << r.output;
  }
}

// Where a run's config.json (every option it resolved) holds an option's value.
std::optional<json> ResolvedValue(const json& config, const std::string& option) {
  const std::map<std::string, std::vector<std::string>> paths = {
      {"sampling", {"sampling"}},
      {"defocus", {"defocus"}},
      {"likelihood", {"likelihood"}},
      {"joint", {"joint"}},
      {"flux", {"flux"}},
      {"seed", {"mcmc", "seed"}},
      {"walkers", {"mcmc", "walkers"}},
      {"max_steps", {"mcmc", "max_steps"}},
      {"target_ess", {"mcmc", "target_ess"}},
      {"threads", {"mcmc", "threads"}},
      {"mcmc", {"mcmc", "enabled"}},
      {"stamp_size", {"calibration", "stamp_size"}}};
  // trend's --requirements names a file; config.json holds the list it read.
  if (option == "requirements") return std::nullopt;
  std::vector<std::string> path = {"flags", option};
  if (paths.count(option) > 0) path = paths.at(option);
  const json* node = &config;
  for (const std::string& key : path) {
    if (!node->is_object() || !node->contains(key)) return std::nullopt;
    node = &(*node)[key];
  }
  return *node;
}

// Every default the help shows equals the value the run used for an option not given (read
// from the run's config.json), except those in `given`.
void ExpectHelpDefaultsWereUsed(const std::string& command, const json& config,
                                const std::set<std::string>& given) {
  ASSERT_TRUE(config.is_object()) << command;
  int compared = 0;
  for (const auto& [name, o] : HelpOptions(command)) {
    if (!o.default_value || given.count(name) > 0) continue;
    const std::optional<json> used = ResolvedValue(config, name);
    if (!used) continue;  // not a setting of the computation (--out, --resume, ...)
    ++compared;
    const std::string& shown = *o.default_value;
    if (o.type == "bool") {
      EXPECT_EQ(used->get<bool>(), shown == "true") << command << " --" << name;
    } else if (o.type == "string") {
      EXPECT_EQ(used->get<std::string>(), shown) << command << " --" << name;
    } else {
      // The help's text reads back to the number exactly (shortest round-trip form).
      EXPECT_EQ(used->get<double>(), std::stod(shown)) << command << " --" << name;
    }
  }
  EXPECT_GE(compared, 5) << command;
}

TEST(CliOptions, FitUsesTheDefaultsItsHelpShows) {
  const std::string out = FreshDir("options", "fit_defaults");
  const RunResult r =
      RunCcdpsf("fit --nomcmc --out=" + out + " " + DemoSet() + "/exposure_000.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  ExpectHelpDefaultsWereUsed("fit", ReadJson(out + "/config.json"), {"mcmc"});
}

TEST(CliOptions, DiagnoseUsesTheDefaultsItsHelpShowsAndItsConfigRepeatsIt) {
  const std::string dir = FreshDir("options", "diagnose");
  const std::string files = DemoSet() + "/exposure_000.fits " + DemoSet() + "/exposure_001.fits";
  const RunResult a =
      RunCcdpsf("diagnose --max_rounds=1 --predictive_sims=5 --out=" + dir + "/a " + files);
  ASSERT_EQ(a.exit_code, 0) << a.output;
  const json config = ReadJson(dir + "/a/config.json");
  ExpectHelpDefaultsWereUsed("diagnose", config, {"max_rounds", "predictive_sims"});
  EXPECT_EQ(config["flags"]["max_rounds"], 1);
  EXPECT_EQ(config["flags"]["predictive_sims"], 5);
  // The same diagnosis from the config alone.
  const RunResult b =
      RunCcdpsf("diagnose --config=" + dir + "/a/config.json --out=" + dir + "/b " + files);
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const json ja = ReadJson(dir + "/a/diagnose.json"), jb = ReadJson(dir + "/b/diagnose.json");
  ASSERT_TRUE(ja.is_object() && jb.is_object());
  EXPECT_EQ(WithoutTimings(ja), WithoutTimings(jb));
  // The terminal's verdict is the file's.
  EXPECT_NE(a.output.find("\n" + ja["verdict"].get<std::string>() + "; chi2/dof"),
            std::string::npos)
      << a.output;
}

TEST(CliOptions, EveryCommandPrintsTheVersions) {
  const RunResult whole = RunCcdpsf("--version");
  ASSERT_EQ(whole.exit_code, 0);
  const json versions = json::parse(whole.output, nullptr, false);
  ASSERT_TRUE(versions.is_object()) << whole.output;
  EXPECT_TRUE(versions.contains("ccdpsf"));
  for (const std::string& c : kCommands) {
    const RunResult r = RunCcdpsf(c + " --version");
    EXPECT_EQ(r.exit_code, 0) << c;
    EXPECT_EQ(r.output, whole.output) << c;
  }
}

// README: 0 for a completed run whatever its verdict; 3 for a suspect or invalid one with
// --strict; 1 for bad input (out-of-range values); 2 for usage errors. (More cases of 1 and
// 2 are in cli_reliability_test.cc.)
TEST(CliOptions, ExitCodesAreAsDocumented) {
  const std::string dir = FreshDir("options", "codes");
  const std::string file = DemoSet() + "/exposure_001.fits";
  struct Case {
    std::string args;
    int code;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"fit --max_rounds=2 --out=" + dir + "/a " + file, 2, "--max_rounds does not apply to 'fit'"},
      {"gain --seed=2 " + file, 2, "--seed does not apply to 'gain'"},
      {"fit --seed=abc --out=" + dir + "/b " + file, 2, "--seed=abc is not a valid"},
      {"trend --target_ess=many --out=" + dir + "/c " + file, 2, "is not a valid double"},
      {"diagnose --max_rounds=0 --out=" + dir + "/d " + file, 1, "max_rounds must be >= 1"},
      {"diagnose --alpha=2 --out=" + dir + "/e " + file, 1, "alpha must be in (0, 1)"},
      {"fit --target_ess=-1 --out=" + dir + "/f " + file, 1, "--target_ess = "},
  };
  for (const Case& c : cases) {
    const RunResult r = RunCcdpsf(c.args);
    EXPECT_EQ(r.exit_code, c.code) << c.args << "\n" << r.output;
    EXPECT_NE(r.output.find(c.message), std::string::npos) << c.args << "\n" << r.output;
  }
  // A chain stopped long before convergence: the verdict is suspect ("the MCMC did not
  // converge"), which exits 0, or 3 with --strict.
  const std::string short_chain = " --max_steps=100 --walkers=20 --seed=3 " + file;
  const RunResult lenient = RunCcdpsf("fit --out=" + dir + "/lenient" + short_chain);
  EXPECT_EQ(lenient.exit_code, 0) << lenient.output;
  const json fit = ReadJson(dir + "/lenient/fit.json");
  ASSERT_TRUE(fit.is_object());
  const std::string verdict = fit["quality"]["verdict"];
  EXPECT_NE(verdict, "ok");
  // The terminal says the file's verdict and convergence.
  EXPECT_NE(lenient.output.find("; verdict " + verdict), std::string::npos) << lenient.output;
  EXPECT_NE(lenient.output.find(fit["mcmc"]["converged"].get<bool>() ? "MCMC converged"
                                                                     : "MCMC NOT converged"),
            std::string::npos);
  const RunResult strict = RunCcdpsf("fit --strict --out=" + dir + "/strict" + short_chain);
  EXPECT_EQ(strict.exit_code, 3) << strict.output;
}

// fit.json's parameters, every number bit for bit (JSON numbers are written to read back
// exactly).
TEST(CliOptions, ConfigJsonRepeatsAFit) {
  const std::string dir = FreshDir("options", "fit_config");
  const std::string file = DemoSet() + "/exposure_002.fits";
  // Options of each kind: FIT.json keys (seed, walkers, likelihood), "flags" (a metadata
  // value, --nooutliers) and one from a FIT.json given (a prior).
  std::ofstream(dir + "_given.json") << R"({"priors": {"airy_radius_px": [0.2, 1.4]}})";
  const RunResult a =
      RunCcdpsf("fit --out=" + dir + "/a --config=" + dir +
                "_given.json --seed=5 --walkers=16 "
                "--max_steps=300 --likelihood=poisson_normal --pixel_um=12 --nooutliers " +
                file);
  ASSERT_EQ(a.exit_code, 0) << a.output;
  const json config = ReadJson(dir + "/a/config.json");
  ASSERT_TRUE(config.is_object());
  EXPECT_EQ(config["mcmc"]["seed"], 5);
  EXPECT_EQ(config["flags"]["pixel_um"], 12.0);
  EXPECT_EQ(config["flags"]["outliers"], false);
  EXPECT_EQ(config["priors"]["airy_radius_px"], json::array({0.2, 1.4}));
  const RunResult b =
      RunCcdpsf("fit --out=" + dir + "/b --config=" + dir + "/a/config.json " + file);
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const json ja = ReadJson(dir + "/a/fit.json"), jb = ReadJson(dir + "/b/fit.json");
  ASSERT_TRUE(ja.contains("parameters"));
  EXPECT_EQ(ja["parameters"], jb["parameters"]);
  EXPECT_EQ(ja["derived"], jb["derived"]);
  EXPECT_EQ(ja["mcmc"]["walkers"], 16);
  EXPECT_EQ(jb["mcmc"]["walkers"], 16);
  // Its own config is the same file: nothing was lost on the way.
  EXPECT_EQ(ReadJson(dir + "/b/config.json"), config);
  // A flag given outranks the file.
  const RunResult c = RunCcdpsf("fit --nomcmc --seed=6 --out=" + dir + "/c --config=" + dir +
                                "/a/config.json " + file);
  ASSERT_EQ(c.exit_code, 0) << c.output;
  EXPECT_EQ(ReadJson(dir + "/c/config.json")["mcmc"]["seed"], 6);
  // A config's "flags" entry that the command does not have is refused with its name.
  std::ofstream(dir + "_bad.json") << R"({"flags": {"max_rounds": 2}})";
  const RunResult d =
      RunCcdpsf("fit --nomcmc --out=" + dir + "/d --config=" + dir + "_bad.json " + file);
  EXPECT_EQ(d.exit_code, 1) << d.output;
  EXPECT_NE(d.output.find("'flags.max_rounds' is not an option of 'fit'"), std::string::npos)
      << d.output;
}

// Counts of each verdict in a JSON list of objects with "verdict".
std::map<std::string, int> VerdictCounts(const json& list) {
  std::map<std::string, int> n;
  for (const json& e : list) ++n[e["verdict"].get<std::string>()];
  return n;
}

// "requirements: 1 pass, 1 fail, 1 undetermined" -> {pass: 1, fail: 1, undetermined: 1}.
std::map<std::string, int> PrintedCounts(const std::string& output, const std::string& label) {
  std::map<std::string, int> n;
  const size_t at = output.find(label + ": ");
  if (at == std::string::npos) return n;
  const std::string rest = output.substr(at + label.size() + 2);
  const std::string part = rest.substr(0, rest.find(';'));
  const std::regex item(R"re((\d+) ([a-z/ ]+?)(?:,|$))re");
  for (std::sregex_iterator it(part.begin(), part.end(), item), end; it != end; ++it) {
    const int count = std::stoi((*it)[1]);
    if (count > 0) n[(*it)[2]] = count;
  }
  return n;
}

// The terminal's summary of a trend counts requirements and groups by the verdicts trend.json
// gives them. Requirements are set so that one is settled each way and one is not: limits at
// 10x and 1/10 of the FWHM the default run measured, and one at that FWHM (P(pass) near 0.5).
TEST(CliOptions, TrendSummaryCountsTheReportsVerdicts) {
  const std::string dir = FreshDir("options", "trend");
  ASSERT_EQ(RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) +
                      "/campaign_tests_tiny.json --out=" + dir + "/data")
                .exit_code,
            0);
  std::ofstream(dir + "/fit.json") << R"({"mcmc": {"target_ess": 100, "min_tau_multiple": 20}})";
  const std::string options =
      " --sampling=pixel_centre --nogroup_reports --config=" + dir + "/fit.json " + dir + "/data";
  const RunResult first = RunCcdpsf("trend --out=" + dir + "/first" + options);
  ASSERT_EQ(first.exit_code, 0) << first.output;
  const json t1 = ReadJson(dir + "/first/trend.json");
  ASSERT_TRUE(t1.is_object());
  double fwhm = NAN;
  for (const json& q : t1["requirements"]) {
    if (q["name"] == "fwhm_800nm" && q["value"].is_number()) fwhm = q["value"].get<double>();
  }
  ASSERT_TRUE(std::isfinite(fwhm)) << t1["requirements"].dump();
  json requirements = json::array();
  for (const auto& [name, limit] : std::vector<std::pair<std::string, double>>{
           {"loose", 10 * fwhm}, {"tight", fwhm / 10}, {"at_value", fwhm}}) {
    requirements.push_back(
        {{"name", name}, {"metric", "fwhm_um"}, {"at", {{"wavelength_nm", 800}}}, {"max", limit}});
  }
  std::ofstream(dir + "/requirements.json") << requirements.dump();
  const RunResult second = RunCcdpsf("trend --requirements=" + dir +
                                     "/requirements.json --out=" + dir + "/second" + options);
  ASSERT_EQ(second.exit_code, 0) << second.output;
  const json t2 = ReadJson(dir + "/second/trend.json");
  const std::map<std::string, int> verdicts = VerdictCounts(t2["requirements"]);
  // The run holds each verdict, so the counts below can tell pass from pass-by-median.
  EXPECT_EQ(verdicts, (std::map<std::string, int>{{"pass", 1}, {"fail", 1}, {"undetermined", 1}}))
      << t2["requirements"].dump();
  for (const RunResult* r : {&first, &second}) {
    const json t = ReadJson(dir + (r == &first ? "/first" : "/second") + "/trend.json");
    EXPECT_EQ(PrintedCounts(r->output, "requirements"), VerdictCounts(t["requirements"]))
        << r->output;
    std::map<std::string, int> groups;
    for (const json& g : t["groups"]) {
      ++groups[g["ok"].get<bool>() ? g["quality"]["verdict"].get<std::string>() : "failed to fit"];
    }
    const size_t open = r->output.find(" groups (");
    ASSERT_NE(open, std::string::npos) << r->output;
    const std::string inside = r->output.substr(open + 9, r->output.find(')', open) - open - 9);
    EXPECT_EQ(PrintedCounts("groups: " + inside, "groups"), groups) << r->output;
  }
  // The second run's config.json holds the requirement list itself.
  const json config = ReadJson(dir + "/second/config.json");
  EXPECT_EQ(config["flags"]["requirements"].size(), 3u);
}

// A trend's config.json repeats it (MAP and Laplace only here, for speed): the same
// trend.json but for the seconds each group took.
TEST(CliOptions, ConfigJsonRepeatsATrend) {
  const std::string dir = FreshDir("options", "trend_config");
  ASSERT_EQ(RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) +
                      "/campaign_small.json --out=" + dir + "/data")
                .exit_code,
            0);
  const RunResult a =
      RunCcdpsf("trend --nomcmc --reference_intensity_e=150000 --seed=4 --out=" + dir + "/a " +
                dir + "/data");
  ASSERT_EQ(a.exit_code, 0) << a.output;
  const json config = ReadJson(dir + "/a/config.json");
  ASSERT_TRUE(config.is_object());
  // trend's own default, not fit's.
  ExpectHelpDefaultsWereUsed("trend", config, {"mcmc", "seed", "reference_intensity_e"});
  EXPECT_EQ(config["flags"]["reference_intensity_e"], 150000.0);
  const RunResult b =
      RunCcdpsf("trend --config=" + dir + "/a/config.json --out=" + dir + "/b " + dir + "/data");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const json ja = ReadJson(dir + "/a/trend.json"), jb = ReadJson(dir + "/b/trend.json");
  ASSERT_TRUE(ja.contains("groups"));
  EXPECT_EQ(WithoutTimings(ja), WithoutTimings(jb));
}

}  // namespace
}  // namespace ccdpsf
