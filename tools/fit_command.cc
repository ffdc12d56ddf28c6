// ccdpsf fit: MAP, Laplace and MCMC for one exposure, several separately, or jointly.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/ptc_prior.h"
#include "ccdpsf/safe_path.h"
#include "ccdpsf/truth.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_string(truth);
DECLARE_string(sampling);
DECLARE_string(defocus);
DECLARE_int32(stamp_size);
// The parser's flags read by fit (and some by trend and diagnose); what each means and
// defaults to is each command's option table (FitCommand() below, trend_command.cc,
// diagnose_command.cc).
DEFINE_bool(joint, false, "");
DEFINE_string(plots, "all", "");
DEFINE_bool(through_focus, false, "");
DEFINE_string(likelihood, "gaussian", "");
DEFINE_uint64(seed, 1, "");
DEFINE_int32(walkers, 0, "");
DEFINE_int32(max_steps, 20000, "");
DEFINE_double(target_ess, 1000, "");
DEFINE_int32(threads, 2, "");
DEFINE_bool(mcmc, true, "");
DEFINE_string(flux, "auto", "");
DEFINE_string(effects, "", "");
DEFINE_bool(mixed_wavelengths, false, "");
DEFINE_bool(strict, false, "");
DEFINE_bool(quiet, false, "");
DEFINE_bool(resume, false, "");
DEFINE_double(checkpoint_s, 30, "");
DEFINE_bool(outliers, true, "");
DEFINE_string(ptc, "", "");

namespace ccdpsf::tools {

namespace {

// Sets the fit options of `c` from the current command's fit flags: every one it has
// (`given_only` false: the command's defaults, or values given) or only those given.
bool ApplyFitFlags(bool given_only, fit::FitConfig* c, std::string* error) {
  auto use = [given_only](const char* name) {
    return CurrentCommand().Find(name) != nullptr && (!given_only || FlagGiven(name));
  };
  if (use("sampling") && !model::ParseSampling(FLAGS_sampling, &c->model.model.sampling)) {
    *error = "--sampling must be integrated or pixel_centre";
    return false;
  }
  if (use("defocus") && !model::ParseDefocusKind(FLAGS_defocus, &c->model.model.defocus)) {
    *error = "--defocus must be gaussian or pillbox";
    return false;
  }
  if (use("likelihood") && !fit::ParseLikelihoodKind(FLAGS_likelihood, &c->model.likelihood)) {
    *error = "--likelihood must be gaussian or poisson_normal";
    return false;
  }
  if (use("joint")) c->joint = FLAGS_joint;
  // Not given, the choice is made from the files (RunFit): no default to apply.
  if (use("through_focus") && FlagGiven("through_focus")) {
    c->model.through_focus = FLAGS_through_focus;
    c->through_focus_given = true;
  }
  if (use("seed")) c->fit.mcmc.seed = FLAGS_seed;
  if (use("walkers")) c->fit.num_walkers = FLAGS_walkers;
  if (use("max_steps")) c->fit.mcmc.max_steps = FLAGS_max_steps;
  if (use("target_ess")) c->fit.mcmc.target_ess = FLAGS_target_ess;
  if (use("threads")) c->fit.mcmc.num_threads = c->fit.map.num_threads = FLAGS_threads;
  if (use("mcmc")) c->fit.run_mcmc = FLAGS_mcmc;
  if (use("stamp_size")) c->calibration.stamp_size = FLAGS_stamp_size;
  if (use("effects") && !fit::ParseFitEffectList(FLAGS_effects, &c->model.effects, error)) {
    return false;
  }
  if (use("flux")) {
    if (FLAGS_flux == "auto") {
      c->flux_given = false;
    } else if (fit::ParseFluxMode(FLAGS_flux, &c->model.flux)) {
      c->flux_given = true;
    } else {
      *error = "--flux must be auto, shared, per_exposure or exptime_scaled";
      return false;
    }
  }
  return true;
}

// --ptc=DIR/ptc.json (fit, trend; also from a config's "flags"): the flats' a_ij as the
// Gaussian prior of boundary_shift's (ptc_prior.h). Checked before any input is read.
bool ApplyPtcPrior(fit::FitConfig* c, std::string* error) {
  c->model.gaussian_prior = fit::GaussianPrior();
  if (CurrentCommand().Find("ptc") == nullptr || FLAGS_ptc.empty()) return true;
  if (!c->model.HasEffect(model::EffectKind::kBoundaryShift)) {
    *error = "--ptc is a prior on boundary_shift's a_ij: add --effects=boundary_shift";
    return false;
  }
  if (!ReadPtcPrior(FLAGS_ptc, &c->model.gaussian_prior, error)) return false;
  // Recorded absolute, as config.json records the flag (run_config.cc), so that a run
  // repeated from it names the same file.
  c->model.gaussian_prior.source =
      std::filesystem::absolute(std::filesystem::path(FLAGS_ptc)).lexically_normal().string();
  return true;
}

}  // namespace

// The command's defaults <- FIT.json (with its "flags") <- flags given on the command line.
bool ResolveFitConfig(fit::FitConfig* c, std::string* error) {
  if (!ApplyFitFlags(/*given_only=*/false, c, error)) return false;
  if (!FLAGS_config.empty()) {
    if (!fit::LoadFitConfig(FLAGS_config, c, error)) return false;
    if (!ApplyConfigFlags(c->flags, {"requirements"}, error)) {
      *error = "'" + FLAGS_config + "': " + *error;
      return false;
    }
  }
  if (!ApplyFitFlags(/*given_only=*/true, c, error)) return false;
  if (!c->calibration.IsValid(error)) return false;
  if (!fit::CheckMcmcSettings(c->fit.num_walkers, c->fit.mcmc.max_steps, c->fit.mcmc.num_threads,
                              c->fit.mcmc.target_ess, "--", error)) {
    return false;
  }
  if (c->model.model.sampling == model::Sampling::kPixelCentre &&
      c->model.model.defocus != model::DefocusKind::kGaussian) {
    *error = "pixel_centre sampling has only the Gaussian defocus of the 2015 code";
    return false;
  }
  if (!fit::EffectsFitInSampling(c->model, error)) return false;
  return ApplyPtcPrior(c, error);
}

namespace {

namespace fs = std::filesystem;

// One fit (single exposure or joint set) written into `dir`, which becomes `shown` (the
// folder named in messages) when the run's output folder is committed. Returns the exit code.
int FitInto(const std::string& dir, const std::string& shown, const std::string& checkpoint,
            const std::vector<Exposure>& exposures, const Quality& set_quality,
            const fit::FitConfig& config, const std::vector<std::string>& files, bool* flagged) {
  fit::ExposuresFitOptions options;
  options.config = config;
  options.config.fit.mcmc.progress_label = shown;
  if (FLAGS_quiet) options.config.fit.mcmc.progress = false;
  // The MCMC's checkpoint, kept in the run's partial folder (dropped at the commit).
  options.config.fit.mcmc.checkpoint_path = checkpoint;
  options.config.fit.mcmc.checkpoint_seconds = FLAGS_checkpoint_s;
  options.flux_given = config.flux_given;
  options.outliers.enabled = FLAGS_outliers;
  fit::ExposuresFit fitted;
  std::string error;
  if (!fit::FitExposures(exposures, set_quality, options, &fitted, &error)) {
    return Fail(shown + ": " + error);
  }
  for (const std::string& note : FLAGS_quiet ? std::vector<std::string>() : fitted.notes) {
    std::fprintf(stderr, "ccdpsf: note: %s\n", note.c_str());
  }
  if (!fitted.result.chain.checkpoint_discarded.empty()) {
    std::fprintf(stderr, "ccdpsf: note: %s: %s\n", shown.c_str(),
                 fitted.result.chain.checkpoint_discarded.c_str());
  }
  if (fitted.result.have_mcmc && fitted.result.chain.resumed_from_step > 0) {
    std::fprintf(stderr, "ccdpsf: note: %s: the MCMC resumed from its checkpoint at step %d\n",
                 shown.c_str(), fitted.result.chain.resumed_from_step);
  }
  nlohmann::json run = {{"command", "fit"},
                        {"files", files},
                        {"options", fit::FitConfigJson(config)},
                        {"seed", config.fit.mcmc.seed},
                        {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  fit::FitReportOptions report_options;
  if (!ParsePlotFormat(FLAGS_plot_format, &report_options.plot.format, &error) ||
      !FindTruth(FLAGS_truth, files, &report_options.truth, &error)) {
    return Fail(error);
  }
  fit::Pictures pictures = fit::Pictures::kAll;
  fit::ParsePictures(FLAGS_plots, &pictures);  // checked by RunFit before any fitting
  report_options.plot.draw = fit::DrawsPictures(pictures, fitted.quality);
  report_options.plot_reason =
      std::string("fit --plots=") + fit::ToString(pictures) +
      (pictures == fit::Pictures::kFlagged ? ", and the verdict is ok" : "");
  if (!fit::WriteFitReport(dir, fitted, run, &warnings, &error, report_options)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  const fit::FitResult& result = fitted.result;
  // What else is in the folder: report.md always, the pictures when they were drawn.
  std::printf("%s: chi2/dof %.4g, %s; verdict %s; results in %s/fit.json (report.md%s)\n",
              files.size() == 1 ? files[0].c_str() : "joint fit", result.map.chi2 / result.map.dof,
              result.have_mcmc ? (result.chain.converged ? "MCMC converged" : "MCMC NOT converged")
                               : "no MCMC",
              fitted.quality.OneLine().c_str(), shown.c_str(),
              report_options.plot.draw ? ", plots" : "");
  if (fitted.quality.Worst() != Severity::kNote) *flagged = true;
  return 0;
}

// Output folders of separate fits, one per file: the file's stem, made unique with its
// parent folders' names when two files share a stem (a second exposure_000.fits from
// another folder must not overwrite the first), and made safe components (safe_path.h: the
// stem of "...fits" is "..").
std::vector<std::string> SeparateFolders(const std::vector<std::string>& files) {
  std::vector<std::string> stems, names;
  for (const std::string& f : files) stems.push_back(fs::path(f).stem().string());
  names = stems;
  for (size_t i = 0; i < files.size(); ++i) {
    bool clash = false;
    for (size_t j = 0; j < files.size(); ++j) clash = clash || (i != j && stems[i] == stems[j]);
    if (!clash) continue;
    fs::path parent = fs::path(files[i]).parent_path();
    std::string name = fs::path(files[i]).stem().string();
    // Prefix parent folder names until the name is unique among all stems and names.
    for (int depth = 0; depth < 8 && !parent.empty(); ++depth) {
      name = parent.filename().string() + "_" + name;
      parent = parent.parent_path();
      bool unique = true;
      for (size_t j = 0; j < files.size(); ++j) unique = unique && (j == i || stems[j] != name);
      if (unique) break;
    }
    names[i] = name;
  }
  // Still equal (the same path given twice is refused earlier): numbered.
  return UniqueSafeComponents(names);
}

int RunFit(const std::vector<std::string>& files) {
  if (FLAGS_out.empty()) return Usage("fit needs --out=DIR");
  fit::FitConfig config;
  std::string error;
  if (!ResolveFitConfig(&config, &error)) return Fail(error);
  {
    // Checked before any fitting, so that a typo fails at once.
    PlotFormat format;
    std::optional<TruthFile> truth;
    if (!ParsePlotFormat(FLAGS_plot_format, &format, &error) ||
        !FindTruth(FLAGS_truth, files, &truth, &error)) {
      return Fail(error);
    }
    fit::Pictures pictures;
    if (!fit::ParsePictures(FLAGS_plots, &pictures)) {
      return Fail("--plots must be all, flagged or none (got \"" + FLAGS_plots + "\")");
    }
  }
  std::vector<InputFile> inputs;
  Manifest manifest;
  if (files.empty() && !FlagGiven("manifest")) {
    return Usage("fit needs at least one FITS file (or --manifest)");
  }
  if (!ResolveInputs(files, config.calibration, &inputs, &manifest, &error)) return Fail(error);
  std::vector<std::string> paths;
  for (const InputFile& input : inputs) paths.push_back(input.path);
  const bool joint = config.joint && inputs.size() > 1;
  ExposureSet set;
  ExposureSetOptions set_options;
  set_options.allow_mixed_wavelengths = !joint || FLAGS_mixed_wavelengths;
  set_options.compression_modelled = fit::SignalDependenceModelled(config.model);
  if (!LoadExposureSet(inputs, set_options, &set, &error)) return Fail(error);
  std::vector<Exposure>& exposures = set.exposures;
  if (config.model.HasEffect(model::EffectKind::kJitter) && !joint) {
    return Fail("jitter is fitted per exposure in a joint fit of two or more files: add --joint");
  }
  if (config.model.through_focus && !config.joint && inputs.size() > 1) {
    return Fail("through_focus fits a series jointly: add --joint");
  }
  if (joint && !config.through_focus_given) {
    // A joint set that is a through-focus series is fitted as one unless told otherwise.
    std::vector<Stamp> stamps;
    std::vector<double> z;
    for (const Exposure& e : exposures) {
      stamps.push_back(e.stamp);
      z.push_back(e.stamp.info.focus_position_um);
    }
    std::string why;
    if (fit::IsFocusSeries(stamps, &why)) {
      std::sort(z.begin(), z.end());
      const long distinct = std::unique(z.begin(), z.end()) - z.begin();
      if (config.model.model.sampling == model::Sampling::kIntegrated &&
          config.model.model.defocus == model::DefocusKind::kGaussian) {
        config.model.through_focus = true;
        if (!FLAGS_quiet) {
          std::fprintf(stderr,
                       "ccdpsf: note: the %zu files carry focus positions with %ld distinct "
                       "values: fitting them as a through-focus series (defocus = rate x |z - "
                       "z0|, CCD kernel fixed; --nothrough_focus to turn off)\n",
                       inputs.size(), distinct);
        }
      } else if (!FLAGS_quiet) {
        std::fprintf(stderr,
                     "ccdpsf: note: the %zu files carry focus positions with %ld distinct "
                     "values, but the through-focus model needs integrated sampling and a "
                     "Gaussian defocus: fitting them with one shared defocus\n",
                     inputs.size(), distinct);
      }
    }
  }
  // MCMC checkpoints live in the partial folder's "checkpoints" until the commit; a
  // --resume run keeps those a killed run left there.
  const std::string kCheckpoints = "checkpoints";
  if (FLAGS_checkpoint_s < 0) return Fail("--checkpoint_s must be >= 0");
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs(paths), FLAGS_resume ? std::vector<std::string>{kCheckpoints}
                                                           : std::vector<std::string>{},
                 &error)) {
    return Fail(error);
  }
  const std::string checkpoints = out.partial() + "/" + kCheckpoints;
  if (!MakeDirectories(checkpoints, &error)) return Fail(error);
  bool flagged = false;
  int status = 0;
  if (joint || inputs.size() == 1) {
    status = FitInto(out.partial(), out.out_dir(), checkpoints + "/fit.bin", exposures, set.quality,
                     config, paths, &flagged);
  } else {
    // Separate fits: one folder per file.
    const std::vector<std::string> names = SeparateFolders(paths);
    nlohmann::json summary = nlohmann::json::array();
    for (size_t i = 0; i < inputs.size(); ++i) {
      const std::string dir = out.out_dir() + "/" + names[i];
      const std::string staged = out.partial() + "/" + names[i];
      // The set checks' findings about this exposure (compression against the others).
      Quality own;
      for (const Finding& f : set.quality.findings) {
        if (f.exposure == static_cast<int>(i)) own.Add(f.code, f.severity, f.message);
      }
      const int s = FitInto(staged, dir, checkpoints + "/" + names[i] + ".bin", {exposures[i]},
                            own, config, {paths[i]}, &flagged);
      summary.push_back({{"file", paths[i]}, {"folder", dir}, {"ok", s == 0}});
      if (s != 0) status = s;
    }
    std::string werr;
    if (!WriteRunRecord(out.partial(), "fit", {{"files", paths}, {"folders", summary}},
                        config.fit.mcmc.seed, &werr)) {
      return Fail(werr);
    }
  }
  // A run that wrote nothing (its one fit failed) leaves the earlier results in place.
  if (!IsCcdpsfOutput(out.partial())) return status;
  if (!WriteRunConfig(out.partial(), config, nlohmann::json::object(), &error) ||
      !out.Commit({kCheckpoints}, &error)) {
    return Fail(error);
  }
  if (status == 0 && flagged && FLAGS_strict) return kExitStrict;
  return status;
}

}  // namespace

Option PtcOption() {
  return {"ptc", "",
          "DIR/ptc.json of `ccdpsf ptc` on flats of this sensor: its a_10, a_01, a_11 (with their "
          "covariance) become a Gaussian prior on boundary_shift's (needs "
          "--effects=boundary_shift); fit.json then also holds the spots' own a_ij against the "
          "flats' (boundary_shift_vs_flats)"};
}

Command FitCommand() {
  const fit::FitConfig d;  // the library's defaults, which fit's flags default to
  std::vector<Option> options = {
      {"out", "", "Output folder (required); replaced as a whole by the run's results"},
      {"config", "",
       "FIT.json with the fit's options (priors, MAP starts, MCMC settings, calibration, "
       "keyword map, \"flags\"); a run's OUT/config.json repeats it; flags given override it"},
      {"plot_format", "png", "Format of the plots: png, pdf or svg"},
      {"plots", "all",
       "Which fit reports get their pictures drawn: all, flagged (those whose verdict is not "
       "ok; for batches of separate fits) or none; every report keeps the pictures' data and "
       "gnuplot scripts"},
      {"truth", "",
       "truth.json of simulated data, drawn on the plots (not given: a truth.json in the folder "
       "holding all the inputs, if there is one)"},
      {"joint", d.joint ? "true" : "false",
       "One joint fit of all files (CCD widths, intensity, defocus and Airy radius shared; a "
       "position per exposure) instead of one fit per file"},
      {"through_focus", "false",
       "With --joint, fit the files as a through-focus series: Gaussian defocus sigma = rate x "
       "|FOCUSPOS - z0| per exposure (rate and best focus z0 fitted), CCD kernel shared; "
       "identifies the CCD widths. Not given: on when every file has FOCUSPOS with >= 3 "
       "distinct values (integrated sampling, Gaussian defocus)"},
      {"sampling", model::ToString(d.model.model.sampling),
       "Model sampling: integrated (exact pixel integral) or pixel_centre (the 2015 code's "
       "discretisation)"},
      {"defocus", model::ToString(d.model.model.defocus), "Defocus kernel: gaussian or pillbox"},
      {"likelihood", fit::ToString(d.model.likelihood),
       "gaussian (the paper's, with model-dependent variance) or poisson_normal (exact, for "
       "low signal)"},
      {"seed", "1", "Random seed of the MCMC (same seed, same chain)"},
      {"walkers", std::to_string(d.fit.num_walkers),
       "MCMC walkers (0: max(2 x ensemble dimension + 2, target_ess / 50))"},
      {"max_steps", std::to_string(d.fit.mcmc.max_steps),
       "MCMC step limit (the chain stops there converged or not)"},
      {"target_ess", NumberText(d.fit.mcmc.target_ess),
       "Effective sample size every parameter must reach for the MCMC to have converged"},
      {"threads", std::to_string(d.fit.mcmc.num_threads),
       "Threads of the MAP search and the MCMC (the results are the same for any number)"},
      {"mcmc", d.fit.run_mcmc ? "true" : "false", "Run the MCMC (--nomcmc: MAP and Laplace only)"},
      {"flux", "auto",
       "How the exposures of a joint fit share the light: auto (chosen from the data and "
       "said), shared, per_exposure or exptime_scaled"},
      {"effects", "",
       "Effects of the catalogue fitted with the spot, comma-separated (" +
           fit::FittableEffectNames(", ") +
           "; `ccdpsf effects` describes them), with the catalogue's priors (FIT.json "
           "\"effects\" sets others)"},
      {"mixed_wavelengths", "false",
       "Let a joint fit share one PSF across exposures at different wavelengths"},
      {"outliers", fit::OutlierOptions().enabled ? "true" : "false",
       "Mask pixels the fitted model cannot explain (cosmic rays, hot pixels) and refit"},
      {"strict", "false",
       "Exit with code 3 when a fit's verdict is suspect or invalid (for pipelines); without "
       "it a completed run exits 0 whatever the verdict"},
      {"quiet", "false",
       "Print only errors, warnings and each fit's closing line (no notes, no MCMC progress)"},
      {"resume", "false",
       "Continue a run that was killed, into the same --out with the same inputs and options: "
       "each MCMC from its last checkpoint, ending with the chain of an uninterrupted run"},
      {"checkpoint_s", "30", "Seconds between MCMC checkpoints (for --resume)"},
      PtcOption()};
  for (const Option& o : InputOptions()) options.push_back(o);
  return {"fit", "ccdpsf fit --out=DIR [--joint] [--config=FIT.json] [options] FILE.fits...",
          "Fit the spot model: MAP (Ceres), Laplace covariance, MCMC credible intervals.", options,
          RunFit};
}

}  // namespace ccdpsf::tools
