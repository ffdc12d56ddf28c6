// Speed of the fitting engine on the paper's simulation (peak ~1.5e5 e-, 21 x 21 stamps).
// Run: ./build/fit_benchmark --benchmark_repetitions=3 --benchmark_report_aggregates_only=true
// Targets (issue 3, this 2-core machine): single MAP <= 20 ms; joint MAP of 12 exposures
// <= 100 ms; complete single fit (MAP, Laplace, MCMC to ESS >= 1000) <= 5 s; five-exposure
// joint fit <= 15 s.
#include <string>

#include "benchmark/benchmark.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/simulate.h"
#include "support/simulated_stamps.h"

namespace {

using namespace ccdpsf;

std::unique_ptr<fit::FitModel> Model(int exposures, model::Sampling sampling) {
  const SimulationConfig c = testing_support::PaperConfig(sampling, exposures, 42);
  fit::FitModelOptions o;
  o.model.sampling = sampling;
  std::string error;
  return fit::FitModel::Create(testing_support::SimulateStamps(c, 43), o, &error);
}

void Map(benchmark::State& state, int exposures) {
  auto model = Model(exposures, model::Sampling::kIntegrated);
  fit::MapOptions options;
  for (auto _ : state) {
    fit::MapResult r;
    std::string error;
    if (!fit::FindMap(*model, options, &r, &error)) state.SkipWithError(error.c_str());
  }
}

void FullFit(benchmark::State& state, int exposures) {
  auto model = Model(exposures, model::Sampling::kIntegrated);
  fit::FitOptions options;
  options.mcmc.progress = false;
  options.mcmc.seed = 1;
  options.mcmc.num_threads = 2;
  for (auto _ : state) {
    fit::FitResult r;
    std::string error;
    if (!fit::RunFit(*model, options, &r, &error)) state.SkipWithError(error.c_str());
    state.counters["steps"] = r.chain.num_steps;
    state.counters["converged"] = r.chain.converged;
    state.counters["max_tau"] = *std::max_element(r.chain.tau.begin(), r.chain.tau.end());
  }
}

void BM_SingleMap(benchmark::State& s) { Map(s, 1); }
void BM_JointMap12(benchmark::State& s) { Map(s, 12); }
void BM_SingleFullFit(benchmark::State& s) { FullFit(s, 1); }
void BM_JointFullFit5(benchmark::State& s) { FullFit(s, 5); }

BENCHMARK(BM_SingleMap)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_JointMap12)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SingleFullFit)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();
BENCHMARK(BM_JointFullFit5)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
