// ccdpsf diagnose: find the effect the model is missing (diagnose/diagnose.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/diagnose/diagnose.h"
#include "ccdpsf/diagnose/diagnose_report.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_quality.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_uint64(seed);
DECLARE_int32(threads);
DECLARE_bool(strict);
DECLARE_string(flux);
DECLARE_bool(mixed_wavelengths);
// The parser's flags read only by diagnose; their meanings are DiagnoseCommand()'s table.
DEFINE_int32(max_rounds, 3, "");
DEFINE_int32(predictive_sims, 50, "");
DEFINE_double(alpha, 0.01, "");
DEFINE_string(baseline, "paper", "");
DEFINE_string(candidates, "", "");
DEFINE_bool(thresholds, false, "");
DEFINE_int32(threshold_sims, 10, "");

namespace ccdpsf::tools {
namespace {

bool ParseKinds(const std::string& text, std::vector<model::EffectKind>* kinds,
                std::string* error) {
  std::stringstream s(text);
  std::string item;
  while (std::getline(s, item, ',')) {
    if (item.empty()) continue;
    model::EffectKind k;
    if (!model::ParseEffectKind(item, &k)) {
      *error = "unknown effect '" + item + "' (catalogue: defocus, brighter_fatter, serial_cti, "
               "parallel_cti, ipc, jitter, background, nonlinearity, halo, defocus_offset)";
      return false;
    }
    kinds->push_back(k);
  }
  return true;
}

// The fit configuration of the diagnosis's final model: `config` with the final round's
// fittable effects (catalogue priors), its flux mode, a joint fit, and a pillbox defocus if
// that alternative was adopted, the measured width of a narrower pixel response (held fixed).
// An effect a fit cannot hold is left out and said in `notes` (since defocus_offset is fitted
// in pixel_centre sampling, every effect diagnose names carries over).
fit::FitConfig FinalFitConfig(const fit::FitConfig& config, const diagnose::DiagnoseResult& result,
                              std::vector<std::string>* notes) {
  fit::FitConfig final_config = config;
  final_config.joint = true;
  final_config.model.flux = result.flux == diagnose::FluxMode::kPerExposure
                                ? fit::FluxMode::kPerExposure
                                : fit::FluxMode::kShared;
  final_config.flux_given = true;
  final_config.model.effects.clear();
  const diagnose::ModelSpec& spec = result.rounds.back().spec;
  std::vector<std::string> left_out;
  for (model::EffectKind kind : model::AllEffectKinds()) {
    // The defocus is the fit model's own component, always fitted (from 0 up).
    if (kind == model::EffectKind::kDefocus || !spec.Has(kind)) continue;
    std::string why;
    if (fit::IsFittableEffect(kind, &why)) {
      final_config.model.effects.push_back({kind, {}});
    } else {
      left_out.push_back(model::ToString(kind) + " (" + why + ")");
    }
  }
  for (const diagnose::RoundResult& round : result.rounds) {
    if (round.adopted == diagnose::ToString(diagnose::AlternativeKind::kPillboxDefocus)) {
      final_config.model.model.defocus = model::DefocusKind::kPillbox;
    }
  }
  // A narrower pixel response: its measured width, held fixed by the fit (its uncertainty
  // is diagnose's, from the likelihood profile).
  for (const diagnose::Attribution& a : result.attributions) {
    if (a.name != diagnose::ToString(diagnose::AlternativeKind::kPixelResponse)) continue;
    for (const diagnose::ParameterEstimate& e : a.parameters) {
      if (e.name == "pixel_response.width_px" && std::isfinite(e.map)) {
        final_config.model.model.pixel_response_width = e.map;
        char width[32];
        std::snprintf(width, sizeof(width), "%.4g", e.map);
        notes->push_back("final_fit.json holds the pixel response width at diagnose's measured " +
                         std::string("value (") + width + " px; a fit does not refit it)");
      }
    }
  }
  for (const std::string& what : left_out) {
    notes->push_back("final_fit.json leaves out " + what);
  }
  return final_config;
}

int RunDiagnose(const std::vector<std::string>& files) {
  if (FLAGS_out.empty()) return Usage("diagnose needs --out=DIR");
  fit::FitConfig config;
  std::string error;
  PlotOptions plot;
  if (!ParsePlotFormat(FLAGS_plot_format, &plot.format, &error)) return Fail(error);
  // The seed, threads and flux come from here too: flag, else FIT.json, else diagnose's
  // default.
  if (!ResolveFitConfig(&config, &error)) return Fail(error);
  if (files.empty() && !FlagGiven("manifest")) {  // a config's "flags" may name the manifest
    return Usage("diagnose needs at least one FITS file (or --manifest)");
  }
  config.model.through_focus = false;
  diagnose::DiagnoseOptions options;
  options.max_rounds = FLAGS_max_rounds;
  options.predictive.num_simulations = FLAGS_predictive_sims;
  options.predictive.seed = config.fit.mcmc.seed;
  options.alpha = FLAGS_alpha;
  options.fit.num_threads = config.fit.mcmc.num_threads;
  options.map.num_threads = config.fit.mcmc.num_threads;
  options.compute_thresholds = FLAGS_thresholds;
  options.thresholds.num_simulations = FLAGS_threshold_sims;
  options.thresholds.seed = config.fit.mcmc.seed;
  options.progress = [](const std::string& line) {
    std::fprintf(stderr, "ccdpsf diagnose: %s\n", line.c_str());
  };
  if (!config.flux_given) {
    options.flux = diagnose::FluxChoice::kAuto;
  } else if (config.model.flux == fit::FluxMode::kShared) {
    options.flux = diagnose::FluxChoice::kShared;
  } else if (config.model.flux == fit::FluxMode::kPerExposure) {
    options.flux = diagnose::FluxChoice::kPerExposure;
  } else {
    return Fail("diagnose: --flux must be auto, shared or per_exposure");
  }
  {
    std::string b = FLAGS_baseline;
    const size_t plus = b.find('+');
    const std::string head = b.substr(0, plus);
    if (head == "paper") {
      options.baseline_defocus = true;
    } else if (head == "no_defocus") {
      options.baseline_defocus = false;
    } else {
      return Fail("--baseline must start with paper or no_defocus");
    }
    if (plus != std::string::npos) {
      std::string rest = b.substr(plus + 1);
      for (char& c : rest) c = c == '+' ? ',' : c;
      if (!ParseKinds(rest, &options.baseline_effects, &error)) return Fail("--baseline: " + error);
    }
  }
  {
    // Catalogue effects and model alternatives by name.
    std::stringstream list(FLAGS_candidates);
    std::string item;
    while (std::getline(list, item, ',')) {
      if (item.empty()) continue;
      bool alternative = false;
      for (diagnose::AlternativeKind a : diagnose::AllAlternatives()) {
        if (item == diagnose::ToString(a)) {
          options.alternatives.push_back(a);
          alternative = true;
        }
      }
      if (alternative) continue;
      if (!ParseKinds(item, &options.candidates, &error)) {
        return Fail("--candidates: " + error + " or a model alternative (pillbox_defocus, "
                    "pixel_response)");
      }
    }
  }
  // Effects a FIT.json fits (a previous diagnosis's final_fit.json) are part of the
  // baseline here, with the catalogue's priors: diagnose goes on from that model.
  for (const fit::FitEffect& e : config.model.effects) {
    if (std::find(options.baseline_effects.begin(), options.baseline_effects.end(), e.kind) ==
        options.baseline_effects.end()) {
      options.baseline_effects.push_back(e.kind);
    }
  }
  config.model.effects.clear();
  if (!options.IsValid(&error)) return Fail(error);
  std::vector<InputFile> inputs;
  Manifest manifest;
  if (!ResolveInputs(files, config.calibration, &inputs, &manifest, &error)) return Fail(error);
  std::vector<std::string> input_paths;
  for (const InputFile& input : inputs) input_paths.push_back(input.path);
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs(input_paths), {}, &error)) return Fail(error);
  ExposureSet set;
  ExposureSetOptions set_options;
  set_options.allow_mixed_wavelengths = FLAGS_mixed_wavelengths;
  if (!LoadExposureSet(inputs, set_options, &set, &error)) return Fail(error);
  std::vector<Stamp> stamps;
  std::vector<std::string> paths;
  int censored = 0;
  for (Exposure& e : set.exposures) {
    // Censored pixels (saturated, clipped) are bounds in every likelihood, as in a fit; the
    // residual statistics leave them out.
    censored += e.stamp.NumCensored();
    stamps.push_back(e.stamp);
    paths.push_back(e.stamp.info.source);
  }
  auto base = fit::FitModel::Create(stamps, config.model, &error);
  if (!base) return Fail(error);
  diagnose::DiagnoseResult result;
  if (!diagnose::RunDiagnosis(*base, options, &result, &error)) return Fail(error);
  // The verdict on the data: calibration's and the set's findings, and the noise check.
  for (size_t k = 0; k < set.exposures.size(); ++k) {
    for (const Finding& f : set.exposures[k].report.quality.findings) {
      result.quality.Add(f.code, f.severity, "exposure " + std::to_string(k) + ": " + f.message,
                         static_cast<int>(k));
    }
  }
  for (const Finding& f : set.quality.findings) {
    result.quality.Add(f.code, f.severity, "exposure " + std::to_string(f.exposure) + ": " + f.message,
                       f.exposure);
  }
  if (censored > 0) {
    result.quality.Add("censored_bounds", Severity::kNote,
                       std::to_string(censored) +
                           " censored pixel(s) (saturated or clipped) enter the likelihood as "
                           "bounds, as in a fit; the residual statistics leave them out");
  }
  {
    // The noise check: the tests compare residuals with the noise model, so a chi^2 below
    // its range (noise overstated) makes every p-value too large; one above it after the
    // last round means the final model does not describe the data either.
    Quality noise;
    const diagnose::ResidualStatistics& first = result.rounds.front().statistics;
    fit::AssessChi2(first.chi2, first.dof, fit::FitQualityOptions(), &noise);
    for (const Finding& f : noise.findings) {
      if (f.code == "chi2_low") {
        result.quality.Add("noise_check_failed", Severity::kSuspect,
                           "baseline " + f.message + "; the tests assume the noise model, so "
                           "their p-values are not right");
      }
    }
    Quality last;
    const diagnose::ResidualStatistics& final_stats = result.rounds.back().statistics;
    fit::AssessChi2(final_stats.chi2, final_stats.dof, fit::FitQualityOptions(), &last);
    for (const Finding& f : last.findings) {
      if (f.code == "chi2_low") {
        result.quality.Add("noise_check_failed", Severity::kSuspect,
                           "final model: " + f.message +
                               "; the tests assume the noise model, so their p-values are not "
                               "right");
      } else {
        result.quality.Add(f.code, f.severity, "final model: " + f.message);
      }
    }
  }
  nlohmann::json run = {
      {"command", "diagnose"},
      {"files", paths},
      {"options",
       {{"fit", fit::FitConfigJson(config)},
        {"max_rounds", options.max_rounds},
        {"predictive_sims", options.predictive.num_simulations},
        {"alpha", options.alpha},
        {"flux", config.flux_given ? fit::ToString(config.model.flux) : std::string("auto")},
        {"baseline", FLAGS_baseline},
        {"candidates", FLAGS_candidates},
        {"thresholds", options.compute_thresholds},
        {"threshold_sims", options.thresholds.num_simulations}}},
      {"seed", config.fit.mcmc.seed},
      {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  std::vector<std::string> final_notes;
  const fit::FitConfig final_config = FinalFitConfig(config, result, &final_notes);
  nlohmann::json final_json = RunConfigJson(final_config, nlohmann::json::object(), &error);
  if (final_json.is_null()) return Fail(error);
  {
    // Only the options `fit` has: the file is for `fit --config=` (and `trend`).
    const Command fit_command = FitCommand();
    nlohmann::json flags = nlohmann::json::object();
    for (auto it = final_json["flags"].begin(); it != final_json["flags"].end(); ++it) {
      if (fit_command.Find(it.key()) != nullptr) flags[it.key()] = it.value();
    }
    final_json["flags"] = flags;
  }
  for (const std::string& n : final_notes) result.notes.push_back(n);
  if (!diagnose::WriteDiagnoseReport(out.partial(), *base, result, options, run, &warnings, &error,
                                     plot) ||
      !WriteRunConfig(out.partial(), config, nlohmann::json::object(), &error) ||
      !WriteTextFileAtomically(out.partial() + "/final_fit.json", final_json.dump(2) + "\n",
                               &error) ||
      !out.Commit({}, &error)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  std::printf(
      "%s; chi2/dof %.4g -> %.4g; verdict on the data %s; results in %s/diagnose.json "
      "(report.md, plots; final_fit.json holds the final model for fit --config=)\n",
      diagnose::DiagnosisVerdict(result).c_str(), result.rounds.front().statistics.chi2_per_dof,
      result.rounds.back().statistics.chi2_per_dof, result.quality.OneLine().c_str(),
      FLAGS_out.c_str());
  if (FLAGS_strict && result.quality.Worst() != Severity::kNote) return kExitStrict;
  return 0;
}

}  // namespace

Command DiagnoseCommand() {
  const fit::FitConfig d;  // the library's fit defaults (the baseline's model)
  const diagnose::DiagnoseOptions dd;
  std::vector<Option> options = {
      {"out", "", "Output folder (required); replaced as a whole by the run's results"},
      {"config", "",
       "FIT.json with the baseline's options (priors, calibration, keyword map) and \"flags\" "
       "(e.g. max_rounds); a diagnosis's OUT/config.json repeats it; flags given override it"},
      {"plot_format", "png", "Format of the plots: png, pdf or svg"},
      {"sampling", model::ToString(d.model.model.sampling),
       "Model sampling: integrated (exact pixel integral) or pixel_centre (the 2015 code's "
       "discretisation)"},
      {"defocus", model::ToString(d.model.model.defocus),
       "Defocus kernel of the baseline: gaussian or pillbox"},
      {"seed", "1", "Random seed of the predictive simulations and of the --thresholds study"},
      {"threads", std::to_string(dd.map.num_threads),
       "Ceres threads, and predictive simulations run at a time"},
      {"max_rounds", std::to_string(dd.max_rounds), "Rounds of testing (each may name one effect)"},
      {"predictive_sims", std::to_string(dd.predictive.num_simulations),
       "Simulations of each fitted model for the predictive p-values (0: none)"},
      {"alpha", NumberText(dd.alpha),
       "Family-wise false-claim rate per round (Bonferroni over the candidates)"},
      {"flux", "auto",
       "How the exposures share the light: auto (a flux per exposure for a set at several "
       "intensities, else shared), shared or per_exposure"},
      {"baseline", "paper",
       "paper (the paper's model) or no_defocus (without the defocus, which then becomes a "
       "candidate); add effects with +, e.g. paper+background"},
      {"candidates", "",
       "Comma-separated catalogue effects and model alternatives (pillbox_defocus, "
       "pixel_response) that may be named (empty: all)"},
      {"thresholds", dd.compute_thresholds ? "true" : "false",
       "Simulate the detection threshold of every effect not found (slow)"},
      {"threshold_sims", std::to_string(dd.thresholds.num_simulations),
       "Simulations per strength for --thresholds"},
      {"mixed_wavelengths", "false",
       "Let the exposures be at different wavelengths (one PSF shared across them)"},
      {"strict", "false",
       "Exit with code 3 when the verdict on the data is suspect or invalid (for pipelines); "
       "without it a completed run exits 0 whatever the verdict"}};
  for (const Option& o : InputOptions()) options.push_back(o);
  return {"diagnose",
          "ccdpsf diagnose --out=DIR [--baseline=paper] [--max_rounds=3] [options] FILE.fits...",
          "Find the physical effect the model is missing: fit, test the catalogue, add, repeat.",
          options, RunDiagnose};
}

}  // namespace ccdpsf::tools
