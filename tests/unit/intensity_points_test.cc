// The intensity check of a joint fit (fit/intensity_points.h) on a small simulated series:
// its predicted widths are the affected widths (affected_widths.h) at the fit's parameters,
// its intrinsic widths the fitted ones, its curve starts at the intrinsic kernel (no signal,
// no widening) and each exposure alone measures a width.
#include "ccdpsf/fit/intensity_points.h"

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/fit/affected_widths.h"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"

namespace ccdpsf::fit {
namespace {

using model::EffectKind;

// Three exposures of the paper's spot (peaks ~4e4, ~8e4, ~1.6e5 e-) drawn with boundary_shift
// at three times the catalogue's coefficients, fitted jointly with it (MAP and Laplace: the
// check's MCMC part is the same code over chain states, run by the e2e trend case).
TEST(IntensityPoints, PredictedWidthsAreTheAffectedWidthsAtTheFit) {
  SimulationConfig c = testing_support::PaperConfig(model::Sampling::kIntegrated, 3, 31);
  const model::BoundaryShiftParams d;
  std::string error;
  ASSERT_TRUE(model::SetEffectParameters(EffectKind::kBoundaryShift,
                                         {3 * d.a_10, 3 * d.a_01, 3 * d.a_11, 3 * d.a_far, d.anisotropy},
                                         &c.effects, &error))
      << error;
  for (int k = 0; k < 3; ++k) c.exposures[k].flux_e *= std::pow(2.0, k - 2);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  options.effects = {{EffectKind::kBoundaryShift, {}}};
  auto m = testing_support::MustCreate(testing_support::SimulateStamps(c, 32), options);
  ASSERT_TRUE(m);
  FitResult r;
  const FitOptions fit_options = testing_support::NoMcmc();
  ASSERT_TRUE(RunFit(*m, fit_options, &r, &error)) << error;

  const IntensityPoints ip = MeasureIntensityPoints(*m, r, fit_options.map);
  EXPECT_EQ(ip.effect, "boundary_shift");
  EXPECT_FALSE(ip.ccd_identified) << "one focus, Gaussian defocus: the totals are compared";
  EXPECT_EQ(ip.intrinsic.ccd_sigma_x_px.map, r.parameters[kCcdSigmaXPx].map);
  EXPECT_EQ(ip.intrinsic.ccd_sigma_y_px.map, r.parameters[kCcdSigmaYPx].map);
  ASSERT_EQ(ip.points.size(), 3u);
  std::unique_ptr<FitEvaluator> ev = m->NewEvaluator();
  for (int k = 0; k < 3; ++k) {
    const IntensityPoint& p = ip.points[k];
    AffectedWidths w;
    ASSERT_TRUE(AffectedKernelWidths(*m, ev.get(), r.map.theta.data(), k, &w));
    EXPECT_NEAR(p.predicted.total_sigma_x_px.map, w.total_sigma_x_px, 1e-12);
    EXPECT_NEAR(p.predicted.ccd_sigma_y_px.map, w.ccd_sigma_y_px, 1e-12);
    EXPECT_NEAR(p.peak_e, w.peak_e, 1e-9 * w.peak_e);
    EXPECT_GT(p.delta_var_x_px2.map, 0.0) << "exposure " << k;
    EXPECT_TRUE(std::isnan(p.predicted.total_sigma_x_px.median)) << "no MCMC, no posterior";
    // Each exposure alone: a finite width with a Laplace sd (the totals are identified).
    EXPECT_TRUE(p.failure.empty()) << p.failure;
    EXPECT_TRUE(std::isfinite(p.measured.total_sigma_x_px.map));
    EXPECT_GT(p.measured.total_sigma_y_px.laplace_sd, 0.0);
  }
  // Brighter exposures are predicted wider (Delta var grows with the signal).
  EXPECT_GT(ip.points[2].predicted.total_sigma_y_px.map, ip.points[0].predicted.total_sigma_y_px.map);
  // The curve's first node has no light: the intrinsic kernel exactly; its last reaches past
  // the brightest exposure.
  ASSERT_FALSE(ip.curve_peak_e.empty());
  EXPECT_EQ(ip.curve_peak_e.front(), 0.0);
  EXPECT_NEAR(ip.curve_widths[0].front().map, r.parameters[kCcdSigmaXPx].map, 1e-12);
  EXPECT_GT(ip.curve_peak_e.back(), ip.points[2].peak_e);
}

}  // namespace
}  // namespace ccdpsf::fit
