// ccdpsf trend: a characterisation campaign in, the CCD PSF's relations with wavelength and
// intensity, the combined model and the requirement checks out.
#include <cstdio>
#include <map>
#include <set>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/defocus_anchor.h"
#include "ccdpsf/trend/group_fit.h"
#include "ccdpsf/trend/intensity_series.h"
#include "ccdpsf/trend/trend.h"
#include "ccdpsf/trend/trend_report.h"
#include "ccdpsf/truth.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_string(truth);
DECLARE_uint64(seed);
DECLARE_int32(threads);
DECLARE_bool(strict);
DECLARE_string(manifest);
DECLARE_bool(resume);
// The parser's flags read only by trend; their meanings are TrendCommand()'s table.
DEFINE_string(requirements, "", "");
DEFINE_double(reference_intensity_e, 157800, "");
DEFINE_bool(group_reports, true, "");
DECLARE_bool(quiet);
DEFINE_string(group_plots, "flagged", "");
DEFINE_string(anchor_defocus, "same_wavelength", "");

namespace ccdpsf::tools {
namespace {

// A campaign's relations need a few hundred independent draws per setting (the MC error of
// a 68 % bound is then ~0.07 sd), not the 1000 of a single fit's default: trend's
// --target_ess defaults to this. The chain must still exceed 50 taus.
constexpr double kTrendTargetEss = 400;

// Counts of verdicts in a fixed order ("2 pass, 0 fail, ..."); the rare kinds ("n/a", "failed
// to fit") only when there are any.
std::string Counts(const std::vector<std::string>& order, const std::map<std::string, int>& n) {
  std::string out;
  for (const std::string& name : order) {
    const auto it = n.find(name);
    const int count = it == n.end() ? 0 : it->second;
    if (count == 0 && (name == "n/a" || name == "failed to fit")) continue;
    out += (out.empty() ? "" : ", ") + std::to_string(count) + " " + name;
  }
  return out;
}

// The terminal's summary of a trend: the groups by their verdict (or failure to fit) and the
// requirements by their verdict (requirements.h: pass / fail need P(pass) beyond 0.95 / 0.05,
// between is undetermined), the same counts trend.json and report.md give.
std::string TrendSummary(const trend::TrendResult& r, const std::string& out_dir) {
  std::map<std::string, int> groups, requirements, focus;
  for (const trend::GroupResult& g : r.groups) {
    ++groups[g.ok ? g.quality.Verdict() : "failed to fit"];
  }
  for (const trend::RequirementResult& q : r.requirements) ++requirements[trend::Verdict(q)];
  for (const auto& q : r.focus_requirements) ++focus[trend::Verdict(q.result)];
  const std::vector<std::string> verdicts = {"pass", "fail", "undetermined", "n/a"};
  std::string line = "trend of " + std::to_string(r.groups.size()) + " groups (" +
                     Counts({"ok", "suspect", "invalid", "failed to fit"}, groups) +
                     "); requirements: " + Counts(verdicts, requirements);
  if (!r.focus_requirements.empty()) {
    line += "; on the through-focus series: " + Counts(verdicts, focus);
  }
  return line + "; report: " + out_dir + "/report.md";
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
  if (!fit::ParsePictures(FLAGS_group_plots, &fit_options.pictures)) {
    return Fail("--group_plots must be all, flagged or none (got \"" + FLAGS_group_plots + "\")");
  }
  if (!ResolveFitConfig(&fit_options.config, &error)) return Fail(error);
  // A setting at one intensity cannot fit a signal-dependent effect: it goes to the intensity
  // series (intensity_series.h).
  fit_options.intensity_series_effects =
      trend::TakeIntensitySeriesEffects(&fit_options.config.model.effects);
  fit_options.seed = fit_options.config.fit.mcmc.seed;
  fit_options.flux_given = fit_options.config.flux_given;
  // --threads (or FIT.json's mcmc.threads): groups fitted at a time, each MCMC as many.
  fit_options.parallel_groups = fit_options.config.fit.mcmc.num_threads;
  report_options.threads = fit_options.parallel_groups;

  trend::TrendOptions trend_options;
  trend_options.reference_intensity_e = FLAGS_reference_intensity_e;
  if (!fit_options.intensity_series_effects.empty()) {
    trend_options.intensity_series_effect =
        model::ToString(fit_options.intensity_series_effects.front().kind);
  }
  trend_options.relation.seed = fit_options.seed;
  const nlohmann::json& config_flags = fit_options.config.flags;
  if (!FlagGiven("requirements") && config_flags.contains("requirements")) {
    // A config.json's own list (run_config.cc), not a file.
    auto requirements = trend::ParseRequirements(config_flags["requirements"], &error);
    if (!requirements) return Fail("'" + FLAGS_config + "': flags.requirements: " + error);
    trend_options.requirements = *requirements;
  } else if (!FLAGS_requirements.empty()) {
    std::string text;
    if (!ReadTextInput(FLAGS_requirements, "--requirements file", &text, &error)) {
      return Fail(error);
    }
    auto requirements = trend::ParseRequirementsText(text, &error);
    if (!requirements) return Fail(FLAGS_requirements + ": " + error);
    trend_options.requirements = *requirements;
  }

  trend::AnchorScope anchor = trend::AnchorScope::kSameWavelength;
  if (!trend::ParseAnchorScope(FLAGS_anchor_defocus, &anchor)) {
    return Fail("--anchor_defocus must be off, same_wavelength or any_wavelength (got \"" +
                FLAGS_anchor_defocus + "\")");
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
  if (!fit_options.intensity_series_effects.empty()) {
    const std::vector<trend::CampaignGroup> series =
        trend::IntensitySeries(groups, !fit::CcdSplitUnidentified(fit_options.config.model));
    if (series.empty()) {
      return Fail(
          model::ToString(fit_options.intensity_series_effects.front().kind) +
          " needs an intensity series: two or more through-focus "
          "series at one wavelength, or two or more single-focus settings at one "
          "wavelength and stage position (FOCUSPOS; without one only where one focus "
          "identifies the CCD widths: pillbox defocus or pixel_centre sampling)");
    }
    groups.insert(groups.end(), series.begin(), series.end());
  }
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
  // Through-focus series first; they anchor the defocus of single-focus settings at the
  // same stage position (defocus_anchor.h).
  std::vector<std::string> anchor_notes;
  // A note is printed the first time its text appears: the same choice in many groups (a
  // shared flux, a through-focus model) is said once, and counted after.
  std::set<std::string> notes_shown;
  int notes_repeated = 0;
  std::vector<trend::GroupResult> results = trend::FitCampaignGroups(
      groups, fit_options, anchor,
      [&notes_shown, &notes_repeated](const trend::GroupResult& r, int done, int total) {
        if (FLAGS_quiet) {
          // Only what needs attention: failures and warnings.
          if (!r.ok) {
            std::fprintf(stderr, "[%d/%d] %s: FAILED: %s\n", done, total, r.group.name.c_str(),
                         r.failure.c_str());
          }
          for (const std::string& w : r.ok ? r.warnings : std::vector<std::string>()) {
            std::fprintf(stderr, "%s: warning: %s\n", r.group.name.c_str(), w.c_str());
          }
          std::fflush(stderr);
          return;
        }
        if (r.ok) {
          std::fprintf(stderr,
                       "[%d/%d] %s: %d exposures, chi2/dof %.3f, %s, verdict %s, %.1f s%s\n", done,
                       total, r.group.name.c_str(), r.exposures, r.chi2_per_dof,
                       !r.mcmc_ran   ? "no MCMC (--nomcmc)"
                       : r.converged ? "MCMC converged"
                                     : "MCMC NOT converged",
                       r.quality.Verdict().c_str(), r.seconds,
                       r.resumed ? " (kept from the interrupted run)" : "");
          for (const std::string& n : r.notes) {
            if (notes_shown.insert(n).second) {
              std::fprintf(stderr, "    note: %s\n", n.c_str());
            } else {
              ++notes_repeated;
            }
          }
          for (const std::string& w : r.warnings) {
            std::fprintf(stderr, "    warning: %s\n", w.c_str());
          }
        } else {
          std::fprintf(stderr, "[%d/%d] %s: FAILED: %s\n", done, total, r.group.name.c_str(),
                       r.failure.c_str());
        }
        std::fflush(stderr);
      },
      &anchor_notes);
  if (notes_repeated > 0) {
    std::fprintf(stderr,
                 "ccdpsf trend: %d note(s) repeated in later groups not shown again (each "
                 "group's report has its own)\n",
                 notes_repeated);
  }
  if (!FLAGS_quiet) {
    for (const std::string& n : anchor_notes) std::fprintf(stderr, "ccdpsf trend: %s\n", n.c_str());
  }
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
  trend_result.notes.insert(trend_result.notes.begin(), anchor_notes.begin(), anchor_notes.end());
  nlohmann::json run = {
      {"command", "trend"},
      {"inputs", inputs},
      {"options", fit::FitConfigJson(fit_options.config)},
      {"requirements", trend::RequirementsToJson(trend_options.requirements)},
      {"reference_intensity_e", trend_options.reference_intensity_e},
      {"intensity_series_effects", fit::FitEffectsJson(fit_options.intensity_series_effects)},
      {"parallel_groups", fit_options.parallel_groups},
      {"seed", fit_options.seed},
      {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  report_options.reference_intensity_e = trend_options.reference_intensity_e;
  if (!trend::WriteTrendReport(out.partial(), trend_result, run, &warnings, &error,
                               report_options) ||
      !WriteRunConfig(out.partial(), fit_options.config,
                      {{"requirements", trend::RequirementsToJson(trend_options.requirements)}},
                      &error) ||
      !out.Commit({kStore}, &error)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  std::printf("%s\n", TrendSummary(trend_result, FLAGS_out).c_str());
  int flagged = 0;  // groups not fitted, suspect or invalid
  for (const auto& g : trend_result.groups) {
    flagged += !g.ok || g.quality.Worst() != Severity::kNote ? 1 : 0;
  }
  if (FLAGS_strict && flagged > 0) return kExitStrict;
  return 0;
}

}  // namespace

Command TrendCommand() {
  const fit::FitConfig d;  // the library's defaults, which most of trend's fit options take
  std::vector<Option> options = {
      {"out", "", "Output folder (required); replaced as a whole by the run's results"},
      {"config", "",
       "FIT.json with the options of every group's fit (priors, MCMC settings, calibration, "
       "keyword map) and \"flags\" (e.g. trend's requirement list); a trend's OUT/config.json "
       "repeats it; flags given override it"},
      {"plot_format", "png", "Format of the plots: png, pdf or svg"},
      {"truth", "",
       "truth.json of simulated data, drawn on the plots (not given: a truth.json in the folder "
       "holding all the inputs, if there is one)"},
      {"sampling", model::ToString(d.model.model.sampling),
       "Model sampling of every group's fit: integrated (exact pixel integral) or pixel_centre "
       "(the 2015 code's discretisation)"},
      {"defocus", model::ToString(d.model.model.defocus),
       "Defocus kernel of every group's fit: gaussian or pillbox"},
      {"likelihood", fit::ToString(d.model.likelihood),
       "gaussian (the paper's, with model-dependent variance) or poisson_normal (exact, for "
       "low signal)"},
      {"seed", "1",
       "Random seed of the groups' MCMCs (each group's derived from it) and of the relations' "
       "draws"},
      {"walkers", std::to_string(d.fit.num_walkers),
       "MCMC walkers per group (0: max(2 x ensemble dimension + 2, target_ess / 50))"},
      {"max_steps", std::to_string(d.fit.mcmc.max_steps), "MCMC step limit per group"},
      {"target_ess", NumberText(kTrendTargetEss),
       "Effective sample size every parameter of a group must reach (a few hundred draws "
       "suffice for the relations; a single fit's default is 1000)"},
      {"threads", std::to_string(d.fit.mcmc.num_threads),
       "Groups fitted at a time, and threads of each group's MCMC"},
      {"mcmc", d.fit.run_mcmc ? "true" : "false",
       "Run each group's MCMC (--nomcmc: MAP and Laplace only; relations from the Laplace "
       "approximation)"},
      {"flux", "auto",
       "How a group's exposures share the light: auto (chosen from the data and said), "
       "shared, per_exposure or exptime_scaled"},
      {"effects", "",
       "Effects of the catalogue fitted with every group's spot, comma-separated (" +
           fit::FittableEffectNames(", ") +
           "; `ccdpsf effects` describes them), with the catalogue's priors (FIT.json "
           "\"effects\" sets others); brighter_fatter and boundary_shift are fitted by an "
           "intensity series per wavelength, every other setting without them (docs/trust.md)"},
      {"requirements", "",
       "JSON list of requirements (not given: the Euclid VIS ones: FWHM <= 10.8 um and e <= "
       "0.156 at 800 nm and I0, alpha of FWHM(lambda) <= -0.2)"},
      {"reference_intensity_e", NumberText(trend::TrendOptions().reference_intensity_e),
       "Intensity zero point I0 [e- in the peak pixel] of the combined model"},
      {"group_reports", "true", "Write each group's full fit report under DIR/groups/"},
      {"quiet", "false",
       "Print only failures, warnings and the closing line (not each group's line and notes)"},
      {"group_plots", "flagged",
       "Which group reports get their pictures drawn: flagged (groups whose verdict is not ok), "
       "all or none; every report keeps the pictures' data and gnuplot scripts"},
      {"anchor_defocus", "same_wavelength",
       "Through-focus series fix the defocus of single-focus settings at a stage position "
       "(FOCUSPOS) inside their scanned range, so that those settings' CCD widths are "
       "identified: same_wavelength (series and setting within 0.5 nm), any_wavelength "
       "(assumes no chromatic shift of best focus) or off"},
      {"strict", "false",
       "Exit with code 3 when a group failed to fit or its verdict is suspect or invalid (for "
       "pipelines); without it a completed run exits 0 whatever the verdicts"},
      {"resume", "false",
       "Continue a run that was killed, into the same --out with the same inputs and options: "
       "the groups already finished are kept"},
      PtcOption()};
  for (const Option& o : InputOptions()) options.push_back(o);
  return {"trend",
          "ccdpsf trend --out=DIR [options] CAMPAIGN (manifest.json, its folder, or FITS files "
          "and folders grouped by WAVELEN / EXPTIME)",
          "Fit every setting of a campaign jointly; relations with wavelength and intensity; "
          "requirement checks.",
          options, RunTrend};
}

}  // namespace ccdpsf::tools
