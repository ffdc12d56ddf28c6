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

// A renderer reuses the Airy image of its last render when the Airy radius and widths are
// unchanged (a joint fit's exposures), so the renders alternate between two radii 1e-12
// apart: each is a complete render, as in a single-exposure fit, where every MCMC proposal
// moves the radius.
void Render(benchmark::State& state, ModelOptions options, SpotParams params, bool jacobian) {
  SpotRenderer renderer(options);
  PixelGrid grid{21, 21, 0.0, 0.0};
  std::vector<double> model(grid.size()), jac(grid.size() * ccdpsf::model::kNumSpotParams);
  renderer.Render(params, grid, model.data(), jac.data());  // builds the Airy table once
  SpotParams other = params;
  other[ccdpsf::model::kAiryRadius] *= 1.0 + 1e-12;
  bool flip = false;
  for (auto _ : state) {
    renderer.Render(flip ? other : params, grid, model.data(), jacobian ? jac.data() : nullptr);
    flip = !flip;
    benchmark::DoNotOptimize(model.data());
  }
}

// The exposures of a five-exposure joint fit at one parameter vector: shared radius and
// widths, a sub-pixel centre of its own in each 21 x 21 stamp; time per exposure.
void RenderJoint(benchmark::State& state, bool jacobian) {
  SpotRenderer renderer{ModelOptions()};
  PixelGrid grid{21, 21, 0.0, 0.0};
  std::vector<double> model(grid.size()), jac(grid.size() * ccdpsf::model::kNumSpotParams);
  const double offsets[5][2] = {
      {0.07, -0.04}, {-0.02, 0.05}, {0.02, -0.09}, {-0.07, 0.02}, {0.09, 0.08}};
  SpotParams p = PaperParams();
  renderer.Render(p, grid, model.data(), jac.data());
  bool flip = false;
  for (auto _ : state) {
    p[ccdpsf::model::kAiryRadius] = flip ? 0.47 * (1.0 + 1e-12) : 0.47;  // a new proposal
    flip = !flip;
    for (const auto& offset : offsets) {
      p[ccdpsf::model::kCentreX] = 10.0 + offset[0];
      p[ccdpsf::model::kCentreY] = 10.0 + offset[1];
      renderer.Render(p, grid, model.data(), jacobian ? jac.data() : nullptr);
      benchmark::DoNotOptimize(model.data());
    }
  }
  state.SetItemsProcessed(state.iterations() * 5);
}
void BM_IntegratedJointWithJacobianPer5(benchmark::State& state) { RenderJoint(state, true); }
void BM_IntegratedJointValuesOnlyPer5(benchmark::State& state) { RenderJoint(state, false); }

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
BENCHMARK(BM_IntegratedJointWithJacobianPer5)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedJointValuesOnlyPer5)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedNarrowestWithJacobian)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IntegratedPillboxWithJacobian)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_IntegratedPillboxValuesOnly)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PixelCentreWithJacobian)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PixelCentreValuesOnly)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
