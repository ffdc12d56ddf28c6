// ccdpsf fit: MAP, Laplace and MCMC for one exposure, several separately, or jointly.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
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
DEFINE_bool(joint, false,
            "fit: one joint fit of all files (CCD widths, intensity, defocus and Airy radius "
            "shared; a position per exposure) instead of one fit per file");
DEFINE_bool(through_focus, false,
            "fit: with --joint, fit the files as a through-focus series: Gaussian defocus "
            "sigma = rate x |FOCUSPOS - z0| per exposure (rate and best focus z0 fitted), CCD "
            "kernel shared; identifies the CCD widths. Default: on when every file has "
            "FOCUSPOS with >= 3 distinct values (integrated sampling, Gaussian defocus)");
DEFINE_string(likelihood, "gaussian",
              "fit: gaussian (the paper's, with model-dependent variance) or poisson_normal "
              "(exact, for low signal)");
DEFINE_uint64(seed, 1, "fit: random seed of the MCMC");
DEFINE_int32(walkers, 0,
             "fit: MCMC walkers (0: max(2 x ensemble dimension + 2, target_ess / 50))");
DEFINE_int32(max_steps, 20000, "fit: MCMC step limit");
DEFINE_double(target_ess, 1000,
              "fit: effective sample size every parameter must reach (trend: 400 unless given)");
DEFINE_int32(threads, 2, "fit: threads for the MCMC; trend: groups fitted at a time; diagnose: Ceres threads and predictive simulations run at a time");
DEFINE_bool(mcmc, true, "fit: run the MCMC (--nomcmc: MAP and Laplace only)");
DEFINE_string(flux, "auto",
              "How the exposures of a joint fit share the light: auto (chosen from the data "
              "and said), shared, per_exposure or (fit, trend) exptime_scaled");
DEFINE_bool(mixed_wavelengths, false,
            "Let a joint fit share one PSF across exposures at different wavelengths");
DEFINE_bool(strict, false,
            "Exit with code 3 when a completed fit's verdict is suspect or invalid (for "
            "pipelines); without it a completed run exits 0 whatever the verdict");
DEFINE_bool(resume, false,
            "fit, trend: continue a run that was killed, into the same --out with the same "
            "inputs and options (fit: each MCMC from its last checkpoint, ending with the chain "
            "of an uninterrupted run; trend: the groups already finished are kept)");
DEFINE_double(checkpoint_s, 30, "fit: seconds between MCMC checkpoints (for --resume)");
DEFINE_bool(outliers, true,
            "Mask pixels the fitted model cannot explain (cosmic rays, hot pixels) and refit");

namespace ccdpsf::tools {

// Defaults <- FIT.json <- flags given on the command line.
bool ResolveFitConfig(fit::FitConfig* c, std::string* error) {
  c->fit.mcmc.seed = FLAGS_seed;
  if (!FLAGS_config.empty() && !fit::LoadFitConfig(FLAGS_config, c, error)) return false;
  if (FlagGiven("sampling") && !model::ParseSampling(FLAGS_sampling, &c->model.model.sampling)) {
    *error = "--sampling must be integrated or pixel_centre";
    return false;
  }
  if (FlagGiven("defocus") && !model::ParseDefocusKind(FLAGS_defocus, &c->model.model.defocus)) {
    *error = "--defocus must be gaussian or pillbox";
    return false;
  }
  if (FlagGiven("likelihood") && !fit::ParseLikelihoodKind(FLAGS_likelihood, &c->model.likelihood)) {
    *error = "--likelihood must be gaussian or poisson_normal";
    return false;
  }
  if (FlagGiven("joint")) c->joint = FLAGS_joint;
  if (FlagGiven("through_focus")) {
    c->model.through_focus = FLAGS_through_focus;
    c->through_focus_given = true;
  }
  if (FlagGiven("seed")) c->fit.mcmc.seed = FLAGS_seed;
  if (FlagGiven("walkers")) c->fit.num_walkers = FLAGS_walkers;
  if (FlagGiven("max_steps")) c->fit.mcmc.max_steps = FLAGS_max_steps;
  if (FlagGiven("target_ess")) c->fit.mcmc.target_ess = FLAGS_target_ess;
  if (FlagGiven("threads")) c->fit.mcmc.num_threads = FLAGS_threads;
  if (FlagGiven("mcmc")) c->fit.run_mcmc = FLAGS_mcmc;
  if (FlagGiven("stamp_size")) c->calibration.stamp_size = FLAGS_stamp_size;
  if (!c->calibration.IsValid(error)) return false;
  if (FlagGiven("flux") && FLAGS_flux != "auto") {
    if (!fit::ParseFluxMode(FLAGS_flux, &c->model.flux)) {
      *error = "--flux must be auto, shared, per_exposure or exptime_scaled";
      return false;
    }
    c->flux_given = true;
  } else if (FlagGiven("flux")) {
    c->flux_given = false;
  }
  if (!fit::CheckMcmcSettings(c->fit.num_walkers, c->fit.mcmc.max_steps, c->fit.mcmc.num_threads,
                              c->fit.mcmc.target_ess, "--", error)) {
    return false;
  }
  if (c->model.model.sampling == model::Sampling::kPixelCentre &&
      c->model.model.defocus != model::DefocusKind::kGaussian) {
    *error = "pixel_centre sampling has only the Gaussian defocus of the 2015 code";
    return false;
  }
  return true;
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
  for (const std::string& note : fitted.notes) {
    std::fprintf(stderr, "ccdpsf: note: %s\n", note.c_str());
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
  if (!fit::WriteFitReport(dir, fitted, run, &warnings, &error, report_options)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  const fit::FitResult& result = fitted.result;
  std::printf("%s: chi2/dof %.4g, %s; verdict %s; results in %s/fit.json (report.md, plots)\n",
              files.size() == 1 ? files[0].c_str() : "joint fit", result.map.chi2 / result.map.dof,
              result.have_mcmc ? (result.chain.converged ? "MCMC converged" : "MCMC NOT converged")
                               : "no MCMC",
              fitted.quality.OneLine().c_str(), shown.c_str());
  if (fitted.quality.Worst() != Severity::kNote) *flagged = true;
  return 0;
}

// Output folders of separate fits, one per file: the file's stem, made unique with its
// parent folders' names when two files share a stem (a second exposure_000.fits from
// another folder must not overwrite the first).
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
  // Still equal (the same path given twice is refused earlier): number them.
  for (size_t i = 0; i < names.size(); ++i) {
    for (size_t j = i + 1; j < names.size(); ++j) {
      if (names[i] == names[j]) names[j] += "_" + std::to_string(j);
    }
  }
  return names;
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
  if (!LoadExposureSet(inputs, set_options, &set, &error)) return Fail(error);
  std::vector<Exposure>& exposures = set.exposures;
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
        std::fprintf(stderr,
                     "ccdpsf: note: the %zu files carry focus positions with %ld distinct "
                     "values: fitting them as a through-focus series (defocus = rate x |z - "
                     "z0|, CCD kernel fixed; --nothrough_focus to turn off)\n",
                     inputs.size(), distinct);
      } else {
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
  if (!out.Commit({kCheckpoints}, &error)) return Fail(error);
  if (status == 0 && flagged && FLAGS_strict) return kExitStrict;
  return status;
}

}  // namespace

std::vector<const char*> FitFlagNames() {
  std::vector<const char*> names = {"out",        "config",    "joint",     "through_focus",
                                    "sampling",   "defocus",   "likelihood", "seed",
                                    "walkers",    "max_steps", "target_ess", "threads",
                                    "mcmc",       "flux",      "mixed_wavelengths", "strict",
                                    "outliers"};
  for (const char* n : InputFlagNames()) names.push_back(n);
  return names;
}

Command FitCommand() {
  return {"fit",
          "ccdpsf fit --out=DIR [--joint] [--config=FIT.json] [options] FILE.fits...",
          "Fit the spot model: MAP (Ceres), Laplace covariance, MCMC credible intervals.",
          [] {
            std::vector<const char*> names = FitFlagNames();
            names.push_back("resume");
            names.push_back("checkpoint_s");
            return names;
          }(),
          RunFit};
}

}  // namespace ccdpsf::tools
