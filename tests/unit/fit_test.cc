// The fitting engine against simulations with known truth.
#include "ccdpsf/fit/fit.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>

#include "ccdpsf/campaign_simulation.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_quality.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/model/spot_model.h"
#include "ccdpsf/trend/campaign.h"
#include "ceres/ceres.h"
#include "ceres/gradient_checker.h"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"
#include "support/slow_test.h"

namespace ccdpsf::fit {
namespace {

using testing_support::PaperConfig;
using testing_support::SimulateStamps;

using testing_support::MustCreate;
using testing_support::NoMcmc;
constexpr auto IndexOf = testing_support::DerivedIndex;

double TotalSigma(double defocus, double ccd) { return std::hypot(defocus, ccd); }

// docs/conventions.md, Noise model: the joint log-likelihood is the singles' sum, at any theta.
TEST(Fit, JointLogLikelihoodIsTheSumOfSingles) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 3, 1);
  const std::vector<Stamp> stamps = SimulateStamps(c, 2);
  for (LikelihoodKind kind : {LikelihoodKind::kGaussian, LikelihoodKind::kPoissonNormal}) {
    FitModelOptions options;
    options.likelihood = kind;
    auto joint = MustCreate(stamps, options);
    std::vector<double> theta = {4.1e5, 0.5, 0.3, 0.35, 0.3};
    for (int k = 0; k < 3; ++k) {
      theta.push_back(c.exposures[k].x_px + 0.01 * k);
      theta.push_back(c.exposures[k].y_px - 0.02);
    }
    double sum = 0.0;
    for (int k = 0; k < 3; ++k) {
      auto single = MustCreate({stamps[k]}, options);
      std::vector<double> t(theta.begin(), theta.begin() + kNumShared);
      t.push_back(theta[FitModel::XIndex(k)]);
      t.push_back(theta[FitModel::YIndex(k)]);
      sum += single->NewEvaluator()->LogLikelihood(t.data());
    }
    const double total = joint->NewEvaluator()->LogLikelihood(theta.data());
    // Same terms summed in another order: agreement to rounding (~1e-16 per term, 1323 terms).
    EXPECT_NEAR(total, sum, 1e-10 * std::fabs(sum)) << ToString(kind);
  }
}

// 1/2 sum of the Ceres residuals squared must equal -log L up to a constant (the -sum log
// sigma term kept): check that the difference is the same at two different points.
TEST(Fit, CeresCostIsMinusLogLikelihoodPlusAConstant) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 3);
  auto model = MustCreate(SimulateStamps(c, 4));
  std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*model, 0));
  auto ev = model->NewEvaluator();
  double offsets[2];
  for (int t = 0; t < 2; ++t) {
    double shared[5] = {4.0e5 * (1 + 0.05 * t), 0.47 + 0.05 * t, 0.41, 0.291 + 0.02 * t, 0.335};
    double position[2] = {c.exposures[0].x_px + 0.03 * t, c.exposures[0].y_px};
    const double* params[2] = {shared, position};
    std::vector<double> r(cost->num_residuals());
    ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));
    double half_sum = 0.0;
    for (double v : r) half_sum += 0.5 * v * v;
    std::vector<double> theta(shared, shared + 5);
    theta.push_back(position[0]);
    theta.push_back(position[1]);
    offsets[t] = half_sum + ev->LogLikelihood(theta.data());
  }
  // The constant: sum over pixels of (1/2) log(2 pi var0) - 1/2; both sides are ~1e3-1e4,
  // so 1e-8 absolute is rounding.
  EXPECT_NEAR(offsets[0], offsets[1], 1e-8);
}

// The analytic Jacobian of the residual block against Ceres' numerical differentiation.
TEST(Fit, ExposureCostPassesGradientChecker) {
  for (model::Sampling sampling : {model::Sampling::kIntegrated, model::Sampling::kPixelCentre}) {
    const SimulationConfig c = PaperConfig(sampling, 1, 5);
    FitModelOptions options;
    options.model.sampling = sampling;
    auto model = MustCreate(SimulateStamps(c, 6), options);
    std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*model, 0));
    ceres::NumericDiffOptions nd;
    // GradientChecker differentiates with Ridders' method; a first step of 1e-4 relative
    // keeps every probe inside the model's domain.
    nd.ridders_relative_initial_step_size = 1e-4;
    const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
    ceres::GradientChecker checker(cost.get(), no_manifolds, nd);
    double shared[5] = {sampling == model::Sampling::kIntegrated ? 4.0e5 : 1.5e5, 0.5, 0.38, 0.3,
                        0.33};
    double position[2] = {c.exposures[0].x_px + 0.02, c.exposures[0].y_px - 0.03};
    const double* params[2] = {shared, position};
    // Ridders' extrapolation is accurate to ~1e-8 relative here; 1e-5 leaves room. No
    // ProbeResults: it would be allocated by libceres and freed here (see renderer_test.cc).
    EXPECT_TRUE(checker.Probe(params, 1e-5, nullptr)) << ToString(sampling);
  }
}

// Recovery on the paper's simulation: identified quantities within 4 reported sd (a 1-in-
// 15000 miss per quantity if the sd is right), and the joint fit tighter than single fits.
TEST(Fit, RecoversIdentifiedQuantitiesAndJointIsTighter) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 5, 7);
  const std::vector<Stamp> stamps = SimulateStamps(c, 8);
  const double tx = TotalSigma(c.defocus_px, c.ccd_sigma_x_px);
  const double ty = TotalSigma(c.defocus_px, c.ccd_sigma_y_px);
  std::string error;
  FitResult joint;
  auto joint_model = MustCreate(stamps);
  ASSERT_TRUE(RunFit(*joint_model, NoMcmc(), &joint, &error)) << error;
  const int ix = IndexOf(joint, "total_sigma_x_px"), iy = IndexOf(joint, "total_sigma_y_px");
  auto check = [&](const FitResult& r, const std::vector<int>& exposures) {
    EXPECT_NEAR(r.derived[ix].second.map, tx, 4 * r.derived[ix].second.laplace_sd);
    EXPECT_NEAR(r.derived[iy].second.map, ty, 4 * r.derived[iy].second.laplace_sd);
    EXPECT_NEAR(r.parameters[kAiryRadiusPx].map, c.airy_radius_px,
                4 * r.parameters[kAiryRadiusPx].laplace_sd);
    EXPECT_NEAR(r.parameters[kFluxE].map, c.exposures[0].flux_e,
                4 * r.parameters[kFluxE].laplace_sd);
    for (size_t k = 0; k < exposures.size(); ++k) {
      const auto& e = c.exposures[exposures[k]];
      EXPECT_NEAR(r.parameters[FitModel::XIndex(k)].map, e.x_px,
                  4 * r.parameters[FitModel::XIndex(k)].laplace_sd);
      EXPECT_NEAR(r.parameters[FitModel::YIndex(k)].map, e.y_px,
                  4 * r.parameters[FitModel::YIndex(k)].laplace_sd);
    }
  };
  check(joint, {0, 1, 2, 3, 4});
  for (int k = 0; k < 5; ++k) {
    FitResult single;
    auto m = MustCreate({stamps[k]});
    ASSERT_TRUE(RunFit(*m, NoMcmc(), &single, &error)) << error;
    check(single, {k});
    // Five exposures carry ~5x the information: sd ~ 1/sqrt(5) of a single one's.
    EXPECT_LT(joint.derived[ix].second.laplace_sd, 0.7 * single.derived[ix].second.laplace_sd);
    EXPECT_LT(joint.parameters[kAiryRadiusPx].laplace_sd,
              0.7 * single.parameters[kAiryRadiusPx].laplace_sd);
  }
}

// peak_e is the peak pixel of the fitted spot centred on a pixel (docs/metrics.md), not of
// the spot where it landed. Three exposures 0.4-0.45 px off a pixel centre, so the landed
// spot's peak pixel is ~10 % below the centred one's; the truth is the simulator's noiseless
// centred spot. Tolerance: 4 Laplace sds (~0.2 %), far below the 10 % that the landed peak
// would miss by (checked, so the test can fail).
TEST(Fit, PeakIsThatOfTheSpotCentredOnAPixel) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 3, 31);
  const double offsets[3][2] = {{0.4, 0.1}, {-0.45, 0.3}, {0.2, -0.42}};
  for (int k = 0; k < 3; ++k) {
    c.exposures[k].x_px = 10.0 + offsets[k][0];
    c.exposures[k].y_px = 10.0 + offsets[k][1];
  }
  auto peak_of = [&](double x, double y) {
    SimulatedExposure e = c.exposures[0];
    e.x_px = x;
    e.y_px = y;
    const Image m = ExpectedElectrons(c, e);
    return *std::max_element(m.data.begin(), m.data.end());
  };
  const double centred = peak_of(10.0, 10.0);
  double landed = 0.0;
  for (int k = 0; k < 3; ++k) landed += peak_of(c.exposures[k].x_px, c.exposures[k].y_px) / 3;
  ASSERT_LT(landed, 0.95 * centred);
  auto model = MustCreate(SimulateStamps(c, 12));
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
  const Summary& peak = r.derived[IndexOf(r, "peak_e")].second;
  ASSERT_TRUE(std::isfinite(peak.laplace_sd));
  EXPECT_NEAR(peak.map, centred, 4 * peak.laplace_sd);
  EXPECT_GT(std::fabs(peak.map - landed), 20 * peak.laplace_sd);
}

// docs/trust.md, single focus: with a Gaussian defocus and integrated sampling, the split between
// defocus and CCD widths is not identified: the fit must say so and give no Laplace sd for
// them or for any metric built from the CCD widths alone.
TEST(Fit, ReportsTheDefocusDegeneracyHonestly) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 9);
  auto model = MustCreate(SimulateStamps(c, 10));
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
  ASSERT_EQ(r.laplace.unconstrained.size(), 1u);
  const UnconstrainedDirection& d = r.laplace.unconstrained[0];
  EXPECT_TRUE(std::isinf(d.sd_fraction_of_prior));
  // Along the null direction sigma_f dsigma_f + sigma_x dsigma_x = 0 (and for y).
  const auto& t = r.map.theta;
  EXPECT_NEAR(t[kDefocusPx] * d.direction[kDefocusPx] + t[kCcdSigmaXPx] * d.direction[kCcdSigmaXPx],
              0.0, 1e-3);
  EXPECT_NEAR(t[kDefocusPx] * d.direction[kDefocusPx] + t[kCcdSigmaYPx] * d.direction[kCcdSigmaYPx],
              0.0, 1e-3);
  for (int i : {kDefocusPx, kCcdSigmaXPx, kCcdSigmaYPx}) {
    EXPECT_TRUE(std::isnan(r.parameters[i].laplace_sd)) << r.names[i];
  }
  for (const char* name : {"fwhm_um", "fwhm_x_um", "r2_px2", "ellipticity"}) {
    EXPECT_TRUE(std::isnan(r.derived[IndexOf(r, name)].second.laplace_sd)) << name;
  }
  for (const char* name : {"total_sigma_x_px", "total_sigma_y_px", "total_fwhm_um", "peak_e"}) {
    EXPECT_TRUE(std::isfinite(r.derived[IndexOf(r, name)].second.laplace_sd)) << name;
  }
  EXPECT_TRUE(std::isfinite(r.parameters[kFluxE].laplace_sd));
}

// The same at a MAP with zero defocus (a spot in perfect focus): the model depends on the
// defocus through its square, so the local curvature sees the defocus alone as free and would
// give the CCD widths a small, false sd. They must still get none.
TEST(Fit, ReportsTheDegeneracyAtZeroDefocus) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 9);
  c.defocus_px = 0.0;
  FitModelOptions options;
  auto model = MustCreate(SimulateStamps(c, 10), options);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
  for (int i : {kDefocusPx, kCcdSigmaXPx, kCcdSigmaYPx}) {
    EXPECT_TRUE(std::isnan(r.parameters[i].laplace_sd)) << r.names[i];
  }
  for (const char* name : {"fwhm_um", "fwhm_x_um", "fwhm_y_um", "r2_px2", "ellipticity"}) {
    EXPECT_TRUE(std::isnan(r.derived[IndexOf(r, name)].second.laplace_sd)) << name;
  }
  bool named = false;
  for (const UnconstrainedDirection& d : r.laplace.unconstrained) {
    named = named || d.description.find("convolve to one Gaussian") != std::string::npos;
  }
  EXPECT_TRUE(named);
  EXPECT_TRUE(std::isfinite(r.derived[IndexOf(r, "total_fwhm_um")].second.laplace_sd));
}

// The answer must not depend on the luck of a start: every single start lands on the same
// identified solution.
TEST(Fit, EveryStartReachesTheSameSolution) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 11);
  auto model = MustCreate(SimulateStamps(c, 12));
  std::vector<double> totals_x, costs;
  for (double r0 : {0.2, 0.6, 1.2}) {
    for (double share : {0.1, 0.9}) {
      MapOptions o;
      o.start_airy_radii_px = {r0};
      o.start_defocus_shares = {share};
      MapResult m;
      std::string error;
      ASSERT_TRUE(FindMap(*model, o, &m, &error)) << error;
      totals_x.push_back(TotalSigma(m.theta[kDefocusPx], m.theta[kCcdSigmaXPx]));
      costs.push_back(m.log_likelihood);
    }
  }
  for (size_t i = 1; i < costs.size(); ++i) {
    // log L to 1e-3: a parameter shift of 0.045 sd along the best-constrained direction.
    EXPECT_NEAR(costs[i], costs[0], 1e-3);
    // The identified width's Laplace sd is ~1e-3 px; agreement to 1e-5 px is convergence.
    EXPECT_NEAR(totals_x[i], totals_x[0], 1e-5);
  }
}

// Simulation-based calibration (reduced): over 60 data sets the Laplace 68 % intervals of
// the identified quantities must contain the truth 68 % of the time. With n = 60 the
// binomial sd of the coverage is 6 %; we accept 68 +- 18 % (3 sd). The full run (larger n,
// MCMC intervals) is tools/calibration_check.sh.
TEST(Fit, LaplaceIntervalsAreCalibrated) {
  CCDPSF_RELEASE_ONLY();  // many fits; see Fit.RecoversIdentifiedQuantitiesAndJointIsTighter for
  // the sanitized run
  const int n = 60;
  int inside_tx = 0, inside_r = 0, inside_flux = 0, inside_x = 0;
  for (int s = 0; s < n; ++s) {
    const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 100 + s);
    auto model = MustCreate(SimulateStamps(c, 1000 + s));
    FitResult r;
    std::string error;
    ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
    const Summary& tx = r.derived[IndexOf(r, "total_sigma_x_px")].second;
    inside_tx += std::fabs(tx.map - TotalSigma(c.defocus_px, c.ccd_sigma_x_px)) < tx.laplace_sd;
    const Summary& rr = r.parameters[kAiryRadiusPx];
    inside_r += std::fabs(rr.map - c.airy_radius_px) < rr.laplace_sd;
    const Summary& f = r.parameters[kFluxE];
    inside_flux += std::fabs(f.map - c.exposures[0].flux_e) < f.laplace_sd;
    const Summary& x = r.parameters[FitModel::XIndex(0)];
    inside_x += std::fabs(x.map - c.exposures[0].x_px) < x.laplace_sd;
  }
  for (int inside : {inside_tx, inside_r, inside_flux, inside_x}) {
    EXPECT_GE(inside, static_cast<int>(0.50 * n));
    EXPECT_LE(inside, static_cast<int>(0.86 * n));
  }
}

// The scores behind the sandwich sd: at the true parameters their outer products average to
// the Fisher information (the information identity), here over 60 realisations of one
// exposure, for every parameter. Each realisation's diagonal entry scatters by ~sqrt(2 /
// n_eff) of its mean (~0.5 for the positions, which a few flank pixels inform), so the mean
// of 60 is held to 1 +- 0.2 (3 sd for the positions, more for the rest).
TEST(Fit, ScoresAverageToTheFisherInformation) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 9);
  std::vector<double> truth = {c.exposures[0].flux_e, c.airy_radius_px, c.defocus_px,
                               c.ccd_sigma_x_px,      c.ccd_sigma_y_px, c.exposures[0].x_px,
                               c.exposures[0].y_px};
  const int n = 60;
  std::vector<double> ratio_sum(truth.size(), 0.0);
  for (int s = 0; s < n; ++s) {
    auto model = MustCreate(SimulateStamps(c, 500 + s));
    auto ev = model->NewEvaluator();
    const std::vector<double> meat = ev->ScoreOuterProducts(truth.data());
    const std::vector<double> fisher = ev->FisherInformation(truth.data());
    const int dim = model->dim();
    ASSERT_EQ(dim, static_cast<int>(truth.size()));
    for (int i = 0; i < dim; ++i) ratio_sum[i] += meat[i * dim + i] / fisher[i * dim + i] / n;
  }
  for (size_t i = 0; i < truth.size(); ++i) EXPECT_NEAR(ratio_sum[i], 1.0, 0.2) << i;
}

// The sandwich sd where the noise model understates the noise. Two independent noisy
// realisations A, B of the same joint set (5 exposures) make C = A + u (A - B) with u = 0.823:
// its noise about the truth is A's times (1 + u) less B's times u, variance (1 + u)^2 + u^2 =
// 4.00 times the noise model's at every pixel. Fitted with the stated noise, chi^2/dof comes
// out ~4, and the sandwich sd of the widths and the Airy radius (each informed by hundreds of
// pixels) grows by ~1.6-2 over the Laplace sd (not exactly 2: the variance term of the
// shot-noise likelihood moves the MAP and weighs the residuals' fourth moment); on A itself
// (the model right) they agree within the meat's scatter. Held: chi^2/dof 4 +- 0.6 and 1 +-
// 0.15 (dof ~2200); ratio > 1.4 misspecified, 1 +- 0.25 right.
TEST(Fit, SandwichSdGrowsWhereTheNoiseIsUnderstated) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 5, 7);
  const std::vector<Stamp> a = SimulateStamps(c, 71), b = SimulateStamps(c, 72);
  std::vector<Stamp> inflated = a;
  const double u = 0.823;
  for (size_t k = 0; k < a.size(); ++k) {
    for (size_t q = 0; q < a[k].electrons.data.size(); ++q) {
      inflated[k].electrons.data[q] += u * (a[k].electrons.data[q] - b[k].electrons.data[q]);
      // Masks and censoring of either realisation apply (both are tiny here).
      inflated[k].valid[q] = a[k].valid[q] && b[k].valid[q];
    }
    inflated[k].censor.clear();
    inflated[k].adc_step_e = 0.0;  // no longer whole ADU
  }
  for (const bool misspecified : {false, true}) {
    auto model = MustCreate(misspecified ? inflated : a);
    FitResult r;
    std::string error;
    ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
    EXPECT_NEAR(r.map.chi2 / r.map.dof, misspecified ? 4.0 : 1.0, misspecified ? 0.6 : 0.15);
    std::vector<std::pair<std::string, Summary>> checked = {
        {"airy_radius_px", r.parameters[kAiryRadiusPx]}};
    for (const char* name : {"total_sigma_x_px", "total_sigma_y_px", "total_fwhm_um"}) {
      checked.push_back(r.derived[IndexOf(r, name)]);
    }
    for (const auto& [name, s] : checked) {
      const double ratio = s.sandwich_sd / s.laplace_sd;
      if (misspecified) {
        EXPECT_GT(ratio, 1.4) << name;
        EXPECT_LT(ratio, 2.6) << name;
      } else {
        EXPECT_NEAR(ratio, 1.0, 0.25) << name;
      }
    }
  }
}

// The undersampled note: the paper's spot (total widths 0.50 / 0.53 px) puts well under half
// its light in its brightest pixel (no note); with the defocus and CCD kernel shrunk to 0.05
// and 0.1 px (the Airy pattern alone, nearly) most of it falls there (the note, naming the
// pixel response and sampling). The share is the model's at the MAP.
TEST(Fit, UndersampledSpotIsSaidOutLoud) {
  for (const bool narrow : {false, true}) {
    SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 13);
    if (narrow) {
      c.defocus_px = 0.05;
      c.ccd_sigma_x_px = 0.1;
      c.ccd_sigma_y_px = 0.1;
      c.exposures[0].flux_e *= 0.3;  // the narrower peak stays below saturation
    }
    auto model = MustCreate(SimulateStamps(c, 14));
    FitResult r;
    std::string error;
    ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
    Quality quality;
    AssessSampling(*model, r, FitQualityOptions(), &quality);
    bool noted = false;
    for (const Finding& f : quality.findings) {
      if (f.code != "undersampled") continue;
      noted = true;
      EXPECT_EQ(f.severity, Severity::kNote);
      EXPECT_NE(f.message.find("pixel_response_width"), std::string::npos) << f.message;
    }
    EXPECT_EQ(noted, narrow) << "chi2/dof " << r.map.chi2 / r.map.dof;
  }
}

// LaplaceInterval68 against its closed forms: map -+ sd for a signed quantity; for a positive
// one the interval of its logarithm, which never goes below 0 (grid's psf_map.csv gave
// 0.80 [-0.69, 2.30] um) and approaches map -+ sd as sd / map -> 0 (error (sd/map)^2 / 2 of sd).
TEST(Fit, LaplaceIntervalOfAPositiveQuantityStaysPositive) {
  double lo, hi;
  LaplaceInterval68(0.80, 1.49, false, &lo, &hi);
  EXPECT_DOUBLE_EQ(lo, 0.80 - 1.49);
  EXPECT_DOUBLE_EQ(hi, 0.80 + 1.49);
  LaplaceInterval68(0.80, 1.49, true, &lo, &hi);
  EXPECT_NEAR(lo, 0.80 * std::exp(-1.49 / 0.80), 1e-15);
  EXPECT_NEAR(hi, 0.80 * std::exp(1.49 / 0.80), 1e-14);
  EXPECT_GT(lo, 0.0);
  LaplaceInterval68(3.0, 0.03, true, &lo, &hi);
  EXPECT_NEAR(lo, 3.0 - 0.03, 0.03 * 0.01);
  EXPECT_NEAR(hi, 3.0 + 0.03, 0.03 * 0.01);
  LaplaceInterval68(0.5, NAN, true, &lo, &hi);
  EXPECT_TRUE(std::isnan(lo) && std::isnan(hi));
}

// pixel_centre data fitted in pixel_centre mode: the 2015 discretisation separates defocus
// from the CCD kernel, so the paper-style sigma_f, sigma_x, sigma_y come back individually.
TEST(Fit, PixelCentreRecoversSeparateWidths) {
  CCDPSF_RELEASE_ONLY();  // fits with MCMC; see Fit.McmcIsDeterministicAndAgreesWithLaplace for the
  // sanitized run
  const SimulationConfig c = PaperConfig(model::Sampling::kPixelCentre, 5, 13);
  FitModelOptions options;
  options.model.sampling = model::Sampling::kPixelCentre;
  auto model = MustCreate(SimulateStamps(c, 14), options);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
  EXPECT_TRUE(r.laplace.unconstrained.empty());
  EXPECT_TRUE(r.laplace.at_bound.empty());  // peak_e's prior spans 8 decades: not "at" it
  const double truth[3] = {c.defocus_px, c.ccd_sigma_x_px, c.ccd_sigma_y_px};
  const int index[3] = {kDefocusPx, kCcdSigmaXPx, kCcdSigmaYPx};
  for (int j = 0; j < 3; ++j) {
    const Summary& s = r.parameters[index[j]];
    ASSERT_TRUE(std::isfinite(s.laplace_sd)) << r.names[index[j]];
    EXPECT_NEAR(s.map, truth[j], 4 * s.laplace_sd) << r.names[index[j]];
  }
  EXPECT_NEAR(r.parameters[kFluxE].map, 1.5e5, 4 * r.parameters[kFluxE].laplace_sd);
}

// Low signal in pixel_centre (Table 1's 7.1 ke- setting, ten exposures): one exposure cannot
// tell the posterior's basins apart, and a joint fit seeded from one used to end in a wrong
// basin (chi^2/dof 1.28 against 0.97 at the truth on Table 1's simulation; on this data set,
// 1.025 against 1.021, a shortfall of ~10 in log L). The MAP must be at least as likely as the
// truth; the tolerance, 0.5 in log L, is far above the solver's convergence tolerance. Of ten
// seeds the single-exposure seeding failed three (this is one), the joint screening none.
TEST(Map, LowSignalPixelCentreJointFitFindsTheBestBasin) {
  CCDPSF_RELEASE_ONLY();  // a multi-start joint MAP; see Fit.EveryStartReachesTheSameSolution for
  // the sanitized run
  SimulationConfig c = PaperConfig(model::Sampling::kPixelCentre, 10, 45);
  for (auto& e : c.exposures) e.flux_e = 7100;
  FitModelOptions options;
  options.model.sampling = model::Sampling::kPixelCentre;
  auto model = MustCreate(SimulateStamps(c, 46), options);
  MapResult map;
  std::string error;
  ASSERT_TRUE(FindMap(*model, MapOptions(), &map, &error)) << error;
  std::vector<double> truth = {7100, c.airy_radius_px, c.defocus_px, c.ccd_sigma_x_px,
                               c.ccd_sigma_y_px};
  for (const auto& e : c.exposures) {
    truth.push_back(e.x_px);
    truth.push_back(e.y_px);
  }
  auto ev = model->NewEvaluator();
  EXPECT_GE(map.log_likelihood, ev->LogLikelihood(truth.data()) - 0.5)
      << "MAP chi2/dof " << map.chi2 / map.dof << ", truth chi2/dof "
      << ev->ChiSquare(truth.data()) / map.dof;
}

// The grid screening keeps the best point of every Airy radius, not only the best ten: on
// the Table-1 700 nm setting of one simulated campaign (testdata/campaign_table1.json, seed
// 504, cut to its eight settings >= 82.8 ke-; six exposures at 151.7 ke-, truth r = 0.411
// px) the ten best grid points all led to r = 0.362 px at chi^2/dof 1.634, 800 in log L
// below the basin of the truth (chi^2/dof 1.013). The MAP's chi^2/dof must be within 5 sd
// of 1 (sd sqrt(2 / dof) = 0.028).
TEST(Map, PixelCentreScreeningKeepsEveryAiryRadius) {
  CCDPSF_RELEASE_ONLY();  // many MAP fits; the screening runs sanitized in
  // Fit.EveryStartReachesTheSameSolution
  namespace fs = std::filesystem;
  std::string error;
  auto config = LoadCampaignConfig(std::string(CCDPSF_TESTDATA) + "/campaign_table1.json", &error);
  ASSERT_TRUE(config) << error;
  config->seed = 504;
  std::vector<CampaignSetting> high;
  for (const CampaignSetting& s : config->settings) {
    if (s.peak_e >= 82800) high.push_back(s);
  }
  config->settings = high;
  const std::string dir = ::testing::TempDir() + "/ccdpsf_screen_" + std::to_string(::getpid());
  fs::remove_all(dir);
  CampaignResult sim;
  ASSERT_TRUE(RunCampaign(*config, dir, false, &sim, &error)) << error;
  std::vector<trend::CampaignGroup> groups;
  ASSERT_TRUE(trend::LoadCampaign({sim.manifest_path}, &groups, &error)) << error;
  std::vector<Stamp> stamps;
  for (const trend::CampaignGroup& g : groups) {
    if (g.wavelength_nm != 700) continue;
    for (const std::string& f : g.files) {
      std::optional<Exposure> e = LoadExposure(f, CalibrationOptions(), &error);
      ASSERT_TRUE(e) << error;
      stamps.push_back(e->stamp);
    }
  }
  fs::remove_all(dir);
  ASSERT_EQ(stamps.size(), 6u);
  FitModelOptions options;
  options.model.sampling = model::Sampling::kPixelCentre;
  auto model = MustCreate(stamps, options);
  MapResult map;
  ASSERT_TRUE(FindMap(*model, MapOptions(), &map, &error)) << error;
  const double chi2_per_dof = map.chi2 / map.dof;
  EXPECT_LT(std::fabs(chi2_per_dof - 1.0), 5.0 * std::sqrt(2.0 / map.dof)) << chi2_per_dof;
  EXPECT_NEAR(map.theta[kAiryRadiusPx], 0.41125, 0.01);
  // The screening's grid scores, refinements and local solves run on num_threads threads
  // (two by default), each writing only its own results, and the final solves on a fixed
  // number of Ceres threads: on one screening thread the MAP is the same to the last bit.
  MapOptions one_thread;
  one_thread.num_threads = 1;
  MapResult map1;
  ASSERT_TRUE(FindMap(*model, one_thread, &map1, &error)) << error;
  EXPECT_EQ(map1.theta, map.theta);
  // Ceres sums each cost over its threads in the order they finish: 1e-12 relative.
  ASSERT_EQ(map1.start_costs.size(), map.start_costs.size());
  for (size_t i = 0; i < map.start_costs.size(); ++i) {
    EXPECT_NEAR(map1.start_costs[i], map.start_costs[i], 1e-12 * map.start_costs[i]) << i;
  }
}

// A short MCMC: intervals contain the identified truths, the chain is identical for 1 and 2
// threads with one seed, and MCMC agrees with Laplace where the posterior is Gaussian.
TEST(Fit, McmcIsDeterministicAndAgreesWithLaplace) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 15);
  auto model = MustCreate(SimulateStamps(c, 16));
  FitOptions o;
  o.mcmc.seed = 3;
  o.mcmc.target_ess = 300;
  o.mcmc.min_tau_multiple = 20;
  o.mcmc.max_steps = 4000;
  o.mcmc.progress = false;
  FitResult a, b;
  std::string error;
  o.mcmc.num_threads = 1;
  ASSERT_TRUE(RunFit(*model, o, &a, &error)) << error;
  o.mcmc.num_threads = 2;
  ASSERT_TRUE(RunFit(*model, o, &b, &error)) << error;
  ASSERT_EQ(a.chain.chain.size(), b.chain.chain.size());
  EXPECT_TRUE(a.chain.chain == b.chain.chain);
  // So are the derived quantities' posteriors, whose peak-pixel draws are rendered on the
  // MCMC's threads.
  ASSERT_EQ(a.derived.size(), b.derived.size());
  const auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  for (size_t j = 0; j < a.derived.size(); ++j) {
    const Summary &sa = a.derived[j].second, &sb = b.derived[j].second;
    EXPECT_TRUE(same(sa.median, sb.median) && same(sa.lo68, sb.lo68) && same(sa.hi68, sb.hi68) &&
                same(sa.lo997, sb.lo997) && same(sa.hi997, sb.hi997))
        << a.derived[j].first;
  }
  const Summary& tx = a.derived[IndexOf(a, "total_sigma_x_px")].second;
  const double truth = TotalSigma(c.defocus_px, c.ccd_sigma_x_px);
  EXPECT_GT(truth, tx.lo997);
  EXPECT_LT(truth, tx.hi997);
  // Gaussian posterior: half the 68 % interval equals the Laplace sd; with ESS >= 300 the
  // interval width is known to ~8 %, so 25 % is generous.
  for (int i : {kFluxE, kAiryRadiusPx}) {
    const Summary& s = a.parameters[i];
    EXPECT_NEAR(0.5 * (s.hi68 - s.lo68) / s.laplace_sd, 1.0, 0.25) << a.names[i];
    EXPECT_NEAR(s.median, s.map, 0.3 * s.laplace_sd) << a.names[i];
  }
  // The unconstrained CCD width spreads over a large part of its prior.
  const Summary& sx = a.parameters[kCcdSigmaXPx];
  EXPECT_GT(sx.hi68 - sx.lo68, 0.1);
}

// The blocked sampler (defocus integrated out, positions by conditional moves:
// posterior_target.h) and the plain ensemble over every parameter target the same posterior:
// their medians agree within 4 combined Monte Carlo errors (se = half the 68 % interval /
// sqrt(ESS)) and their 68 % widths within 25 % (the width of an interval from ESS >= 300
// draws is known to ~6 %; 25 % is ~3 combined sd). Checked on identified quantities, the
// positions, and the prior-dominated CCD width and defocus (the part the blocked sampler
// draws from its exact conditional instead of walking).
TEST(Fit, BlockedSamplerAgreesWithPlainEnsemble) {
  CCDPSF_RELEASE_ONLY();  // two long chains; see Fit.McmcIsDeterministicAndAgreesWithLaplace for
  // the sanitized run
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 2, 41);
  auto model = MustCreate(SimulateStamps(c, 42));
  FitOptions o;
  // Both runs to 50 tau (emcee's advice for a reliable tau, hence honest errors): at 20 tau
  // the Laplace-move chains are ~200 steps and their tau estimates optimistic. Seed 1: with
  // seed 5 (used until the renderer's rounding changed, which changes every chain) the plain
  // run made a ~4 sd excursion along the ridge (ccd_sigma_x median 0.311, against
  // 0.286-0.298 for seeds 1, 2, 3, 4, 6).
  o.mcmc.seed = 1;
  o.mcmc.target_ess = 300;
  o.mcmc.min_tau_multiple = 50;
  o.mcmc.max_steps = 8000;
  o.mcmc.progress = false;
  FitResult blocked, plain;
  std::string error;
  ASSERT_TRUE(RunFit(*model, o, &blocked, &error)) << error;
  o.target.marginal_defocus = false;
  o.target.positions_by_conditional = false;
  o.mcmc.max_steps = 30000;  // the plain ensemble walks the flat ridge slowly
  ASSERT_TRUE(RunFit(*model, o, &plain, &error)) << error;
  ASSERT_TRUE(blocked.chain.converged) << blocked.chain.stop_reason;
  ASSERT_TRUE(plain.chain.converged) << plain.chain.stop_reason;
  auto compare = [&](const Summary& a, const Summary& b, double ess_a, double ess_b,
                     const std::string& name) {
    const double wa = 0.5 * (a.hi68 - a.lo68), wb = 0.5 * (b.hi68 - b.lo68);
    const double se = std::sqrt(wa * wa / ess_a + wb * wb / ess_b);
    EXPECT_NEAR(a.median, b.median, 4.0 * se) << name;
    EXPECT_NEAR(wa / wb, 1.0, 0.25) << name;
  };
  for (int i :
       {static_cast<int>(kFluxE), static_cast<int>(kAiryRadiusPx), static_cast<int>(kDefocusPx),
        static_cast<int>(kCcdSigmaXPx), FitModel::XIndex(1), FitModel::YIndex(0)}) {
    compare(blocked.parameters[i], plain.parameters[i], blocked.chain.ess[i], plain.chain.ess[i],
            blocked.names[i]);
  }
  const double ess_a = *std::min_element(blocked.chain.ess.begin(), blocked.chain.ess.end());
  const double ess_b = *std::min_element(plain.chain.ess.begin(), plain.chain.ess.end());
  for (const char* name : {"total_sigma_x_px", "total_sigma_y_px", "ellipticity"}) {
    compare(blocked.derived[IndexOf(blocked, name)].second,
            plain.derived[IndexOf(plain, name)].second, ess_a, ess_b, name);
  }
}

// Post-burn-in mean and sd of parameter i of a fit's chain (theta coordinates).
void ChainMeanSd(const FitResult& r, int i, double* mean, double* sd) {
  const SamplerResult& c = r.chain;
  const size_t first = static_cast<size_t>(c.burn_in) * c.num_walkers;
  const size_t last = static_cast<size_t>(c.num_steps) * c.num_walkers;
  double sum = 0.0, sum2 = 0.0;
  for (size_t s = first; s < last; ++s) sum += c.chain[s * c.dim + i];
  *mean = sum / (last - first);
  for (size_t s = first; s < last; ++s) {
    const double d = c.chain[s * c.dim + i] - *mean;
    sum2 += d * d;
  }
  *sd = std::sqrt(sum2 / (last - first - 1));
}

// issue 18: the sampler with the Laplace-informed independence move (the default) targets the
// posterior of the stretch-only sampler, checked against a long stretch-only run (ESS >= 2000)
// on a single exposure and on a two-exposure joint fit (positions by conditional moves, the
// independence move on the shared block). For every parameter the posterior mean and the
// 16 / 50 / 84 % quantiles agree within 4 combined Monte Carlo standard errors:
//   mean:      sd / sqrt(ESS);
//   quantile:  sqrt(q (1 - q) / ESS) / f(x_q), with the density f at the quantile taken as a
//              Gaussian's of sd w = half the 68 % interval: 1.51 w / sqrt(ESS) at 16 and
//              84 %, 1.25 w / sqrt(ESS) at the median (for the flat-topped, prior-dominated
//              CCD widths this overstates the error by ~30 %, a conservative choice).
// ESS is the run's per-parameter ESS. 4 SE: 4 x 7-11 parameters x 2 fits ~ 70 checks, each
// failing by chance with probability 6e-5, while a sampler that missed the tails (e.g. an
// independence move without its q ratio, pulled to the Laplace centre) shifts the 16 / 84 %
// quantiles by ~0.1 sd, several SE at ESS 1000.
TEST(Fit, LaplaceMoveAgreesWithALongStretchOnlyRun) {
  CCDPSF_RELEASE_ONLY();  // two long chains; the fit's MCMC runs sanitized in
  // Fit.McmcIsDeterministicAndAgreesWithLaplace
  for (const int exposures : {1, 2}) {
    SCOPED_TRACE(std::to_string(exposures) + " exposure(s)");
    const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, exposures, 51);
    auto model = MustCreate(SimulateStamps(c, 52));
    FitOptions o;
    o.mcmc.seed = 7;
    o.mcmc.progress = false;
    FitResult fast, reference;
    std::string error;
    ASSERT_TRUE(RunFit(*model, o, &fast, &error)) << error;
    ASSERT_TRUE(fast.chain.converged) << fast.chain.stop_reason;
    ASSERT_GT(fast.chain.independence_proposed, 0);
    o.target.laplace_move_fraction = 0.0;
    o.mcmc.target_ess = 2000;
    ASSERT_TRUE(RunFit(*model, o, &reference, &error, &fast.map)) << error;
    ASSERT_TRUE(reference.chain.converged) << reference.chain.stop_reason;
    EXPECT_EQ(reference.chain.independence_proposed, 0);
    for (int i = 0; i < model->dim(); ++i) {
      SCOPED_TRACE(fast.names[i]);
      const double ess_a = fast.chain.ess[i], ess_b = reference.chain.ess[i];
      double mean_a, sd_a, mean_b, sd_b;
      ChainMeanSd(fast, i, &mean_a, &sd_a);
      ChainMeanSd(reference, i, &mean_b, &sd_b);
      EXPECT_NEAR(mean_a, mean_b, 4.0 * std::sqrt(sd_a * sd_a / ess_a + sd_b * sd_b / ess_b));
      const Summary& a = fast.parameters[i];
      const Summary& b = reference.parameters[i];
      const double wa = 0.5 * (a.hi68 - a.lo68), wb = 0.5 * (b.hi68 - b.lo68);
      auto se = [&](double factor) {
        return factor * std::sqrt(wa * wa / ess_a + wb * wb / ess_b);
      };
      EXPECT_NEAR(a.lo68, b.lo68, 4.0 * se(1.51));
      EXPECT_NEAR(a.median, b.median, 4.0 * se(1.25));
      EXPECT_NEAR(a.hi68, b.hi68, 4.0 * se(1.51));
    }
  }
}

// docs/trust.md, Identifiability: a prior excluding the truth pins the MAP to its bound; that must
// be flagged (Ceres' covariance, and a Laplace approximation, ignore bounds).
TEST(Fit, FlagsParametersAtABound) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 19);
  FitModelOptions options;
  options.priors.airy_radius_px[0] = 0.6;  // truth 0.47
  auto model = MustCreate(SimulateStamps(c, 20), options);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*model, NoMcmc(), &r, &error)) << error;
  ASSERT_EQ(r.laplace.at_bound.size(), 1u);
  EXPECT_EQ(r.names[r.laplace.at_bound[0]], "airy_radius_px");
  EXPECT_NEAR(r.map.theta[kAiryRadiusPx], 0.6, 1e-9);
}

TEST(Fit, BadInputIsReported) {
  std::string error;
  EXPECT_EQ(FitModel::Create({}, FitModelOptions(), &error), nullptr);
  EXPECT_NE(error.find("no exposures"), std::string::npos);

  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 2, 17);
  std::vector<Stamp> stamps = SimulateStamps(c, 18);
  std::vector<Stamp> mixed = stamps;
  mixed[1].electrons = Image(15, 15);
  mixed[1].valid.assign(225, 1);
  EXPECT_EQ(FitModel::Create(mixed, FitModelOptions(), &error), nullptr);
  EXPECT_NE(error.find("one stamp size"), std::string::npos) << error;

  std::vector<Stamp> masked = {stamps[0]};
  std::fill(masked[0].valid.begin(), masked[0].valid.end(), 0);
  EXPECT_EQ(FitModel::Create(masked, FitModelOptions(), &error), nullptr);
  EXPECT_NE(error.find("every pixel"), std::string::npos) << error;

  std::vector<Stamp> empty = {stamps[0]};
  std::fill(empty[0].electrons.data.begin(), empty[0].electrons.data.end(), 0.0);
  EXPECT_EQ(FitModel::Create(empty, FitModelOptions(), &error), nullptr);
  EXPECT_NE(error.find("no spot"), std::string::npos) << error;

  // A fit that cannot converge: one iteration allowed.
  auto model = MustCreate({stamps[0]});
  FitOptions o = NoMcmc();
  o.map.max_iterations = 1;
  FitResult r;
  EXPECT_FALSE(RunFit(*model, o, &r, &error));
  EXPECT_NE(error.find("did not converge"), std::string::npos) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos);
}

TEST(FitConfig, ParsesOverridesAndRejectsUnknownKeys) {
  FitConfig c;
  std::string error;
  ASSERT_TRUE(ParseFitConfig(R"({"sampling": "pixel_centre", "joint": true,
      "priors": {"airy_radius_px": [0.2, 1.0]}, "mcmc": {"seed": 9, "walkers": 40},
      "calibration": {"gain_e_per_adu": 2.5, "stamp_size": 15},
      "flags": {"outliers": false, "pixel_um": 12}})",
                             &c, &error))
      << error;
  EXPECT_EQ(c.model.model.sampling, model::Sampling::kPixelCentre);
  EXPECT_TRUE(c.joint);
  EXPECT_EQ(c.model.priors.airy_radius_px[0], 0.2);
  EXPECT_EQ(c.fit.mcmc.seed, 9u);
  EXPECT_EQ(c.fit.num_walkers, 40);
  ASSERT_TRUE(c.calibration.given.Find("gain_e_per_adu") != nullptr);
  EXPECT_EQ(*c.calibration.given.Find("gain_e_per_adu")->number, 2.5);
  EXPECT_EQ(c.calibration.given.Find("gain_e_per_adu")->source, "FIT.json");
  EXPECT_EQ(c.calibration.stamp_size, 15);
  // "flags" is kept as read, for the tool to apply.
  EXPECT_EQ(c.flags, nlohmann::json({{"outliers", false}, {"pixel_um", 12}}));
  for (const char* bad :
       {R"({"priors": {"airy_radius": [0.2, 1.0]}})",
        R"({"priors": {"airy_radius_px": [1.0, 0.2]}})", R"({"likelihood": "cauchy"})",
        R"({"mcmc": {"walkers": -2}})", R"({"calibration": {"gain_e_per_adu": 0}})",
        R"({"flags": [1, 2]})", R"({"pixel_response_width": 0})",
        R"({"pixel_response_width": 1.2})", R"({"pixel_response_width": "0.8"})", "{oops"}) {
    FitConfig d;
    EXPECT_FALSE(ParseFitConfig(bad, &d, &error)) << bad;
    EXPECT_FALSE(error.empty());
  }
}

// A pixel response narrower than the pixel: read, written back (a run's config.json), and
// refused with the 2015 discretisation, which has no collecting window.
TEST(FitConfig, PixelResponseWidthRoundTripsAndNeedsIntegratedSampling) {
  FitConfig c;
  std::string error;
  ASSERT_TRUE(ParseFitConfig(R"({"pixel_response_width": 0.8})", &c, &error)) << error;
  EXPECT_EQ(c.model.model.pixel_response_width, 0.8);
  FitConfig again;
  ASSERT_TRUE(ParseFitConfig(FitConfigJson(c).dump(), &again, &error)) << error;
  EXPECT_EQ(again.model.model.pixel_response_width, 0.8);
  EXPECT_EQ(FitConfigJson(FitConfig())["pixel_response_width"], 1.0);

  FitModelOptions o = c.model;
  o.model.sampling = model::Sampling::kPixelCentre;
  const std::vector<Stamp> stamps =
      SimulateStamps(PaperConfig(model::Sampling::kPixelCentre, 1, 17), 18);
  EXPECT_EQ(FitModel::Create(stamps, o, &error), nullptr);
  EXPECT_NE(error.find("pixel_response_width"), std::string::npos) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace ccdpsf::fit
