// The missing-effect workflow on many simulated sets: what the unit tests cannot afford.
// Run: ./build/diagnose_benchmark [--clean_sets=40] [--thresholds] [--threshold_sims=10]
//                                 [--no_sets] [--only=serial_cti,ipc] [--clean_pixel_centre]
//                                 [--clean_only] [--cases=TEXT] [--threads=N]
//   1. per catalogue effect, a five-exposure set (paper's simulation, ~1.5e5 e- peak; five
//      intensities from 1.5e5 down to 3.7e4 e- peak for nonlinearity and brighter_fatter)
//      with the effect hidden at its realistic strength (the catalogue default) or, where
//      that is below detection, also at the measured threshold: named?, chi2/dof before and
//      after, the effect's parameters against the truth, wall time of the full diagnosis
//      (50 predictive simulations per round, each refitted);
//   2. the rate of "no missing effect" on clean three-exposure sets (predictive simulations
//      off: the decision does not use them); --clean_pixel_centre: in pixel_centre sampling;
//   3. with --thresholds, the detection threshold of every effect for a five-exposure set
//      (ComputeDetectionThreshold: weakest strength, on a grid of 1/64 to 16 times the
//      catalogue default, named in >= 80 % of simulations). --only restricts it to the
//      effects whose names appear in the list; --no_sets skips sections 1 and 2.
// --threads=N: as `ccdpsf diagnose --threads` (Ceres threads, predictive simulations N at a
// time; default 1). --cases=TEXT runs only the section-1 sets whose name contains TEXT (same data as in the full
// run: every set keeps its seed). Not a Google Benchmark timing loop: one pass, printed as a table.
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
  bool in_focus = false;  // data without defocus
  bool baseline_defocus = true;
  model::Sampling sampling = model::Sampling::kIntegrated;
};

void SetIntensities(SimulationConfig* c) {
  const double flux[] = {4.0e5, 2.8e5, 2.0e5, 1.4e5, 1.0e5};
  for (size_t k = 0; k < c->exposures.size(); ++k) c->exposures[k].flux_e = flux[k % 5];
}

// A threshold study: the set it is measured on and the baseline.
struct ThresholdCase {
  std::string label;
  EffectKind kind;
  model::Sampling sampling = model::Sampling::kIntegrated;
  bool multi_intensity = false;   // five intensities (SetIntensities)
  bool no_defocus = false;        // data in focus
  bool baseline_defocus = true;
};

std::vector<ThresholdCase> ThresholdCases() {
  using model::Sampling;
  return {
      {"background", EffectKind::kBackground},
      {"ipc", EffectKind::kIpc},
      {"serial_cti", EffectKind::kSerialCti},
      {"parallel_cti", EffectKind::kParallelCti},
      {"halo", EffectKind::kHalo},
      {"jitter (all but the reference)", EffectKind::kJitter},
      {"nonlinearity (5 intensities)", EffectKind::kNonlinearity, Sampling::kIntegrated, true},
      {"brighter_fatter (5 int., in focus)", EffectKind::kBrighterFatter, Sampling::kIntegrated,
       true, true, false},
      {"brighter_fatter (5 int., defocus)", EffectKind::kBrighterFatter, Sampling::kIntegrated,
       true},
      {"defocus (pixel_centre, no baseline defocus)", EffectKind::kDefocus,
       Sampling::kPixelCentre, false, true, false},
      {"defocus_offset (pixel_centre)", EffectKind::kDefocusOffset, Sampling::kPixelCentre},
  };
}

std::string Named(const DiagnoseResult& r) {
  std::string s;
  for (EffectKind k : r.named) s += (s.empty() ? "" : "+") + model::ToString(k);
  return s.empty() ? "none" : s;
}

}  // namespace

int main(int argc, char** argv) {
  int clean_sets = 40, threshold_sims = 10;
  model::Sampling clean_sampling = model::Sampling::kIntegrated;
  bool thresholds = false, sets = true, cases_too = true;
  std::string only;  // --only=serial_cti,ipc: thresholds of these effects only
  std::string cases_filter;  // --cases=TEXT: section-1 sets whose name contains TEXT
  int threads = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strncmp(argv[i], "--clean_sets=", 13) == 0) clean_sets = std::atoi(argv[i] + 13);
    if (std::strcmp(argv[i], "--clean_pixel_centre") == 0) clean_sampling = model::Sampling::kPixelCentre;
    if (std::strcmp(argv[i], "--thresholds") == 0) thresholds = true;
    if (std::strncmp(argv[i], "--threshold_sims=", 17) == 0) threshold_sims = std::atoi(argv[i] + 17);
    if (std::strcmp(argv[i], "--no_sets") == 0) sets = false;
    if (std::strcmp(argv[i], "--clean_only") == 0) cases_too = false;
    if (std::strncmp(argv[i], "--only=", 7) == 0) only = argv[i] + 7;
    if (std::strncmp(argv[i], "--cases=", 8) == 0) cases_filter = argv[i] + 8;
    if (std::strncmp(argv[i], "--threads=", 10) == 0) threads = std::max(1, std::atoi(argv[i] + 10));
  }
  using model::Sampling;
  const std::vector<Case> cases = {
      {"background 20 e-", [](SimulationConfig* c) { c->effects.background = model::BackgroundParams{20.0}; },
       {{"background.pedestal_e", 20.0}}},
      {"ipc 0.01", [](SimulationConfig* c) { c->effects.ipc = model::IpcParams{0.01}; }, {{"ipc.alpha", 0.01}}},
      {"serial_cti 1e-3, 1.5 px", [](SimulationConfig* c) { c->effects.serial_cti = model::CtiParams{1e-3, 1.5}; },
       {{"serial_cti.trail_fraction", 1e-3}, {"serial_cti.trail_length_px", 1.5}}},
      {"parallel_cti 1e-3, 1.5 px", [](SimulationConfig* c) { c->effects.parallel_cti = model::CtiParams{1e-3, 1.5}; },
       {{"parallel_cti.trail_fraction", 1e-3}, {"parallel_cti.trail_length_px", 1.5}}},
      {"halo 3 %, 2.5 px", [](SimulationConfig* c) { c->effects.halo = model::HaloParams{0.03, 2.5}; },
       {{"halo.fraction", 0.03}, {"halo.sigma_px", 2.5}}},
      {"nonlinearity 3e-8 (5 int.; realistic)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->effects.nonlinearity = model::NonlinearityParams{3e-8};
       },
       {{"nonlinearity.beta_per_e", 3e-8}}},
      {"nonlinearity 2.4e-7 (5 int.; threshold)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->effects.nonlinearity = model::NonlinearityParams{2.4e-7};
       },
       {{"nonlinearity.beta_per_e", 2.4e-7}}},
      {"brighter_fatter 4e-7 (5 int., in focus)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->defocus_px = 0.0;
         c->effects.brighter_fatter = model::BrighterFatterParams{4e-7, 4e-7};
       },
       {{"brighter_fatter.slope_x_px_per_e", 4e-7}, {"brighter_fatter.slope_y_px_per_e", 4e-7}},
       true, false},
      {"brighter_fatter 4e-7 (5 int., defocus 0.41)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->effects.brighter_fatter = model::BrighterFatterParams{4e-7, 4e-7};
       },
       {{"brighter_fatter.slope_x_px_per_e", 4e-7}, {"brighter_fatter.slope_y_px_per_e", 4e-7}}},
      {"jitter (0, .1, .15, .2, .25 px)",
       [](SimulationConfig* c) {
         const double s[] = {0.0, 0.1, 0.15, 0.2, 0.25};
         for (size_t k = 0; k < c->exposures.size(); ++k) {
           c->exposures[k].jitter = model::JitterParams{s[k % 5], s[k % 5], 0, 0};
         }
       },
       {{"jitter.var_x_px2.4", 0.0625}, {"jitter.var_y_px2.4", 0.0625}}},
      {"defocus 0.41 (pixel_centre, no baseline defocus)", [](SimulationConfig*) {},
       {{"defocus_sigma_px", 0.41}}, false, false, Sampling::kPixelCentre},
      {"defocus_offset 0.1 px (integrated: a shift)",
       [](SimulationConfig* c) { c->effects.defocus_offset = model::DefocusOffsetParams{0.1, 0.0}; },
       {}},
      {"defocus_offset 0.1 px (pixel_centre)",
       [](SimulationConfig* c) { c->effects.defocus_offset = model::DefocusOffsetParams{0.1, 0.0}; },
       {{"defocus_offset.dx_px", 0.1}, {"defocus_offset.dy_px", 0.0}}, false, true,
       Sampling::kPixelCentre},
      {"serial_cti 1e-3 + background 20 e-",
       [](SimulationConfig* c) {
         c->effects.serial_cti = model::CtiParams{1e-3, 1.5};
         c->effects.background = model::BackgroundParams{20.0};
       },
       {{"serial_cti.trail_fraction", 1e-3}, {"background.pedestal_e", 20.0}}},
      {"brighter_fatter 4e-7 + serial_cti 1e-3 (5 int., in focus)",
       [](SimulationConfig* c) {
         SetIntensities(c);
         c->defocus_px = 0.0;
         c->effects.brighter_fatter = model::BrighterFatterParams{4e-7, 4e-7};
         c->effects.serial_cti = model::CtiParams{1e-3, 1.5};
       },
       {{"brighter_fatter.slope_x_px_per_e", 4e-7}, {"serial_cti.trail_fraction", 1e-3}},
       true, false},
  };
  if (sets) {
  std::printf("# 1. Five-exposure sets, one hidden effect (50 predictive simulations per round)\n");
  std::printf("%-58s %-26s %8s %8s %7s  %s  parameters (fit +- sd | truth)\n", "case", "named",
              "chi2 bef", "chi2 aft", "sec", "min p bef/aft (statistic)");
  int seed = 100;
  for (const Case& c : cases) {
    if (!cases_too) break;
    SimulationConfig config = testing_support::PaperConfig(c.sampling, 5, seed);
    c.inject(&config);
    if (c.in_focus) config.defocus_px = 0.0;
    const uint64_t noise_seed = seed + 1;
    seed += 2;
    if (!cases_filter.empty() && c.name.find(cases_filter) == std::string::npos) continue;
    const auto stamps = testing_support::SimulateStamps(config, noise_seed);
    fit::FitModelOptions fo;
    fo.model.sampling = c.sampling;
    std::string error;
    auto base = fit::FitModel::Create(stamps, fo, &error);
    DiagnoseOptions options;
    options.baseline_defocus = c.baseline_defocus;
    options.fit.num_threads = threads;
    options.map.num_threads = threads;
    DiagnoseResult r;
    if (!base || !RunDiagnosis(*base, options, &r, &error)) {
      std::printf("%-58s failed: %s\n", c.name.c_str(), error.c_str());
      continue;
    }
    // The smallest predictive p-value of a round's statistics, and which statistic.
    auto min_p = [](const ResidualStatistics& st) {
      const NamedStatistic* least = nullptr;
      for (const NamedStatistic& v : st.values) {
        if (std::isfinite(v.p_value) && (least == nullptr || v.p_value < least->p_value))
          least = &v;
      }
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.3f (%s)", least ? least->p_value : NAN,
                    least ? least->name.c_str() : "-");
      return std::string(buf);
    };
    std::printf("%-58s %-26s %8.4f %8.4f %7.1f  %s / %s ", c.name.c_str(), Named(r).c_str(),
                r.rounds.front().statistics.chi2_per_dof, r.rounds.back().statistics.chi2_per_dof,
                r.seconds, min_p(r.rounds.front().statistics).c_str(),
                min_p(r.rounds.back().statistics).c_str());
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

  std::printf("\n# 2. Clean three-exposure sets (%s): no missing effect?\n",
              model::ToString(clean_sampling).c_str());
  int clean = 0;
  std::vector<std::string> claims;
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < clean_sets; ++s) {
    SimulationConfig config = testing_support::PaperConfig(clean_sampling, 3, 1000 + s);
    const auto stamps = testing_support::SimulateStamps(config, 5000 + s);
    std::string error;
    fit::FitModelOptions fo;
    fo.model.sampling = clean_sampling;
    auto base = fit::FitModel::Create(stamps, fo, &error);
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
  }

  if (thresholds) {
    std::printf("\n# 3. Detection thresholds, five-exposure sets (named in >= 80 %% of %d "
                "simulations; strengths x catalogue default)\n",
                threshold_sims);
    for (const ThresholdCase& tc : ThresholdCases()) {
      if (!only.empty() && only.find(model::ToString(tc.kind)) == std::string::npos) continue;
      SimulationConfig config = testing_support::PaperConfig(tc.sampling, 5, 77);
      if (tc.multi_intensity) SetIntensities(&config);
      if (tc.no_defocus) config.defocus_px = 0.0;
      const auto stamps = testing_support::SimulateStamps(config, 78);
      fit::FitModelOptions fo;
      fo.model.sampling = tc.sampling;
      std::string error;
      auto base = fit::FitModel::Create(stamps, fo, &error);
      DiagnoseOptions options;
      options.baseline_defocus = tc.baseline_defocus;
      options.predictive.num_simulations = 0;
      options.thresholds.num_simulations = threshold_sims;
      options.thresholds.multiples = {1.0 / 64, 1.0 / 32, 1.0 / 16, 0.125, 0.25, 0.5,
                                      1.0,      2.0,      4.0,      8.0,   16.0};
      DiagnoseResult r;
      const auto t0 = std::chrono::steady_clock::now();
      if (!base || !RunDiagnosis(*base, options, &r, &error)) {
        std::printf("%-16s failed: %s\n", tc.label.c_str(), error.c_str());
        continue;
      }
      DetectionThreshold t;
      if (!ComputeDetectionThreshold(*base, r.rounds.back().spec, r.rounds.back().fit.p, tc.kind,
                                     r.rounds.back().p_threshold, options, &t, &error)) {
        std::printf("%-16s failed: %s\n", tc.label.c_str(), error.c_str());
        continue;
      }
      std::printf("%-40s %-32s default %-9.3g threshold %-9.3g (p < %.2g; %.0f s) rates:",
                  tc.label.c_str(), t.parameter.c_str(),
                  model::DescribeEffect(tc.kind).parameters[0].default_value, t.threshold,
                  r.rounds.back().p_threshold,
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      for (size_t i = 0; i < t.strengths.size(); ++i) std::printf(" %.3g:%.1f", t.strengths[i], t.rates[i]);
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  return 0;
}
