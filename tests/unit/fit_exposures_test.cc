// Tests of the lab-frame fit (fit/fit_exposures.h, fit/fit_quality.h) and of the model
// features it relies on: per-exposure and exposure-time-scaled fluxes, censored and coarse
// pixels in the MAP's residual blocks, outlier masking and the verdict's rules.
//
// Data are the paper's simulation (tests/support/simulated_stamps.h) with known truth;
// defects are applied here by hand, as plainly as possible.
#include "ccdpsf/fit/fit_exposures.h"

#include <cmath>
#include <memory>

#include "ccdpsf/fit/map_fit.h"
#include "ceres/ceres.h"
#include "ceres/gradient_checker.h"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"

namespace ccdpsf::fit {
namespace {

using testing_support::MustCreate;
using testing_support::PaperConfig;
using testing_support::SimulateStamps;

const double kTotalX = std::hypot(0.41, 0.291);
const double kTotalY = std::hypot(0.41, 0.335);

// Stamps of the paper's simulation whose fluxes are scaled per exposure.
std::vector<Stamp> ScaledStamps(const std::vector<double>& scales, uint64_t seed) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, static_cast<int>(scales.size()),
                                   seed);
  for (size_t k = 0; k < scales.size(); ++k) {
    c.exposures[k].flux_e *= scales[k];
    c.exposures[k].exptime_s = 2.5 * scales[k];
  }
  std::vector<Stamp> stamps = SimulateStamps(c, seed + 100);
  for (size_t k = 0; k < stamps.size(); ++k) stamps[k].info.exptime_s = c.exposures[k].exptime_s;
  return stamps;
}

std::vector<double> ThetaFor(const FitModel& m, const SimulationConfig& c, double flux) {
  std::vector<double> theta(m.dim(), 0.0);
  theta[kFluxE] = flux;
  theta[kAiryRadiusPx] = 0.47;
  theta[kDefocusPx] = 0.41;
  theta[kCcdSigmaXPx] = 0.291;
  theta[kCcdSigmaYPx] = 0.335;
  for (int k = 0; k < m.num_exposures(); ++k) {
    theta[FitModel::XIndex(k)] = c.exposures[k].x_px;
    theta[FitModel::YIndex(k)] = c.exposures[k].y_px;
  }
  return theta;
}

TEST(FluxModes, PerExposureJointLogLikelihoodIsTheSumOfSingles) {
  const std::vector<double> scales = {1.0, 2.0, 0.5};
  const std::vector<Stamp> stamps = ScaledStamps(scales, 11);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  auto joint = MustCreate(stamps, options);
  ASSERT_EQ(joint->dim(), kNumShared + 6 + 2);
  EXPECT_EQ(joint->names()[joint->RatioIndex(1)], "flux_ratio_1");
  EXPECT_EQ(joint->RatioIndex(0), -1);
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 3, 11);
  std::vector<double> theta = ThetaFor(*joint, c, 4.0e5);
  theta[joint->RatioIndex(1)] = 1.9;
  theta[joint->RatioIndex(2)] = 0.55;
  double sum = 0.0;
  for (int k = 0; k < 3; ++k) {
    auto single = MustCreate({stamps[k]});
    std::vector<double> t(theta.begin(), theta.begin() + kNumShared);
    t[kFluxE] *= k == 0 ? 1.0 : theta[joint->RatioIndex(k)];
    t.push_back(theta[FitModel::XIndex(k)]);
    t.push_back(theta[FitModel::YIndex(k)]);
    sum += single->NewEvaluator()->LogLikelihood(t.data());
  }
  // The same terms in another order: agreement to rounding.
  EXPECT_NEAR(joint->NewEvaluator()->LogLikelihood(theta.data()), sum, 1e-10 * std::fabs(sum));
}

TEST(FluxModes, ExptimeScaledFluxFollowsTheExposureTimes) {
  const std::vector<Stamp> stamps = ScaledStamps({1.0, 2.0, 3.0}, 12);
  FitModelOptions options;
  options.flux = FluxMode::kExptimeScaled;
  auto m = MustCreate(stamps, options);
  EXPECT_EQ(m->dim(), kNumShared + 6);  // no extra parameters
  EXPECT_DOUBLE_EQ(m->FixedFluxScale(2), 3.0);
  // An exposure without a time cannot be scaled.
  std::vector<Stamp> no_time = stamps;
  no_time[1].info.exptime_s = NAN;
  std::string error;
  EXPECT_EQ(FitModel::Create(no_time, options, &error), nullptr);
  EXPECT_NE(error.find("exposure time"), std::string::npos) << error;
}

TEST(FluxModes, ModelJacobianOfTheRatiosMatchesDifferences) {
  const std::vector<Stamp> stamps = ScaledStamps({1.0, 2.0}, 13);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  auto m = MustCreate(stamps, options);
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 2, 13);
  std::vector<double> theta = ThetaFor(*m, c, 4.0e5);
  const int r = m->RatioIndex(1);
  theta[r] = 2.1;
  auto ev = m->NewEvaluator();
  std::vector<double> image, jac, plus, minus;
  ev->ModelImage(theta.data(), 1, &image, &jac);
  for (int i : {static_cast<int>(kFluxE), r}) {
    std::vector<double> tp = theta, tm = theta;
    const double h = 1e-6 * theta[i];
    tp[i] += h;
    tm[i] -= h;
    ev->ModelImage(tp.data(), 1, &plus, nullptr);
    ev->ModelImage(tm.data(), 1, &minus, nullptr);
    for (size_t q = 0; q < image.size(); ++q) {
      // The model is linear in both: the central difference is exact to rounding.
      EXPECT_NEAR(jac[q * m->dim() + i], (plus[q] - minus[q]) / (2 * h),
                  1e-6 * (1.0 + std::fabs(image[q] / theta[i])))
          << i << " " << q;
    }
  }
}

// The residual block with every optional part: a flux-ratio block, censored pixels and (in a
// second stamp) coarse ADC steps.
TEST(FluxModes, ExposureCostWithRatioAndCensoringPassesGradientChecker) {
  std::vector<Stamp> stamps = ScaledStamps({1.0, 1.5}, 14);
  Stamp& s = stamps[1];
  s.censor.assign(s.valid.size(), Censor::kNone);
  s.adc_step_e = s.gain_e_per_adu;
  double peak = 0;
  for (double v : s.electrons.data) peak = std::max(peak, v);
  int censored = 0;
  for (size_t q = 0; q < s.valid.size(); ++q) {
    if (s.electrons.data[q] > 0.6 * peak) {
      s.censor[q] = Censor::kAtOrAbove;
      s.electrons.data[q] = 0.6 * peak;
      ++censored;
    } else if (s.electrons.data[q] < 3.0) {
      s.censor[q] = Censor::kAtOrBelow;
      s.electrons.data[q] = 3.0;
    }
  }
  ASSERT_GE(censored, 1);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  auto m = MustCreate(stamps, options);
  std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*m, 1));
  ASSERT_EQ(cost->parameter_block_sizes().size(), 3u);  // shared, position, ratio
  ceres::NumericDiffOptions nd;
  nd.ridders_relative_initial_step_size = 1e-4;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(cost.get(), no_manifolds, nd);
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 2, 14);
  double shared[5] = {4.0e5, 0.5, 0.38, 0.3, 0.33};
  double position[2] = {c.exposures[1].x_px + 0.02, c.exposures[1].y_px - 0.03};
  double ratio[1] = {1.45};
  const double* params[3] = {shared, position, ratio};
  EXPECT_TRUE(checker.Probe(params, 1e-5, nullptr));
  // And with coarse steps (read noise below one ADU: the interval form).
  stamps[1].read_noise_e = 0.5 * stamps[1].gain_e_per_adu;
  auto coarse = MustCreate(stamps, options);
  ASSERT_TRUE(StampNoise(coarse->stamps()[1]).interval);
  std::unique_ptr<ceres::CostFunction> coarse_cost(NewExposureCost(*coarse, 1));
  ceres::GradientChecker coarse_checker(coarse_cost.get(), no_manifolds, nd);
  EXPECT_TRUE(coarse_checker.Probe(params, 1e-5, nullptr));
}

TEST(FluxModes, PerExposureFitRecoversTheRatios) {
  const std::vector<Stamp> stamps = ScaledStamps({1.0, 2.0, 0.5}, 15);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  auto m = MustCreate(stamps, options);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*m, testing_support::NoMcmc(), &r, &error)) << error;
  for (const auto& [k, truth] : {std::pair<int, double>{1, 2.0}, {2, 0.5}}) {
    const Summary& s = r.parameters[m->RatioIndex(k)];
    EXPECT_NEAR(s.map, truth, 4 * s.laplace_sd) << k;
  }
}

TEST(FluxModes, ChoiceFromTheData) {
  std::string why;
  // One exposure time, the same lamp: shared.
  EXPECT_EQ(ChooseFluxMode(ScaledStamps({1.0, 1.0, 1.0}, 16), &why), FluxMode::kShared) << why;
  // Times 1:2:3 with the light following them (ScaledStamps sets the times): scaled.
  EXPECT_EQ(ChooseFluxMode(ScaledStamps({1.0, 2.0, 3.0}, 17), &why), FluxMode::kExptimeScaled)
      << why;
  // One time but the lamp drifting by 10 %: a flux each.
  std::vector<Stamp> drift = ScaledStamps({1.0, 1.1, 1.0}, 18);
  for (Stamp& s : drift) s.info.exptime_s = 2.5;
  EXPECT_EQ(ChooseFluxMode(drift, &why), FluxMode::kPerExposure) << why;
  // Times 1:2:3 but the light not following (a shutter delay): a flux each.
  std::vector<Stamp> shutter = ScaledStamps({1.0, 1.5, 2.0}, 19);
  shutter[1].info.exptime_s = 5.0;
  shutter[2].info.exptime_s = 7.5;
  EXPECT_EQ(ChooseFluxMode(shutter, &why), FluxMode::kPerExposure) << why;
  // A clipped core does not change the choice: the comparison is on the wings.
  std::vector<Stamp> clipped = ScaledStamps({1.0, 1.0, 1.0}, 20);
  double peak = 0;
  for (double v : clipped[0].electrons.data) peak = std::max(peak, v);
  for (double& v : clipped[0].electrons.data) v = std::min(v, 0.5 * peak);
  EXPECT_EQ(ChooseFluxMode(clipped, &why), FluxMode::kShared) << why;
}

// Wings too faint to compare (~1200 e- spots: their wings' noise is tens of % of their light)
// and no exposure times (as on the real 8-bit frames of ../shared/realdata): the 5 x 5 cores
// decide. Equal light stays shared; one exposure with 3x the light gets a flux each (a shared
// flux there made the faint exposure's whole core an outlier and failed the run).
TEST(FluxModes, FaintWingsCoresTellDifferentLight) {
  std::string why;
  auto faint = [](const std::vector<double>& scales, uint64_t seed) {
    std::vector<Stamp> stamps = ScaledStamps(scales, seed);
    for (Stamp& s : stamps) s.info.exptime_s = NAN;
    return stamps;
  };
  const std::vector<Stamp> same = faint({0.003, 0.003, 0.003}, 23);
  EXPECT_EQ(ChooseFluxMode(same, &why), FluxMode::kShared) << why;
  EXPECT_NE(why.find("too faint"), std::string::npos) << why;  // the wings did not decide
  const std::vector<Stamp> brighter = faint({0.003, 0.009, 0.003}, 24);
  EXPECT_EQ(ChooseFluxMode(brighter, &why), FluxMode::kPerExposure) << why;
  EXPECT_NE(why.find("5 x 5 cores"), std::string::npos) << why;
}

TEST(Outliers, ACosmicRayInOneExposureIsFoundAndAModelErrorIsNot) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 4, 21);
  std::vector<Stamp> stamps = SimulateStamps(c, 22);
  // 8000 e- in the pixel right of exposure 2's peak.
  const int cx = static_cast<int>(std::lround(c.exposures[2].x_px));
  const int cy = static_cast<int>(std::lround(c.exposures[2].y_px));
  stamps[2].electrons(cx + 1, cy) += 8000.0;
  auto m = MustCreate(stamps);
  std::vector<double> theta = ThetaFor(*m, c, 4.0e5);
  OutlierOptions options;
  std::vector<OutlierMask> found = FindOutliers(*m, theta, options);
  ASSERT_EQ(found.size(), 1u);
  EXPECT_EQ(found[0].exposure, 2);
  EXPECT_EQ(found[0].x_px, cx + 1);
  EXPECT_EQ(found[0].y_px, cy);
  EXPECT_TRUE(found[0].core);
  EXPECT_GT(found[0].z, 8.0);
  // A wrong model at its best: data with a pillbox defocus (a geometric defocus) fitted with
  // the default Gaussian one. The residuals are large (chi^2/dof ~ 2-4) but alike in every
  // exposure (jointly) and ring-shaped (alone): nothing is masked.
  SimulationConfig pillbox = PaperConfig(model::Sampling::kIntegrated, 4, 29);
  pillbox.model.defocus = model::DefocusKind::kPillbox;
  pillbox.defocus_px = 1.2;  // radius [px]
  const std::vector<Stamp> misfit = SimulateStamps(pillbox, 30);
  for (int n : {4, 1}) {
    auto wrong = MustCreate(std::vector<Stamp>(misfit.begin(), misfit.begin() + n));
    MapResult map;
    std::string error;
    ASSERT_TRUE(FindMap(*wrong, MapOptions(), &map, &error)) << error;
    EXPECT_GT(map.chi2 / map.dof, 1.5) << n;
    for (const OutlierMask& o : FindOutliers(*wrong, map.theta, options)) {
      ADD_FAILURE() << n << " exposure(s): masked " << o.exposure << " (" << o.x_px << ", "
                    << o.y_px << ") z " << o.z << (o.core ? " core" : "");
    }
  }
}

TEST(Verdict, Chi2RangeAndBounds) {
  Quality q;
  FitQualityOptions options;
  // dof 1000: the central 99.8 % of chi^2/dof is about 1 +- 3.09 x 0.0447.
  AssessChi2(1000.0, 1000, options, &q);
  EXPECT_TRUE(q.findings.empty());
  AssessChi2(1200.0, 1000, options, &q);
  EXPECT_TRUE(q.Has("chi2_high"));
  Quality low;
  AssessChi2(820.0, 1000, options, &low);
  EXPECT_TRUE(low.Has("chi2_low"));
  EXPECT_EQ(low.Verdict(), "suspect");
  Quality gross;
  AssessChi2(15000.0, 1000, options, &gross);
  EXPECT_TRUE(gross.Has("gross_misfit"));
  EXPECT_EQ(gross.Verdict(), "invalid");
  double lo = 0, hi = 0;
  ExpectedChi2PerDofRange(1000, 1e-3, &lo, &hi);
  EXPECT_NEAR(hi, 1 + 3.0902 * std::sqrt(2.0 / 1000), 1e-3);
}

TEST(Verdict, CleanFitIsOkAndAWidthAtItsLowerBoundIsAnUpperLimit) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 3, 23);
  std::vector<Exposure> exposures;
  for (const Stamp& s : SimulateStamps(c, 24)) exposures.push_back({s, CalibrationReport()});
  ExposuresFitOptions options;
  options.config.fit.run_mcmc = false;
  ExposuresFit fit;
  std::string error;
  ASSERT_TRUE(FitExposures(exposures, Quality(), options, &fit, &error)) << error;
  EXPECT_EQ(fit.quality.Verdict(), "ok") << fit.quality.OneLine();
  EXPECT_EQ(fit.model->options().flux, FluxMode::kShared);
  ASSERT_EQ(fit.notes.size(), 1u);
  // A spot far narrower than the pixel (pixel_centre sampling, whose CCD widths are not
  // degenerate with the defocus): the widths reach the prior's lower edge.
  SimulationConfig narrow = PaperConfig(model::Sampling::kPixelCentre, 1, 25);
  narrow.ccd_sigma_x_px = narrow.ccd_sigma_y_px = 0.05;
  narrow.defocus_px = 0.05;
  std::vector<Exposure> one;
  for (const Stamp& s : SimulateStamps(narrow, 26)) one.push_back({s, CalibrationReport()});
  options.config.model.model.sampling = model::Sampling::kPixelCentre;
  ASSERT_TRUE(FitExposures(one, Quality(), options, &fit, &error)) << error;
  EXPECT_TRUE(fit.quality.Has("width_upper_limit")) << fit.quality.OneLine();
  EXPECT_NE(fit.quality.Verdict(), "ok");
}

TEST(Verdict, SaturatedCoreFitsAsCensoredAndRecoversTheWidths) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 27);
  std::vector<Stamp> stamps = SimulateStamps(c, 28);
  Stamp& s = stamps[0];
  // Saturate at 40 % of the peak: the peak and its four neighbours... whatever lies above.
  double peak = 0;
  for (double v : s.electrons.data) peak = std::max(peak, v);
  s.censor.assign(s.valid.size(), Censor::kNone);
  int censored = 0;
  for (size_t q = 0; q < s.valid.size(); ++q) {
    if (s.electrons.data[q] >= 0.4 * peak) {
      s.censor[q] = Censor::kAtOrAbove;
      s.electrons.data[q] = 0.4 * peak;
      ++censored;
    }
  }
  ASSERT_GE(censored, 1);
  auto m = MustCreate(stamps);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*m, testing_support::NoMcmc(), &r, &error)) << error;
  const int tx = testing_support::DerivedIndex(r, "total_sigma_x_px");
  const int ty = testing_support::DerivedIndex(r, "total_sigma_y_px");
  // The censored core keeps its information "at least this much": the identified widths
  // come back within 4 sd, with a wider interval than the unsaturated fit's.
  EXPECT_NEAR(r.derived[tx].second.map, kTotalX, 4 * r.derived[tx].second.laplace_sd);
  EXPECT_NEAR(r.derived[ty].second.map, kTotalY, 4 * r.derived[ty].second.laplace_sd);
  EXPECT_EQ(r.map.num_pixels, m->NumValidPixels() - censored);  // bounds are no dof
  auto unsaturated = MustCreate(SimulateStamps(c, 28));
  FitResult u;
  ASSERT_TRUE(RunFit(*unsaturated, testing_support::NoMcmc(), &u, &error)) << error;
  EXPECT_GT(r.derived[tx].second.laplace_sd, u.derived[tx].second.laplace_sd);
}

}  // namespace
}  // namespace ccdpsf::fit
