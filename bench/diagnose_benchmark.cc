// The missing-effect workflow on many simulated sets: what the unit tests cannot afford.
// Run: ./build/diagnose_benchmark [--clean_sets=40] [--thresholds] [--threshold_sims=10]
//   1. per catalogue effect, a five-exposure set (paper's simulation, ~1.5e5 e- peak) with the
//      effect hidden at the strength of tests/diagnose_test.cc: named?, chi2/dof before and
//      after, the effect's parameters against the truth, wall time of the full diagnosis
//      (50 predictive simulations per round, each refitted);
//   2. the rate of "no missing effect" on clean three-exposure sets (predictive simulations
//      off: the decision does not use them);
//   3. with --thresholds, the detection threshold of every effect for a three-exposure set
//      (ComputeDetectionThreshold: weakest strength named in >= 80 % of simulations).
// Not a Google Benchmark timing loop: one pass, printed as a table.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "ccdpsf/diagnose/diagnose.h"
#include "support/simulated_stamps.h"

namespace {

using namespace ccdpsf;
using namespace ccdpsf::diagnose;
using model::EffectKind;

struct Case {
  std::string name;
  void (*inject)(SimulationConfig*);
  std::vector<std::pair<std::string, double>> truth;
  bool no_defocus = false;  // data in focus, baseline without defocus
};

void SetIntensities(SimulationConfig* c) {
  const double flux[] = {4.0e5, 2.8e5, 2.0e5, 1.4e5, 1.0e5};
  for (size_t k = 0; k < c->exposures.size(); ++k) c->exposures[k].flux_e = flux[k % 5];
}

std::string Named(const DiagnoseResult& r) {
  std::string s;
  for (EffectKind k : r.named) s += (s.empty() ? "" : "+") + model::ToString(k);
  return s.empty() ? "none" : s;
}

}  // namespace

int main(int argc, char** argv) {
  int clean_sets = 40, threshold_sims = 10;
  bool thresholds = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strncmp(argv[i], "--clean_sets=", 13) == 0) clean_sets = std::atoi(argv[i] + 13);
    if (std::strcmp(argv[i], "--thresholds") == 0) thresholds = true;
    if (std::strncmp(argv[i], "--threshold_sims=", 17) == 0) threshold_sims = std::atoi(argv[i] + 17);
  }
  const std::vector<Case> cases = {
      {"background", [](SimulationConfig* c) { c->effects.background = model::BackgroundParams{20.0}; },
       {{"background.pedestal_e", 20.0}}},
      {"ipc", [](SimulationConfig* c) { c->effects.ipc = model::IpcParams{0.01}; }, {{"ipc.alpha", 0.01}}},
      {"serial_cti", [](SimulationConfig* c) { c->effects.serial_cti = model::CtiParams{5e-3, 1.5}; },
       {{"serial_cti.trail_fraction", 5e-3}, {"serial_cti.trail_length_px", 1.5}}},
      {"parallel_cti", [](SimulationConfig* c) { c->effects.parallel_cti = model::CtiParams{5e-3, 1.5}; },
       {{"parallel_cti.trail_fraction", 5e-3}, {"parallel_cti.trail_length_px", 1.5}}},
      {"halo", [](SimulationConfig* c) { c->effects.halo = model::HaloParams{0.03, 2.5}; },
       {{"halo.fraction", 0.03}, {"halo.sigma_px", 2.5}}},
      {"nonlinearity (5 intensities; default 1e-7, below detection)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->effects.nonlinearity = model::NonlinearityParams{1e-7};
       },
       {{"nonlinearity.beta_per_e", 1e-7}}},
      {"brighter_fatter (5 intensities, in focus)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->defocus_px = 0.0;
         c->effects.brighter_fatter = model::BrighterFatterParams{4e-7, 4e-7};
       },
       {{"brighter_fatter.slope_x_px_per_e", 4e-7}, {"brighter_fatter.slope_y_px_per_e", 4e-7}},
       true},
      {"jitter (0, .1, .15, .2, .25 px)",
       [](SimulationConfig* c) {
         const double s[] = {0.0, 0.1, 0.15, 0.2, 0.25};
         for (size_t k = 0; k < c->exposures.size(); ++k) {
           c->exposures[k].jitter = model::JitterParams{s[k % 5], s[k % 5], 0, 0};
         }
       },
       {{"jitter.var_x_px2.4", 0.0625}, {"jitter.var_y_px2.4", 0.0625}}},
      {"serial_cti + background",
       [](SimulationConfig* c) {
         c->effects.serial_cti = model::CtiParams{5e-3, 1.5};
         c->effects.background = model::BackgroundParams{20.0};
       },
       {{"serial_cti.trail_fraction", 5e-3}, {"background.pedestal_e", 20.0}}},
      {"brighter_fatter + serial_cti (5 intensities, in focus)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->defocus_px = 0.0;
         c->effects.brighter_fatter = model::BrighterFatterParams{4e-7, 4e-7};
         c->effects.serial_cti = model::CtiParams{5e-3, 1.5};
       },
       {{"brighter_fatter.slope_x_px_per_e", 4e-7}, {"serial_cti.trail_fraction", 5e-3}},
       true},
      {"defocus_offset (0.1 px; not identifiable)",
       [](SimulationConfig* c) { c->effects.defocus_offset = model::DefocusOffsetParams{0.1, 0.0}; },
       {}},
      {"serial_cti at the default 5e-4 (below detection)",
       [](SimulationConfig* c) { c->effects.serial_cti = model::CtiParams{5e-4, 1.5}; },
       {}},
  };
  std::printf("# 1. Five-exposure sets, one hidden effect (50 predictive simulations per round)\n");
  std::printf("%-52s %-26s %8s %8s %7s  parameters (fit +- sd | truth)\n", "case", "named",
              "chi2 bef", "chi2 aft", "sec");
  int seed = 100;
  for (const Case& c : cases) {
    SimulationConfig config = testing_support::PaperConfig(model::Sampling::kIntegrated, 5, seed);
    c.inject(&config);
    const auto stamps = testing_support::SimulateStamps(config, seed + 1);
    seed += 2;
    fit::FitModelOptions fo;
    std::string error;
    auto base = fit::FitModel::Create(stamps, fo, &error);
    DiagnoseOptions options;
    options.baseline_defocus = !c.no_defocus;
    DiagnoseResult r;
    if (!base || !RunDiagnosis(*base, options, &r, &error)) {
      std::printf("%-52s failed: %s\n", c.name.c_str(), error.c_str());
      continue;
    }
    std::printf("%-52s %-26s %8.4f %8.4f %7.1f ", c.name.c_str(), Named(r).c_str(),
                r.rounds.front().statistics.chi2_per_dof, r.rounds.back().statistics.chi2_per_dof,
                r.seconds);
    const RoundResult& last = r.rounds.back();
    for (const auto& [name, value] : c.truth) {
      for (size_t i = 0; i < last.names.size(); ++i) {
        if (last.names[i] != name) continue;
        std::printf(" %s %.4g +- %.2g | %.4g (%.1f sd);", name.c_str(), last.fit.p[i],
                    last.fit.laplace.sd[i], value, (last.fit.p[i] - value) / last.fit.laplace.sd[i]);
      }
    }
    std::printf("  [chi2/dof sd %.4f]\n", last.statistics.chi2_per_dof_sd);
    std::fflush(stdout);
  }

  std::printf("\n# 2. Clean three-exposure sets: no missing effect?\n");
  int clean = 0;
  std::vector<std::string> claims;
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < clean_sets; ++s) {
    SimulationConfig config = testing_support::PaperConfig(model::Sampling::kIntegrated, 3, 1000 + s);
    const auto stamps = testing_support::SimulateStamps(config, 5000 + s);
    std::string error;
    auto base = fit::FitModel::Create(stamps, fit::FitModelOptions(), &error);
    DiagnoseOptions options;
    options.predictive.num_simulations = 0;
    DiagnoseResult r;
    if (!base || !RunDiagnosis(*base, options, &r, &error)) {
      claims.push_back("failed: " + error);
      continue;
    }
    if (r.named.empty()) {
      ++clean;
    } else {
      claims.push_back(Named(r));
    }
  }
  std::printf("no missing effect in %d of %d sets (%.1f %%); %.1f s\n", clean, clean_sets,
              100.0 * clean / std::max(1, clean_sets),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  for (const std::string& c : claims) std::printf("  claimed: %s\n", c.c_str());

  if (thresholds) {
    std::printf("\n# 3. Detection thresholds, three-exposure paper set (>= 80 %% of %d simulations)\n",
                threshold_sims);
    SimulationConfig config = testing_support::PaperConfig(model::Sampling::kIntegrated, 3, 77);
    const auto stamps = testing_support::SimulateStamps(config, 78);
    SimulationConfig multi = config;
    for (int k = 0; k < 3; ++k) multi.exposures[k].flux_e = std::vector<double>{4e5, 2e5, 1e5}[k];
    const auto multi_stamps = testing_support::SimulateStamps(multi, 79);
    for (EffectKind kind : {EffectKind::kBackground, EffectKind::kIpc, EffectKind::kSerialCti,
                            EffectKind::kParallelCti, EffectKind::kHalo, EffectKind::kJitter,
                            EffectKind::kNonlinearity}) {
      std::string error;
      auto base = fit::FitModel::Create(kind == EffectKind::kNonlinearity ? multi_stamps : stamps,
                                        fit::FitModelOptions(), &error);
      DiagnoseOptions options;
      options.predictive.num_simulations = 0;
      options.thresholds.num_simulations = threshold_sims;
      DiagnoseResult r;
      RunDiagnosis(*base, options, &r, &error);
      DetectionThreshold t;
      ComputeDetectionThreshold(*base, r.rounds.back().spec, r.rounds.back().fit.p, kind,
                                options.alpha / 8, options, &t, &error);
      std::printf("%-14s %-32s threshold %-10.3g rates:", model::ToString(kind).c_str(),
                  t.parameter.c_str(), t.threshold);
      for (size_t i = 0; i < t.strengths.size(); ++i) std::printf(" %.3g:%.2f", t.strengths[i], t.rates[i]);
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  return 0;
}
