// ccdpsf diagnose: find the effect the model is missing (diagnose/diagnose.h).
#include <cstdio>
#include <sstream>

#include "ccdpsf/diagnose/diagnose.h"
#include "ccdpsf/diagnose/diagnose_report.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(out);
DECLARE_uint64(seed);
DECLARE_int32(threads);
DEFINE_int32(max_rounds, 3, "diagnose: rounds of testing (each may name one effect)");
DEFINE_int32(predictive_sims, 50,
             "diagnose: simulations of each fitted model for the predictive p-values (0: none)");
DEFINE_double(alpha, 0.01,
              "diagnose: family-wise false-claim rate per round (Bonferroni over the candidates)");
DEFINE_string(flux, "auto",
              "diagnose: auto (a flux per exposure when the set spans several intensities), "
              "shared or per_exposure");
DEFINE_string(baseline, "paper",
              "diagnose: paper (the paper's model) or no_defocus (without the defocus, which "
              "then becomes a candidate); add effects with +, e.g. paper+background");
DEFINE_string(candidates, "",
              "diagnose: comma-separated catalogue names that may be named (default: all)");
DEFINE_bool(thresholds, false,
            "diagnose: simulate the detection threshold of every effect not found (slow)");
DEFINE_int32(threshold_sims, 10, "diagnose: simulations per strength for --thresholds");

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

int RunDiagnose(const std::vector<std::string>& files) {
  if (FLAGS_out.empty()) return Fail("diagnose needs --out=DIR");
  if (files.empty()) return Fail("diagnose needs at least one FITS file");
  fit::FitConfig config;
  std::string error;
  if (!ResolveFitConfig(&config, &error)) return Fail(error);
  config.model.through_focus = false;
  diagnose::DiagnoseOptions options;
  options.max_rounds = FLAGS_max_rounds;
  options.predictive.num_simulations = FLAGS_predictive_sims;
  options.predictive.seed = FLAGS_seed;
  options.alpha = FLAGS_alpha;
  options.fit.num_threads = FLAGS_threads;
  options.map.num_threads = FLAGS_threads;
  options.compute_thresholds = FLAGS_thresholds;
  options.thresholds.num_simulations = FLAGS_threshold_sims;
  options.thresholds.seed = FLAGS_seed;
  options.progress = [](const std::string& line) {
    std::fprintf(stderr, "ccdpsf diagnose: %s\n", line.c_str());
  };
  if (FLAGS_flux == "auto") {
    options.flux = diagnose::FluxChoice::kAuto;
  } else if (FLAGS_flux == "shared") {
    options.flux = diagnose::FluxChoice::kShared;
  } else if (FLAGS_flux == "per_exposure") {
    options.flux = diagnose::FluxChoice::kPerExposure;
  } else {
    return Fail("--flux must be auto, shared or per_exposure");
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
  if (!ParseKinds(FLAGS_candidates, &options.candidates, &error)) {
    return Fail("--candidates: " + error);
  }
  if (!options.IsValid(&error)) return Fail(error);
  std::vector<Stamp> stamps;
  for (const std::string& f : files) {
    auto e = LoadExposure(f, config.calibration, &error);
    if (!e) return Fail(error);
    stamps.push_back(std::move(e->stamp));
  }
  auto base = fit::FitModel::Create(stamps, config.model, &error);
  if (!base) return Fail(error);
  diagnose::DiagnoseResult result;
  if (!diagnose::RunDiagnosis(*base, options, &result, &error)) return Fail(error);
  nlohmann::json run = {{"command", "diagnose"},
                        {"files", files},
                        {"options",
                         {{"fit", fit::FitConfigJson(config)},
                          {"max_rounds", options.max_rounds},
                          {"predictive_sims", options.predictive.num_simulations},
                          {"alpha", options.alpha},
                          {"flux", FLAGS_flux},
                          {"baseline", FLAGS_baseline},
                          {"candidates", FLAGS_candidates},
                          {"thresholds", options.compute_thresholds},
                          {"threshold_sims", options.thresholds.num_simulations}}},
                        {"seed", FLAGS_seed},
                        {"software", SoftwareVersions()}};
  std::vector<std::string> warnings;
  if (!diagnose::WriteDiagnoseReport(FLAGS_out, *base, result, options, run, &warnings, &error)) {
    return Fail(error);
  }
  for (const std::string& w : warnings) std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  std::string named;
  for (model::EffectKind k : result.named) named += (named.empty() ? "" : ", ") + model::ToString(k);
  std::printf("%s; chi2/dof %.4g -> %.4g; results in %s/diagnose.json (report.md, plots)\n",
              named.empty() ? "no missing effect" : ("missing: " + named).c_str(),
              result.rounds.front().statistics.chi2_per_dof,
              result.rounds.back().statistics.chi2_per_dof, FLAGS_out.c_str());
  return 0;
}

}  // namespace

Command DiagnoseCommand() {
  return {"diagnose",
          "ccdpsf diagnose --out=DIR [--baseline=paper] [--max_rounds=3] [options] FILE.fits...",
          "Find the physical effect the model is missing: fit, test the catalogue, add, repeat.",
          {"out", "config", "sampling", "defocus", "seed", "threads", "gain_e_per_adu",
           "read_noise_e", "bias_adu", "saturation_adu", "stamp_size", "spot_x_px", "spot_y_px",
           "max_rounds", "predictive_sims", "alpha", "flux", "baseline", "candidates",
           "thresholds", "threshold_sims"},
          RunDiagnose};
}

}  // namespace ccdpsf::tools
