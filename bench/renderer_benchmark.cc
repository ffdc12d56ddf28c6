// Speed of the forward model: one 21 x 21 stamp, with and without the Jacobian of all seven
// parameters. Run: ./build/renderer_benchmark --benchmark_repetitions=5
// --benchmark_report_aggregates_only=true (medians are what the notes report).
#include <vector>

#include "benchmark/benchmark.h"
#include "ccdpsf/model/renderer.h"

namespace {

using ccdpsf::model::DefocusKind;
using ccdpsf::model::ModelOptions;
using ccdpsf::model::PixelGrid;
using ccdpsf::model::Sampling;
using ccdpsf::model::SpotParams;
using ccdpsf::model::SpotRenderer;

// The paper's simulation values (section 3.3), flux giving a ~150 ke- peak pixel.
SpotParams PaperParams() { return {4.0e5, 10.07, 9.96, 0.47, 0.41, 0.291, 0.335}; }

void Render(benchmark::State& state, ModelOptions options, SpotParams params, bool jacobian) {
  SpotRenderer renderer(options);
  PixelGrid grid{21, 21, 0.0, 0.0};
  std::vector<double> model(grid.size()), jac(grid.size() * ccdpsf::model::kNumSpotParams);
  renderer.Render(params, grid, model.data(), jac.data());  // builds the Airy table once
  for (auto _ : state) {
    renderer.Render(params, grid, model.data(), jacobian ? jac.data() : nullptr);
    benchmark::DoNotOptimize(model.data());
  }
}

void BM_IntegratedWithJacobian(benchmark::State& state) {
  Render(state, ModelOptions(), PaperParams(), true);
}
void BM_IntegratedValuesOnly(benchmark::State& state) {
  Render(state, ModelOptions(), PaperParams(), false);
}
// The hardest corner of the accuracy range: smallest Airy radius and widths.
void BM_IntegratedNarrowestWithJacobian(benchmark::State& state) {
  Render(state, ModelOptions(), {4.0e5, 10.07, 9.96, 0.3, 0.1, 0.1, 0.1}, true);
}
void BM_IntegratedPillboxWithJacobian(benchmark::State& state) {
  ModelOptions options;
  options.defocus = DefocusKind::kPillbox;
  Render(state, options, {4.0e5, 10.07, 9.96, 0.47, 0.6, 0.291, 0.335}, true);
}
void BM_IntegratedPillboxValuesOnly(benchmark::State& state) {
  ModelOptions options;
  options.defocus = DefocusKind::kPillbox;
  Render(state, options, {4.0e5, 10.07, 9.96, 0.47, 0.6, 0.291, 0.335}, false);
}
void BM_PixelCentreWithJacobian(benchmark::State& state) {
  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  Render(state, options, {1.5e5, 10.07, 9.96, 0.47, 0.41, 0.291, 0.335}, true);
}
void BM_PixelCentreValuesOnly(benchmark::State& state) {
  ModelOptions options;
  options.sampling = Sampling::kPixelCentre;
  Render(state, options, {1.5e5, 10.07, 9.96, 0.47, 0.41, 0.291, 0.335}, false);
}

BENCHMARK(BM_IntegratedWithJacobian)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedValuesOnly)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedNarrowestWithJacobian)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedPillboxWithJacobian)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_IntegratedPillboxValuesOnly)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PixelCentreWithJacobian)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PixelCentreValuesOnly)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
