// ccdpsf trend: a characterisation campaign in, the CCD PSF's relations with wavelength and
// intensity, the combined model and the requirement checks out.
#include <cstdio>
#include <fstream>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/truth.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"
#include "ccdpsf/trend/trend.h"
#include "ccdpsf/trend/trend_report.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_string(truth);
DECLARE_uint64(seed);
DECLARE_int32(threads);
DECLARE_bool(strict);
DECLARE_string(manifest);
DECLARE_bool(resume);
DEFINE_string(requirements, "",
              "trend: JSON list of requirements (default: the Euclid VIS ones: FWHM <= 10.8 um "
              "and e <= 0.156 at 800 nm and I0, alpha of FWHM(lambda) <= -0.2)");
DEFINE_double(reference_intensity_e, 157800,
              "trend: intensity zero point I0 [e- in the peak pixel] of the combined model");
DEFINE_bool(group_reports, true, "trend: write each group's full fit report under DIR/groups/");

namespace ccdpsf::tools {
namespace {

constexpr double kTrendTargetEss = 400;

// What decides a trend's numbers, for the keys of its stored groups (group_store.h): the
// inputs and every option given, but not those that change only where or how fast it runs.
std::string RunSignature(const std::vector<std::string>& inputs) {
  nlohmann::json signature = {{"inputs", inputs}};
  std::vector<gflags::CommandLineFlagInfo> flags;
  gflags::GetAllFlags(&flags);
  for (const auto& f : flags) {
    if (f.is_default || f.name == "out" || f.name == "resume" || f.name == "threads") continue;
    signature["flags"][f.name] = f.current_value;
  }
  // The files --config, --manifest, --keywords and --requirements name, by content.
  for (const char* flag : {"config", "manifest", "keywords", "requirements"}) {
    std::string path;
    if (!gflags::GetCommandLineOption(flag, &path) || path.empty()) continue;
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    signature["files"][flag] = text.str();
  }
  return signature.dump();
}

int RunTrend(const std::vector<std::string>& inputs) {
  if (FLAGS_out.empty()) return Usage("trend needs --out=DIR");
  std::string error;
  trend::TrendReportOptions report_options;
  if (!ParsePlotFormat(FLAGS_plot_format, &report_options.plot.format, &error) ||
      !FindTruth(FLAGS_truth, inputs, &report_options.truth, &error)) {
    return Fail(error);
  }
  trend::GroupFitOptions fit_options;
  fit_options.plot_format = report_options.plot.format;
  // A campaign's relations need a few hundred independent draws per setting (the MC error of
  // a 68 % bound is then ~0.07 sd), not the 1000 of a single fit's default: 400 unless
  // FIT.json or --target_ess says otherwise. The chain must still exceed 50 taus.
  fit_options.config.fit.mcmc.target_ess = kTrendTargetEss;
  if (!ResolveFitConfig(&fit_options.config, &error)) return Fail(error);
  fit_options.seed = fit_options.config.fit.mcmc.seed;
  fit_options.flux_given = fit_options.config.flux_given;
  fit_options.parallel_groups = FlagGiven("threads") ? FLAGS_threads
                                                     : fit_options.config.fit.mcmc.num_threads;

  trend::TrendOptions trend_options;
  trend_options.reference_intensity_e = FLAGS_reference_intensity_e;
  trend_options.relation.seed = fit_options.seed;
  if (!FLAGS_requirements.empty()) {
    std::ifstream in(FLAGS_requirements);
    if (!in) return Fail("cannot read --requirements file " + FLAGS_requirements);
    std::stringstream text;
    text << in.rdbuf();
    auto requirements = trend::ParseRequirementsText(text.str(), &error);
    if (!requirements) return Fail(FLAGS_requirements + ": " + error);
    trend_options.requirements = *requirements;
  }

  trend::CampaignOptions campaign;
  campaign.config = fit_options.config.calibration;
  if (!InputFlags(&campaign.flags, &campaign.config.keywords, &error)) return Fail(error);
  if (FlagGiven("manifest")) campaign.manifest = FLAGS_manifest;
  if (inputs.empty() && campaign.manifest.empty()) {
    return Usage("trend needs a campaign: a manifest, a campaign folder, or FITS files / folders");
  }
  std::vector<trend::CampaignGroup> groups;
  if (!trend::LoadCampaign(inputs, campaign, &groups, &error)) return Fail(error);
  std::vector<std::string> read = inputs;
  for (const trend::CampaignGroup& g : groups) read.insert(read.end(), g.files.begin(), g.files.end());
  // Finished groups are kept in the partial folder's "store" (and their reports in
  // "groups") until the commit; a --resume run reuses those of a killed run.
  const std::string kStore = "store", kGroups = "groups";
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs(read),
                 FLAGS_resume ? std::vector<std::string>{kStore, kGroups}
                              : std::vector<std::string>{},
                 &error)) {
    return Fail(error);
  }
  if (FLAGS_group_reports) fit_options.reports_dir = out.partial() + "/" + kGroups;
  fit_options.store_dir = out.partial() + "/" + kStore;
  if (!MakeDirectories(fit_options.store_dir, &error)) return Fail(error);
  fit_options.run_signature = RunSignature(inputs);
  int exposures = 0;
  for (const auto& g : groups) exposures += static_cast<int>(g.files.size());
  std::fprintf(stderr, "ccdpsf trend: %zu groups, %d exposures, %d in parallel\n", groups.size(),
               exposures, fit_options.parallel_groups);
  std::vector<trend::GroupResult> results = trend::FitGroups(
      groups, fit_options, [](const trend::GroupResult& r, int done, int total) {
        if (r.ok) {
          std::fprintf(stderr, "[%d/%d] %s: %d exposures, chi2/dof %.3f, %s, verdict %s, %.1f s%s\n",
                       done, total, r.group.name.c_str(), r.exposures, r.chi2_per_dof,
                       r.converged ? "MCMC converged" : "MCMC NOT converged",
                       r.quality.Verdict().c_str(), r.seconds,
                       r.resumed ? " (kept from the interrupted run)" : "");
          for (const std::string& n : r.notes) std::fprintf(stderr, "    note: %s\n", n.c_str());
          for (const std::string& w : r.warnings) {
            std::fprintf(stderr, "    warning: %s\n", w.c_str());
          }
        } else {
          std::fprintf(stderr, "[%d/%d] %s: FAILED: %s\n", done, total, r.group.name.c_str(),
                       r.failure.c_str());
        }
        std::fflush(stderr);
      });
  int failed = 0;
  for (const auto& r : results) failed += r.ok ? 0 : 1;
  if (failed == static_cast<int>(results.size())) {
    return Fail("every group failed to fit (first: " + results[0].group.name + ": " +
                results[0].failure + ")");
  }
  trend::TrendResult trend_result;
  if (!trend::ComputeTrend(std::move(results), trend_options, &trend_result, &error)) {
    return Fail(error);
  }
  nlohmann::json run = {{"command", "trend"},
                        {"inputs", inputs},
                        {"options", fit::FitConfigJson(fit_options.config)},
                        {"requirements", trend::RequirementsToJson(trend_options.requirements)},
                        {"reference_intensity_e", trend_options.reference_intensity_e},
                        {"parallel_groups", fit_options.parallel_groups},
                        {"seed", fit_options.seed},
                        {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  report_options.reference_intensity_e = trend_options.reference_intensity_e;
  if (!trend::WriteTrendReport(out.partial(), trend_result, run, &warnings, &error,
                               report_options) ||
      !out.Commit({kStore}, &error)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  int passed = 0, decided = 0;
  for (const auto& q : trend_result.requirements) {
    if (q.pass) {
      ++decided;
      passed += *q.pass ? 1 : 0;
    }
  }
  int suspect = 0;
  for (const auto& g : trend_result.groups) {
    suspect += g.ok && g.quality.Worst() == Severity::kSuspect ? 1 : 0;
  }
  std::printf("trend of %zu groups (%d failed or invalid, %d suspect): %d/%d requirements pass; "
              "report: %s/report.md\n",
              trend_result.groups.size(), failed, suspect, passed, decided, FLAGS_out.c_str());
  if (FLAGS_strict && (failed > 0 || suspect > 0)) return kExitStrict;
  return 0;
}

}  // namespace

std::vector<const char*> TrendFlagNames() {
  std::vector<const char*> names = {"out",        "config",      "sampling",   "defocus",
                                    "likelihood", "seed",        "walkers",    "max_steps",
                                    "target_ess", "threads",     "mcmc",       "flux",
                                    "strict",     "requirements", "reference_intensity_e",
                                    "group_reports", "resume"};
  for (const char* n : InputFlagNames()) names.push_back(n);
  return names;
}

Command TrendCommand() {
  return {"trend",
          "ccdpsf trend --out=DIR [options] CAMPAIGN (manifest.json, its folder, or FITS files "
          "and folders grouped by WAVELEN / EXPTIME)",
          "Fit every setting of a campaign jointly; relations with wavelength and intensity; "
          "requirement checks.",
          TrendFlagNames(),
          RunTrend};
}

}  // namespace ccdpsf::tools
