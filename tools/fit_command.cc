// ccdpsf fit: MAP, Laplace and MCMC for one exposure, several separately, or jointly.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DECLARE_string(sampling);
DECLARE_string(defocus);
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
DEFINE_double(gain_e_per_adu, 0, "fit: gain [e-/ADU], overrides GAIN");
DEFINE_double(read_noise_e, 0, "fit: read noise [e-], overrides RDNOISE");
DEFINE_double(bias_adu, 0, "fit: bias [ADU], overrides BIASLVL / BIASSEC");
DEFINE_double(saturation_adu, 0, "fit: saturation [ADU], overrides SATURATE");
DEFINE_int32(stamp_size, 21, "fit: stamp side [px]");
DEFINE_double(spot_x_px, 0, "fit: spot x (frame pixels); with --spot_y_px skips spot finding");
DEFINE_double(spot_y_px, 0, "fit: spot y (frame pixels)");

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
  CalibrationOptions& k = c->calibration;
  if (FlagGiven("gain_e_per_adu")) k.gain_e_per_adu = FLAGS_gain_e_per_adu;
  if (FlagGiven("read_noise_e")) k.read_noise_e = FLAGS_read_noise_e;
  if (FlagGiven("bias_adu")) k.bias_adu = FLAGS_bias_adu;
  if (FlagGiven("saturation_adu")) k.saturation_adu = FLAGS_saturation_adu;
  if (FlagGiven("stamp_size")) k.stamp_size = FLAGS_stamp_size;
  if (FlagGiven("spot_x_px")) k.spot_x_px = FLAGS_spot_x_px;
  if (FlagGiven("spot_y_px")) k.spot_y_px = FLAGS_spot_y_px;
  if (!k.IsValid(error)) return false;
  if (c->fit.num_walkers < 0 || c->fit.mcmc.max_steps < 1 || c->fit.mcmc.num_threads < 1 ||
      !(c->fit.mcmc.target_ess >= 0)) {
    *error = "--walkers >= 0, --max_steps >= 1, --threads >= 1 and --target_ess >= 0 required";
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

// One fit (single exposure or joint set) into out_dir. Returns the exit code.
int FitInto(const std::string& out_dir, const std::vector<Exposure>& exposures,
            const fit::FitConfig& config, const std::vector<std::string>& files) {
  std::vector<Stamp> stamps;
  std::vector<CalibrationReport> calibration;
  for (const Exposure& e : exposures) {
    stamps.push_back(e.stamp);
    calibration.push_back(e.report);
  }
  std::string error;
  auto model = fit::FitModel::Create(stamps, config.model, &error);
  if (!model) return Fail(error);
  fit::FitOptions options = config.fit;
  options.mcmc.progress_label = out_dir;
  fit::FitResult result;
  if (!fit::RunFit(*model, options, &result, &error)) return Fail(out_dir + ": " + error);
  nlohmann::json run = {{"command", "fit"},
                        {"files", files},
                        {"options", fit::FitConfigJson(config)},
                        {"seed", config.fit.mcmc.seed},
                        {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  if (!fit::WriteFitReport(out_dir, *model, result, calibration, run, &warnings, &error)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  std::printf("%s: chi2/dof %.4g, %s; results in %s/fit.json (report.md, plots)\n",
              files.size() == 1 ? files[0].c_str() : "joint fit", result.map.chi2 / result.map.dof,
              result.have_mcmc ? (result.chain.converged ? "MCMC converged" : "MCMC NOT converged")
                               : "no MCMC",
              out_dir.c_str());
  return 0;
}

int RunFit(const std::vector<std::string>& files) {
  if (FLAGS_out.empty()) return Fail("fit needs --out=DIR");
  if (files.empty()) return Fail("fit needs at least one FITS file");
  fit::FitConfig config;
  std::string error;
  if (!ResolveFitConfig(&config, &error)) return Fail(error);
  std::vector<Exposure> exposures;
  for (const std::string& f : files) {
    auto e = LoadExposure(f, config.calibration, &error);
    if (!e) return Fail(error);
    exposures.push_back(std::move(*e));
  }
  if (config.model.through_focus && !config.joint && files.size() > 1) {
    return Fail("through_focus fits a series jointly: add --joint");
  }
  if (config.joint && files.size() > 1 && !config.through_focus_given) {
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
                     "ccdpsf: note: the %zu files carry FOCUSPOS with %ld distinct values: "
                     "fitting them as a through-focus series (defocus = rate x |z - z0|, CCD "
                     "kernel fixed; --nothrough_focus to turn off)\n",
                     files.size(), distinct);
      } else {
        std::fprintf(stderr,
                     "ccdpsf: note: the %zu files carry FOCUSPOS with %ld distinct values, but "
                     "the through-focus model needs integrated sampling and a Gaussian "
                     "defocus: fitting them with one shared defocus\n",
                     files.size(), distinct);
      }
    }
  }
  if (config.joint || files.size() == 1) return FitInto(FLAGS_out, exposures, config, files);
  // Separate fits: one folder per file, named after it.
  int status = 0;
  nlohmann::json summary = nlohmann::json::array();
  for (size_t i = 0; i < files.size(); ++i) {
    const std::string dir = FLAGS_out + "/" + fs::path(files[i]).stem().string();
    const int s = FitInto(dir, {exposures[i]}, config, {files[i]});
    summary.push_back({{"file", files[i]}, {"folder", dir}, {"ok", s == 0}});
    if (s != 0) status = s;
  }
  std::string werr;
  if (!WriteRunRecord(FLAGS_out, "fit", {{"files", files}, {"folders", summary}},
                      config.fit.mcmc.seed, &werr)) {
    return Fail(werr);
  }
  return status;
}

}  // namespace

Command FitCommand() {
  return {"fit",
          "ccdpsf fit --out=DIR [--joint] [--config=FIT.json] [options] FILE.fits...",
          "Fit the spot model: MAP (Ceres), Laplace covariance, MCMC credible intervals.",
          {"out", "config", "joint", "through_focus", "sampling", "defocus", "likelihood", "seed", "walkers",
           "max_steps", "target_ess", "threads", "mcmc", "gain_e_per_adu", "read_noise_e",
           "bias_adu", "saturation_adu", "stamp_size", "spot_x_px", "spot_y_px"},
          RunFit};
}

}  // namespace ccdpsf::tools
