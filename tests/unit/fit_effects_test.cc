// Effects of the catalogue as components of the fit's model (fit_model.h, "Effects"): the
// fit's expected image against the simulator's forward model, its derivatives against
// numerical differentiation, the joint likelihood against the sum of singles, and recovery of
// hidden effects from simulations with known truth.
#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/simulate.h"
#include "ceres/ceres.h"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"

namespace ccdpsf::fit {
namespace {

using model::EffectKind;
using testing_support::MustCreate;
using testing_support::PaperConfig;
using testing_support::SimulateStamps;

// Every fittable effect, at strengths well above the realistic ones so that each is visible
// in the comparisons (values in catalogue order of their parameters).
struct EffectValue {
  EffectKind kind;
  std::vector<double> values;
};
const std::vector<EffectValue>& StrongEffects() {
  static const std::vector<EffectValue> effects = {
      {EffectKind::kBrighterFatter, {6e-7, 3e-7}},
      {EffectKind::kSerialCti, {4e-3, 1.7}},
      {EffectKind::kParallelCti, {2e-3, 0.9}},
      {EffectKind::kIpc, {0.015}},
      {EffectKind::kBackground, {12.0}},
      {EffectKind::kNonlinearity, {2e-7}},
      {EffectKind::kHalo, {0.04, 2.2}},
  };
  return effects;
}

FitModelOptions WithEffects(const std::vector<EffectValue>& effects) {
  FitModelOptions options;
  for (const EffectValue& e : effects) options.effects.push_back({e.kind, {}});
  return options;
}

// theta at the paper's truth for exposure positions from `c`, the given flux and effects.
std::vector<double> TruthTheta(const FitModel& m, const SimulationConfig& c, double flux,
                               const std::vector<EffectValue>& effects) {
  std::vector<double> theta(m.dim(), 0.0);
  theta[kFluxE] = flux;
  theta[kAiryRadiusPx] = c.airy_radius_px;
  theta[kDefocusPx] = c.defocus_px;
  theta[kCcdSigmaXPx] = c.ccd_sigma_x_px;
  theta[kCcdSigmaYPx] = c.ccd_sigma_y_px;
  for (int k = 0; k < m.num_exposures(); ++k) {
    theta[FitModel::XIndex(k)] = c.exposures[k].x_px;
    theta[FitModel::YIndex(k)] = c.exposures[k].y_px;
    if (m.RatioIndex(k) >= 0)
      theta[m.RatioIndex(k)] = c.exposures[k].flux_e / c.exposures[0].flux_e;
  }
  for (const EffectValue& e : effects) {
    for (size_t p = 0; p < e.values.size(); ++p) theta[m.EffectIndex(e.kind) + p] = e.values[p];
  }
  return theta;
}

// StrongEffects, and in pixel_centre sampling (the 2015 model) defocus_offset too: there the
// F kernel centred away from the Airy centre is not a shift. In integrated sampling
// boundary_shift too (it needs the pixel integral), at four times its realistic coefficients.
std::vector<EffectValue> StrongEffects(model::Sampling sampling) {
  std::vector<EffectValue> effects = StrongEffects();
  if (sampling == model::Sampling::kPixelCentre) {
    effects.push_back({EffectKind::kDefocusOffset, {0.12, -0.08}});
  } else {
    effects.push_back({EffectKind::kBoundaryShift, {6e-7, 8e-7, 2.4e-7, 6e-8, -0.2}});
  }
  return effects;
}

// Every effect of StrongEffects(sampling) that a model can hold at once: brighter_fatter and
// boundary_shift describe one effect, so the empirical law gives way where the physics is in.
std::vector<EffectValue> AllTogether(model::Sampling sampling) {
  std::vector<EffectValue> effects = StrongEffects(sampling);
  if (sampling == model::Sampling::kIntegrated) {
    effects.erase(std::remove_if(effects.begin(), effects.end(),
                                 [](const EffectValue& e) {
                                   return e.kind == EffectKind::kBrighterFatter;
                                 }),
                  effects.end());
  }
  return effects;
}

FitModelOptions WithEffects(const std::vector<EffectValue>& effects, model::Sampling sampling) {
  FitModelOptions options = WithEffects(effects);
  options.model.sampling = sampling;
  return options;
}

// The fit's expected image is the simulator's (simulate.h ExpectedElectrons, which draws the
// brighter-fatter signal with model::BrighterFatterSignal and applies the image effects to the
// frame): each effect alone and all together, in both samplings. Integrated: the stamp is the
// whole 21 x 21 frame, so the image effects see the same pixels. pixel_centre: the simulator
// draws the 2015 stamp inside the frame and the halo takes its share of that stamp's charge
// (as the fit does); compared on the fit's stamp, which is that stamp. Both are sums of the
// same terms in different orders: agreement to 1e-12 of the peak.
TEST(FitEffects, ModelImageIsTheSimulatorsExpectation) {
  for (const model::Sampling sampling :
       {model::Sampling::kIntegrated, model::Sampling::kPixelCentre}) {
    std::vector<std::vector<EffectValue>> cases;
    for (const EffectValue& e : StrongEffects(sampling)) cases.push_back({e});
    cases.push_back(AllTogether(sampling));
    for (const auto& effects : cases) {
      SimulationConfig c = PaperConfig(sampling, 1, 3);
      std::string error;
      for (const EffectValue& e : effects) {
        ASSERT_TRUE(model::SetEffectParameters(e.kind, e.values, &c.effects, &error)) << error;
      }
      const Image expected = ExpectedElectrons(c, c.exposures[0]);
      auto m = MustCreate(SimulateStamps(c, 4), WithEffects(effects, sampling));
      ASSERT_TRUE(m);
      const Stamp& stamp = m->stamps()[0];
      const std::vector<double> theta = TruthTheta(*m, c, c.exposures[0].flux_e, effects);
      std::vector<double> image;
      ASSERT_TRUE(m->NewEvaluator()->ModelImage(theta.data(), 0, &image, nullptr));
      ASSERT_EQ(static_cast<int>(image.size()), stamp.nx() * stamp.ny());
      double peak = 0.0, worst = 0.0;
      for (int y = 0; y < stamp.ny(); ++y) {
        for (int x = 0; x < stamp.nx(); ++x) {
          const double want =
              expected(static_cast<int>(stamp.origin_x) + x, static_cast<int>(stamp.origin_y) + y);
          peak = std::max(peak, want);
          worst = std::max(worst, std::fabs(image[y * stamp.nx() + x] - want));
        }
      }
      EXPECT_LT(worst, 1e-12 * peak)
          << model::ToString(sampling) << ": " << model::ToString(effects[0].kind) << " ("
          << effects.size() << " effects)";
    }
  }
}

// Largest difference between a residual block's analytic Jacobian and central differences,
// each column relative to its own largest entry. Steps are 1e-6 of each parameter's value
// (the effects' parameters are ~1e-7-1e-2, so Ceres' GradientChecker, whose Ridders steps
// start at 1e-4 absolute, would step them out of their domains): the truncation error is
// ~1e-12 of a column and the rounding ~1e-16 / 1e-6 = 1e-10.
double WorstJacobianError(const ceres::CostFunction& cost,
                          std::vector<std::vector<double>> blocks) {
  const int nr = cost.num_residuals();
  const int nb = static_cast<int>(blocks.size());
  std::vector<const double*> params(nb);
  for (int b = 0; b < nb; ++b) params[b] = blocks[b].data();
  std::vector<double> r(nr), rp(nr), rm(nr);
  std::vector<std::vector<double>> jac(nb);
  std::vector<double*> jac_ptr(nb);
  for (int b = 0; b < nb; ++b) {
    jac[b].resize(static_cast<size_t>(nr) * blocks[b].size());
    jac_ptr[b] = jac[b].data();
  }
  EXPECT_TRUE(cost.Evaluate(params.data(), r.data(), jac_ptr.data()));
  double worst = 0.0;
  for (int b = 0; b < nb; ++b) {
    const int size = static_cast<int>(blocks[b].size());
    for (int i = 0; i < size; ++i) {
      const double x = blocks[b][i], h = 1e-6 * std::fabs(x);
      blocks[b][i] = x + h;
      EXPECT_TRUE(cost.Evaluate(params.data(), rp.data(), nullptr));
      blocks[b][i] = x - h;
      EXPECT_TRUE(cost.Evaluate(params.data(), rm.data(), nullptr));
      blocks[b][i] = x;
      double column = 0.0, error = 0.0;
      for (int q = 0; q < nr; ++q) {
        const double numeric = (rp[q] - rm[q]) / (2.0 * h);
        column = std::max(column, std::fabs(numeric));
        error = std::max(error, std::fabs(numeric - jac[b][static_cast<size_t>(q) * size + i]));
      }
      worst = std::max(worst, error / column);
    }
  }
  return worst;
}

// The Ceres residual block's analytic Jacobian, effects' block included, against central
// differences, for each effect alone on one exposure and for all of them on the second
// exposure of a joint fit with per-exposure fluxes (shared, position, ratio and effects
// blocks). 1e-6 leaves a factor 1e4 over the differences' own error (above).
TEST(FitEffects, ExposureCostJacobianIsTheDerivative) {
  for (const model::Sampling sampling :
       {model::Sampling::kIntegrated, model::Sampling::kPixelCentre}) {
    // The 2015 model's flux parameter is its peak meta-parameter m.
    const double flux = sampling == model::Sampling::kPixelCentre ? 1.5e5 : 4.0e5;
    for (const EffectValue& e : StrongEffects(sampling)) {
      const SimulationConfig c = PaperConfig(sampling, 1, 5);
      auto m = MustCreate(SimulateStamps(c, 6), WithEffects({e}, sampling));
      ASSERT_TRUE(m);
      std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*m, 0));
      ASSERT_EQ(cost->parameter_block_sizes().size(), 3u);  // shared, position, effects
      const double error =
          WorstJacobianError(*cost, {{flux, 0.5, 0.38, 0.3, 0.33},
                                     {c.exposures[0].x_px + 0.02, c.exposures[0].y_px - 0.03},
                                     e.values});
      EXPECT_LT(error, 1e-6) << model::ToString(sampling) << ": " << model::ToString(e.kind);
    }
    SimulationConfig c = PaperConfig(sampling, 2, 7);
    c.exposures[1].flux_e *= 0.4;
    FitModelOptions options = WithEffects(AllTogether(sampling), sampling);
    options.flux = FluxMode::kPerExposure;
    auto m = MustCreate(SimulateStamps(c, 8), options);
    ASSERT_TRUE(m);
    std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*m, 1));
    ASSERT_EQ(cost->parameter_block_sizes().size(), 4u);  // shared, position, ratio, effects
    std::vector<double> effect;
    for (const EffectValue& e : AllTogether(sampling)) {
      effect.insert(effect.end(), e.values.begin(), e.values.end());
    }
    const double error =
        WorstJacobianError(*cost, {{flux, 0.5, 0.38, 0.3, 0.33},
                                   {c.exposures[1].x_px + 0.02, c.exposures[1].y_px - 0.03},
                                   {0.42},
                                   effect});
    EXPECT_LT(error, 1e-6) << model::ToString(sampling);
  }
}

// docs/conventions.md, Noise model: with effects the joint log-likelihood is still the sum of
// the singles' (each single given the same shared and effect parameters).
TEST(FitEffects, JointLogLikelihoodIsTheSumOfSingles) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 3, 9);
  const std::vector<Stamp> stamps = SimulateStamps(c, 10);
  const FitModelOptions options = WithEffects(StrongEffects());
  auto joint = MustCreate(stamps, options);
  ASSERT_TRUE(joint);
  const std::vector<double> theta = TruthTheta(*joint, c, 4.1e5, StrongEffects());
  double sum = 0.0;
  for (int k = 0; k < 3; ++k) {
    auto single = MustCreate({stamps[k]}, options);
    std::vector<double> t(theta.begin(), theta.begin() + kNumShared);
    t.push_back(theta[FitModel::XIndex(k)]);
    t.push_back(theta[FitModel::YIndex(k)]);
    t.insert(t.end(), theta.begin() + joint->EffectsFirstIndex(), theta.end());
    ASSERT_EQ(static_cast<int>(t.size()), single->dim());
    sum += single->NewEvaluator()->LogLikelihood(t.data());
  }
  const double total = joint->NewEvaluator()->LogLikelihood(theta.data());
  // The same terms summed in another order: rounding (~1e-16 per term, 1323 terms).
  EXPECT_NEAR(total, sum, 1e-10 * std::fabs(sum));
}

// The background is a bias residual (model/effects.h): the pedestal P shifts the expectation
// but carries no shot noise, as the simulator adds it and diagnose scores it. The fit's
// log-likelihood is therefore sum log N(d; m, (m - P)+ + RN^2 + g^2/12), written out here
// from the stamp's noise figures; the Fisher information of P alone is sum 1/var (the
// variance does not move with P). Both are the same terms summed in another order (1e-10).
TEST(FitEffects, TheBackgroundCarriesNoShotNoise) {
  const double pedestal = 35.0;
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 13);
  std::string error;
  ASSERT_TRUE(model::SetEffectParameters(EffectKind::kBackground, {pedestal}, &c.effects, &error))
      << error;
  const std::vector<EffectValue> effects = {{EffectKind::kBackground, {pedestal}}};
  auto m = MustCreate(SimulateStamps(c, 14), WithEffects(effects));
  ASSERT_TRUE(m);
  const std::vector<double> theta = TruthTheta(*m, c, c.exposures[0].flux_e, effects);
  std::vector<double> image;
  auto ev = m->NewEvaluator();
  ASSERT_TRUE(ev->ModelImage(theta.data(), 0, &image, nullptr));
  const Stamp& s = m->stamps()[0];
  double expected = 0.0, pedestal_information = 0.0;
  int pixels = 0;
  for (size_t q = 0; q < image.size(); ++q) {
    if (!s.valid[q]) continue;
    ASSERT_EQ(s.CensorAt(q), Censor::kNone);
    const double var = std::max(image[q] - pedestal, 0.0) + s.read_noise_e * s.read_noise_e +
                       s.gain_e_per_adu * s.gain_e_per_adu / 12.0;
    const double r = s.electrons.data[q] - image[q];
    expected += -0.5 * r * r / var - 0.5 * std::log(2.0 * M_PI * var);
    pedestal_information += 1.0 / var;
    ++pixels;
  }
  ASSERT_GT(pixels, 400);
  const double ll = ev->LogLikelihood(theta.data());
  EXPECT_NEAR(ll, expected, 1e-10 * std::fabs(expected));
  const int p = m->EffectIndex(EffectKind::kBackground);
  const std::vector<double> fisher = ev->FisherInformation(theta.data());
  EXPECT_NEAR(fisher[static_cast<size_t>(p) * m->dim() + p], pedestal_information,
              1e-10 * pedestal_information);
  // A likelihood that gave the pedestal shot noise (variance from m, not m - P) differs by
  // far more than the tolerance: the test can tell the two apart.
  double with_shot_noise = 0.0;
  for (size_t q = 0; q < image.size(); ++q) {
    if (!s.valid[q]) continue;
    const double var = std::max(image[q], 0.0) + s.read_noise_e * s.read_noise_e +
                       s.gain_e_per_adu * s.gain_e_per_adu / 12.0;
    const double r = s.electrons.data[q] - image[q];
    with_shot_noise += -0.5 * r * r / var - 0.5 * std::log(2.0 * M_PI * var);
  }
  EXPECT_GT(std::fabs(with_shot_noise - expected), 1e4 * 1e-10 * std::fabs(expected));
}

// Jitter, fitted per exposure (fit_model.h): three exposures with their own Gaussian jitter.
// The simulator draws exposure k with CCD widths hypot(sigma, s_k); the fit with the
// reference's widths hypot(sigma, s_ref) and the excess variances v_k = s_k^2 - s_ref^2.
SimulationConfig JitterConfig(const std::vector<double>& sigmas, uint64_t seed) {
  SimulationConfig c =
      PaperConfig(model::Sampling::kIntegrated, static_cast<int>(sigmas.size()), seed);
  for (size_t k = 0; k < sigmas.size(); ++k) {
    c.exposures[k].jitter = model::JitterParams{sigmas[k], sigmas[k], 0.0, 0.0};
  }
  return c;
}
std::vector<double> JitterTheta(const FitModel& m, const SimulationConfig& c,
                                const std::vector<double>& sigmas) {
  std::vector<double> theta = TruthTheta(m, c, c.exposures[0].flux_e, {});
  const double ref = sigmas[m.JitterReference()];
  theta[kCcdSigmaXPx] = std::hypot(c.ccd_sigma_x_px, ref);
  theta[kCcdSigmaYPx] = std::hypot(c.ccd_sigma_y_px, ref);
  for (int k = 0; k < m.num_exposures(); ++k) {
    if (m.JitterIndex(k) < 0) continue;
    theta[m.JitterIndex(k)] = theta[m.JitterIndex(k) + 1] = sigmas[k] * sigmas[k] - ref * ref;
  }
  return theta;
}

// The fit's image of every exposure is the simulator's expectation (simulate.h), whichever
// exposure is the reference, with serial CTI beside it, and with the brighter-fatter growth
// (exact when the reference has no jitter of its own: fit_model.h): the same terms in other
// orders, and widths through two square roots instead of one (1e-12 of the peak).
TEST(FitEffects, JitterImagesAreTheSimulatorsExpectation) {
  // The reference is the least jittered exposure (the others' excess variances are >= 0).
  struct Case {
    int reference;
    std::vector<double> sigmas;
    bool brighter_fatter;
  };
  const Case cases[] = {
      {0, {0.1, 0.22, 0.15}, false}, {2, {0.22, 0.15, 0.1}, false}, {1, {0.15, 0.0, 0.22}, true}};
  for (const auto& [reference, sigmas, brighter_fatter] : cases) {
    SimulationConfig c = JitterConfig(sigmas, 13);
    std::string error;
    ASSERT_TRUE(model::SetEffectParameters(EffectKind::kSerialCti, {4e-3, 1.7}, &c.effects, &error))
        << error;
    FitModelOptions options = WithEffects({{EffectKind::kSerialCti, {}}});
    if (brighter_fatter) {
      ASSERT_TRUE(
          model::SetEffectParameters(EffectKind::kBrighterFatter, {6e-7, 3e-7}, &c.effects, &error))
          << error;
      options.effects.push_back({EffectKind::kBrighterFatter, {}});
    }
    options.effects.push_back({EffectKind::kJitter, {}});
    options.jitter_reference = reference;
    auto m = MustCreate(SimulateStamps(c, 14), options);
    ASSERT_TRUE(m);
    ASSERT_EQ(m->JitterReference(), reference);
    EXPECT_EQ(m->EffectSize(EffectKind::kJitter), 4);
    std::vector<double> theta = JitterTheta(*m, c, sigmas);
    theta[m->EffectIndex(EffectKind::kSerialCti)] = 4e-3;
    theta[m->EffectIndex(EffectKind::kSerialCti) + 1] = 1.7;
    if (brighter_fatter) {
      theta[m->EffectIndex(EffectKind::kBrighterFatter)] = 6e-7;
      theta[m->EffectIndex(EffectKind::kBrighterFatter) + 1] = 3e-7;
    }
    auto ev = m->NewEvaluator();
    for (int k = 0; k < 3; ++k) {
      const Image expected = ExpectedElectrons(c, c.exposures[k]);
      std::vector<double> image;
      ASSERT_TRUE(ev->ModelImage(theta.data(), k, &image, nullptr));
      double peak = 0.0, worst = 0.0;
      for (size_t q = 0; q < image.size(); ++q) {
        peak = std::max(peak, expected.data[q]);
        worst = std::max(worst, std::fabs(image[q] - expected.data[q]));
      }
      EXPECT_LT(worst, 1e-12 * peak) << "exposure " << k << ", reference " << reference;
    }
  }
}

// The residual block of a jittered exposure, its jitter variances in the effects' block beside
// serial CTI and the brighter-fatter growth (whose signal is drawn with the jitter), against
// central differences (as ExposureCostJacobianIsTheDerivative).
TEST(FitEffects, JitterCostJacobianIsTheDerivative) {
  const std::vector<double> sigmas = {0.1, 0.22, 0.15};
  const SimulationConfig c = JitterConfig(sigmas, 15);
  FitModelOptions options =
      WithEffects({{EffectKind::kSerialCti, {}}, {EffectKind::kBrighterFatter, {}}});
  options.effects.push_back({EffectKind::kJitter, {}});
  options.jitter_reference = 0;
  auto m = MustCreate(SimulateStamps(c, 16), options);
  ASSERT_TRUE(m);
  std::vector<double> theta = JitterTheta(*m, c, sigmas);
  theta[m->EffectIndex(EffectKind::kSerialCti)] = 4e-3;
  theta[m->EffectIndex(EffectKind::kSerialCti) + 1] = 1.7;
  theta[m->EffectIndex(EffectKind::kBrighterFatter)] = 6e-7;
  theta[m->EffectIndex(EffectKind::kBrighterFatter) + 1] = 3e-7;
  for (int k : {1, 2}) {
    std::unique_ptr<ceres::CostFunction> cost(NewExposureCost(*m, k));
    ASSERT_EQ(cost->parameter_block_sizes().size(), 3u);  // shared, position, effects
    const std::vector<double> effects(theta.begin() + m->EffectsFirstIndex(), theta.end());
    const double error =
        WorstJacobianError(*cost, {{4.0e5, 0.5, 0.38, 0.3, 0.33},
                                   {c.exposures[k].x_px + 0.02, c.exposures[k].y_px - 0.03},
                                   effects});
    EXPECT_LT(error, 1e-6) << "exposure " << k;
  }
}

// Recovery with known truth: five exposures jittered by 0, 0.1, ... 0.25 px; the sharpest is
// the reference, and every other exposure's excess variances come back within 4 Laplace sd
// (measured pulls: see the assertion's message).
TEST(FitEffects, JitterVariancesAreRecoveredPerExposure) {
  const std::vector<double> sigmas = {0.0, 0.1, 0.15, 0.2, 0.25};
  const SimulationConfig c = JitterConfig(sigmas, 17);
  FitModelOptions options;
  options.effects = {{EffectKind::kJitter, {}}};
  auto m = MustCreate(SimulateStamps(c, 18), options);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->JitterReference(), 0);
  FitResult r;
  std::string error;
  ASSERT_TRUE(RunFit(*m, testing_support::NoMcmc(), &r, &error)) << error;
  for (int k = 1; k < 5; ++k) {
    for (int axis = 0; axis < 2; ++axis) {
      const int i = m->JitterIndex(k) + axis;
      const double truth = sigmas[k] * sigmas[k], sd = r.laplace.sd[i];
      ASSERT_TRUE(std::isfinite(sd) && sd > 0) << r.names[i];
      EXPECT_LT(std::fabs(r.map.theta[i] - truth), 4.0 * sd)
          << r.names[i] << ": " << r.map.theta[i] << " against " << truth << ", pull "
          << (r.map.theta[i] - truth) / sd;
    }
  }
}

// Recovery with known truth: an intensity series of eight exposures (peaks ~2e4 to ~2.7e5 e-,
// fluxes fitted per exposure) drawn with boundary_shift at three times the catalogue's
// coefficients and column boundaries softer than the rows (anisotropy -0.12, the reference
// sensor's), fitted with it. Every parameter comes back within 4 Laplace sds of the truth;
// the nearest lags, which carry most of the redistribution, are measured to 30 %; and chi^2 /
// dof is that of pure noise (the model describes the data), where the paper's model without
// the effect is off.
TEST(FitEffects, BoundaryShiftCoefficientsAreRecoveredFromAnIntensitySeries) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 8, 21);
  const model::BoundaryShiftParams d;
  const std::vector<double> truth = {3 * d.a_10, 3 * d.a_01, 3 * d.a_11, 3 * d.a_far, -0.12};
  std::string error;
  ASSERT_TRUE(model::SetEffectParameters(EffectKind::kBoundaryShift, truth, &c.effects, &error))
      << error;
  for (int k = 0; k < 8; ++k) c.exposures[k].flux_e *= std::pow(2.0, 1 - 0.5 * k);
  const std::vector<Stamp> stamps = SimulateStamps(c, 22);
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  options.effects = {{EffectKind::kBoundaryShift, {}}};
  auto m = MustCreate(stamps, options);
  ASSERT_TRUE(m);
  FitResult r;
  ASSERT_TRUE(RunFit(*m, testing_support::NoMcmc(), &r, &error)) << error;
  const int first = m->EffectIndex(EffectKind::kBoundaryShift);
  for (int p = 0; p < model::kNumBoundaryShiftParams; ++p) {
    const int i = first + p;
    const double sd = r.laplace.sd[i];
    ASSERT_TRUE(std::isfinite(sd) && sd > 0) << r.names[i];
    EXPECT_LT(std::fabs(r.map.theta[i] - truth[p]), 4.0 * sd)
        << r.names[i] << ": " << r.map.theta[i] << " against " << truth[p] << ", pull "
        << (r.map.theta[i] - truth[p]) / sd;
    if (p < 2) {
      EXPECT_LT(sd, 0.3 * truth[p]) << r.names[i] << " is measured";
    }
  }
  const double dof = r.map.dof;
  EXPECT_LT(std::fabs(r.map.chi2 / dof - 1.0), 4.0 * std::sqrt(2.0 / dof));
  FitModelOptions paper;
  paper.flux = FluxMode::kPerExposure;
  auto without = MustCreate(stamps, paper);
  FitResult rp;
  ASSERT_TRUE(RunFit(*without, testing_support::NoMcmc(), &rp, &error)) << error;
  EXPECT_GT(rp.map.chi2 / rp.map.dof - 1.0, 6.0 * std::sqrt(2.0 / rp.map.dof))
      << "the data hold the effect";
}

TEST(FitEffects, BadEffectsAreReported) {
  const SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, 1, 11);
  const std::vector<Stamp> stamps = SimulateStamps(c, 12);
  std::string error;
  FitModelOptions options;
  options.effects = {{EffectKind::kJitter, {}}};  // one exposure
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("jitter needs two or more exposures"), std::string::npos) << error;
  const std::vector<Stamp> pair =
      SimulateStamps(PaperConfig(model::Sampling::kIntegrated, 2, 11), 12);
  options.jitter_reference = 2;
  EXPECT_EQ(FitModel::Create(pair, options, &error), nullptr);
  EXPECT_NE(error.find("out of range"), std::string::npos) << error;
  options.jitter_reference = -1;
  options.effects = {{EffectKind::kIpc, {}}, {EffectKind::kIpc, {}}};
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("twice"), std::string::npos) << error;
  options.effects = {{EffectKind::kIpc, {{0.0, 0.3}}}};  // alpha's domain ends at 0.25
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("ipc.alpha"), std::string::npos) << error;
  options.effects = {{EffectKind::kHalo, {{0.0, 0.1}}}};  // two parameters, one range
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("priors"), std::string::npos) << error;
  // defocus_offset is a component of the 2015 model only: in integrated sampling it is
  // exactly a shift of the position.
  options.effects = {{EffectKind::kDefocusOffset, {}}};
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("exactly a shift"), std::string::npos) << error;
  options.model.sampling = model::Sampling::kPixelCentre;
  EXPECT_NE(FitModel::Create(stamps, options, &error), nullptr) << error;
}

}  // namespace
}  // namespace ccdpsf::fit

namespace ccdpsf::fit {
namespace {

// FIT.json "effects" and --effects: parsed, written back whole, and refused with a reason.
TEST(FitEffects, ConfigParsesWritesAndRefuses) {
  FitConfig c;
  std::string error;
  ASSERT_TRUE(ParseFitConfig(R"({"effects": {"serial_cti": {"trail_fraction": [0, 0.02]},
                                             "brighter_fatter": {}}})",
                             &c, &error))
      << error;
  ASSERT_EQ(c.model.effects.size(), 2u);
  const nlohmann::json written = FitConfigJson(c)["effects"];
  EXPECT_EQ(written["serial_cti"]["trail_fraction"], nlohmann::json({0.0, 0.02}));
  EXPECT_EQ(written["serial_cti"]["trail_length_px"], nlohmann::json({0.2, 10.0}));  // catalogue
  FitConfig again;
  ASSERT_TRUE(ParseFitConfig(FitConfigJson(c).dump(), &again, &error)) << error;
  EXPECT_EQ(FitConfigJson(again)["effects"], written);
  const std::pair<const char*, const char*> bad[] = {
      {R"({"effects": {"glow": {}}})", "unknown effect 'effects.glow'"},
      {R"({"effects": {"defocus": {}}})", "'effects.defocus' cannot be fitted"},
      {R"({"effects": {"ipc": {"beta": [0, 1]}}})", "effects.ipc.beta"},
      {R"({"effects": {"ipc": {"alpha": [0, 0.5]}}})", "effects.ipc.alpha"},
      {R"({"effects": {"ipc": {"alpha": [0.1, 0.05]}}})", "lower < upper"},
      {R"({"effects": ["ipc"]})", "must be an object"}};
  for (const auto& [text, expected] : bad) {
    FitConfig d;
    EXPECT_FALSE(ParseFitConfig(text, &d, &error)) << text;
    EXPECT_NE(error.find(expected), std::string::npos) << text << ": " << error;
  }
  std::vector<FitEffect> list;
  ASSERT_TRUE(ParseFitEffectList("serial_cti,halo", &list, &error)) << error;
  EXPECT_EQ(list.size(), 2u);
  EXPECT_TRUE(ParseFitEffectList("", &list, &error));
  EXPECT_TRUE(list.empty());
  EXPECT_FALSE(ParseFitEffectList("ipc,ipc", &list, &error));
  EXPECT_NE(error.find("twice"), std::string::npos) << error;
  EXPECT_FALSE(ParseFitEffectList("defocus", &list, &error));
  EXPECT_NE(error.find("cannot be fitted"), std::string::npos) << error;
}

}  // namespace
}  // namespace ccdpsf::fit
