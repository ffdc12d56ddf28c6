// What the lab-frame machinery costs on top of a complete fit: reading and calibrating the
// file (spot search with candidates, column and source checks, censoring), the flux-model
// choice, the outlier scan and the verdict. Target (issue "Real laboratory frames"): under
// 10 % of a complete single fit.
//
// The same exposure both ways: testdata/demo_simulation.json's first exposure, written as
// FITS by the simulator (48 x 48 frame, peak ~158 ke-).
//   BM_BareCompleteFit   FitModel on the calibrated stamp + RunFit (MAP, Laplace, MCMC)
//   BM_LabCompleteFit    LoadExposureSet (from the FITS file) + FitExposures: the path of
//                        `ccdpsf fit`, MCMC with the same seed
//   BM_Calibrate         LoadExposureSet alone
//   BM_OutliersAndVerdict the outlier scan at the MAP and the fit's findings
// Run: ./build/lab_fit_benchmark --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <filesystem>
#include <string>

#include "benchmark/benchmark.h"
#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/simulate.h"

namespace {

using namespace ccdpsf;
namespace fs = std::filesystem;

// The demo exposure as a FITS file, made once.
const std::string& DemoFile() {
  static const std::string path = [] {
    const std::string dir = fs::temp_directory_path().string() + "/ccdpsf_lab_fit_benchmark";
    fs::remove_all(dir);
    std::string error;
    std::optional<SimulationConfig> c =
        LoadSimulationConfig(std::string(CCDPSF_SOURCE_DIR) + "/testdata/demo_simulation.json", &error);
    SimulationResult r;
    if (!c || !RunSimulation(*c, dir, false, &r, &error)) std::abort();
    return dir + "/exposure_000.fits";
  }();
  return path;
}

ExposureSet Load() {
  ExposureSet set;
  std::string error;
  InputFile input;
  input.path = DemoFile();
  if (!LoadExposureSet({input}, ExposureSetOptions(), &set, &error)) std::abort();
  return set;
}

fit::FitOptions McmcOptions() {
  fit::FitOptions o;
  o.mcmc.progress = false;
  o.mcmc.seed = 1;
  o.mcmc.num_threads = 2;
  return o;
}

void BM_BareCompleteFit(benchmark::State& state) {
  const ExposureSet set = Load();
  std::string error;
  auto model = fit::FitModel::Create({set.exposures[0].stamp}, fit::FitModelOptions(), &error);
  for (auto _ : state) {
    fit::FitResult r;
    if (!fit::RunFit(*model, McmcOptions(), &r, &error)) state.SkipWithError(error.c_str());
    state.counters["steps"] = r.chain.num_steps;
  }
}

void BM_LabCompleteFit(benchmark::State& state) {
  DemoFile();
  for (auto _ : state) {
    const ExposureSet set = Load();
    fit::ExposuresFitOptions options;
    options.config.fit = McmcOptions();
    fit::ExposuresFit fitted;
    std::string error;
    if (!fit::FitExposures(set.exposures, set.quality, options, &fitted, &error)) {
      state.SkipWithError(error.c_str());
    }
    state.counters["steps"] = fitted.result.chain.num_steps;
  }
}

void BM_Calibrate(benchmark::State& state) {
  DemoFile();
  for (auto _ : state) benchmark::DoNotOptimize(Load());
}

void BM_OutliersAndVerdict(benchmark::State& state) {
  const ExposureSet set = Load();
  std::string error;
  auto model = fit::FitModel::Create({set.exposures[0].stamp}, fit::FitModelOptions(), &error);
  fit::FitOptions options = McmcOptions();
  options.run_mcmc = false;
  fit::FitResult r;
  if (!fit::RunFit(*model, options, &r, &error)) std::abort();
  for (auto _ : state) {
    benchmark::DoNotOptimize(fit::FindOutliers(*model, r.map.theta, fit::OutlierOptions()));
    Quality q;
    fit::AssessFit(*model, r, fit::FitQualityOptions(), &q);
    benchmark::DoNotOptimize(q);
  }
}

BENCHMARK(BM_BareCompleteFit)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();
BENCHMARK(BM_LabCompleteFit)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();
BENCHMARK(BM_Calibrate)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_OutliersAndVerdict)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
