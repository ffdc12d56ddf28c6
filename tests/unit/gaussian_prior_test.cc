// The Gaussian prior of fit/gaussian_prior.h in every use of the posterior (the MAP's residual
// block, the Laplace precision, the MCMC's log density) against a closed-form normal density;
// fits with a very tight and a very loose prior; the spots-alone estimate of
// data_alone_estimate.h against a fit without the prior; ptc.json as the prior (ptc_prior.h).
#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fit/data_alone_estimate.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/gaussian_prior.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/fit/posterior_target.h"
#include "ccdpsf/ptc_prior.h"
#include "nlohmann/json.hpp"
#include "ceres/ceres.h"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"
#include "support/slow_test.h"

namespace ccdpsf::fit {
namespace {

using model::EffectKind;
using testing_support::MustCreate;
using testing_support::PaperConfig;
using testing_support::SimulateStamps;

const std::vector<std::string> kNames = {"boundary_shift.a_10", "boundary_shift.a_01",
                                         "boundary_shift.a_11"};

// A prior on the three nearest coefficients with the given means and sds and correlations
// 0.3 (a_10, a_01), -0.2 (a_10, a_11), 0.1 (a_01, a_11).
GaussianPrior Prior(const std::vector<double>& mean, const std::vector<double>& sd) {
  const double rho[3][3] = {{1.0, 0.3, -0.2}, {0.3, 1.0, 0.1}, {-0.2, 0.1, 1.0}};
  GaussianPrior p;
  p.names = kNames;
  p.mean = mean;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) p.covariance.push_back(rho[i][j] * sd[i] * sd[j]);
  }
  p.source = "test";
  return p;
}

// The closed-form normal of a 3 x 3 covariance: its inverse by cofactors over the determinant
// (Sarrus' rule), independent of the Cholesky factor the prior uses.
struct ClosedForm {
  double inverse[3][3];
  double det;
  explicit ClosedForm(const std::vector<double>& c) {
    auto at = [&](int i, int j) { return c[i * 3 + j]; };
    det = at(0, 0) * (at(1, 1) * at(2, 2) - at(1, 2) * at(2, 1)) -
          at(0, 1) * (at(1, 0) * at(2, 2) - at(1, 2) * at(2, 0)) +
          at(0, 2) * (at(1, 0) * at(2, 1) - at(1, 1) * at(2, 0));
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        // cofactor C_ji / det (the adjugate is the cofactors' transpose)
        const int r0 = (j + 1) % 3, r1 = (j + 2) % 3, c0 = (i + 1) % 3, c1 = (i + 2) % 3;
        inverse[i][j] = (at(r0, c0) * at(r1, c1) - at(r0, c1) * at(r1, c0)) / det;
      }
    }
  }
  // d^T C^-1 d
  double Quadratic(const double d[3]) const {
    double q = 0.0;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) q += d[i] * inverse[i][j] * d[j];
    }
    return q;
  }
  double LogDensity(const double d[3]) const {
    return -0.5 * Quadratic(d) - 1.5 * std::log(2.0 * M_PI) - 0.5 * std::log(det);
  }
};

std::vector<double> Truth() {
  const model::BoundaryShiftParams d;
  return {3 * d.a_10, 3 * d.a_01, 3 * d.a_11, 3 * d.a_far, d.anisotropy};
}

// `count` exposures of the paper's spot drawn with boundary_shift at three times the
// catalogue's coefficients, fluxes halving from 8e5 e- every second exposure.
std::vector<Stamp> BoundaryShiftSeries(int count, uint64_t seed) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, count, seed);
  std::string error;
  EXPECT_TRUE(model::SetEffectParameters(EffectKind::kBoundaryShift, Truth(), &c.effects, &error))
      << error;
  for (int k = 0; k < count; ++k) c.exposures[k].flux_e *= std::pow(2.0, 1 - 0.5 * k);
  return SimulateStamps(c, seed + 1);
}

FitModelOptions BoundaryShiftOptions(const GaussianPrior& prior) {
  FitModelOptions options;
  options.flux = FluxMode::kPerExposure;
  options.effects = {{EffectKind::kBoundaryShift, {}}};
  options.gaussian_prior = prior;
  return options;
}

// (a) At random points inside the flat box: the residual block's 1/2 |r|^2 and gradient
// J^T r, the Laplace precision and the MCMC log density (with the prior less without it)
// against the closed-form normal, to 1e-9 relative (rounding in sums of a few terms) and, for
// the log densities, 1e-7 absolute (the difference of two log posteriors of ~1e3).
TEST(GaussianPrior, EveryUseAgreesWithTheClosedFormDensity) {
  const GaussianPrior prior = Prior({4.0e-7, 5.5e-7, 1.6e-7}, {3e-8, 5e-8, 2e-8});
  const ClosedForm closed(prior.covariance);
  const std::vector<Stamp> stamps = BoundaryShiftSeries(2, 31);
  auto with = MustCreate(stamps, BoundaryShiftOptions(prior));
  auto without = MustCreate(stamps, BoundaryShiftOptions(GaussianPrior()));
  ASSERT_TRUE(with && without);
  ASSERT_TRUE(with->gaussian_prior().active());
  ASSERT_FALSE(without->gaussian_prior().active());
  const int first = with->EffectIndex(EffectKind::kBoundaryShift);
  std::vector<double> base = with->MomentStart(0.47, 0.5);
  base[kFluxE] = 8.0e5;
  for (int k = 1; k < with->num_exposures(); ++k) base[with->RatioIndex(k)] = 0.7;
  std::mt19937_64 engine(5);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<ExposureCostLayout> layouts;
  for (int k = 0; k < with->num_exposures(); ++k) {
    layouts.push_back(FitExposureCostLayout(*with, k));
  }
  const ExposureCostLayout layout = GaussianPriorLayout(*with, layouts);
  std::unique_ptr<ceres::CostFunction> cost(NewGaussianPriorCost(*with, layout));
  ASSERT_EQ(cost->num_residuals(), 3);
  std::unique_ptr<FitEvaluator> ev_with = with->NewEvaluator(), ev_without = without->NewEvaluator();
  for (int trial = 0; trial < 4; ++trial) {
    std::vector<double> theta = base;
    for (int p = 0; p < 4; ++p) {
      const int i = first + p;
      theta[i] = with->lower()[i] + unit(engine) * (with->upper()[i] - with->lower()[i]);
    }
    double d[3];
    for (int a = 0; a < 3; ++a) d[a] = theta[first + a] - prior.mean[a];
    const double want_log = closed.LogDensity(d);
    EXPECT_NEAR(with->LogPrior(theta.data()), want_log, 1e-9 * std::fabs(want_log));

    // The residual block, its parameter blocks read from theta.
    std::vector<const double*> blocks;
    std::vector<std::vector<double>> jac_store;
    std::vector<double*> jacobians;
    for (const auto& b : layout.blocks) {
      blocks.push_back(theta.data() + b.first);
      jac_store.emplace_back(3 * b.size);
    }
    for (auto& j : jac_store) jacobians.push_back(j.data());
    double r[3];
    ASSERT_TRUE(cost->Evaluate(blocks.data(), r, jacobians.data()));
    const double half_r2 = 0.5 * (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    EXPECT_NEAR(half_r2, 0.5 * closed.Quadratic(d), 1e-9 * std::max(1.0, half_r2));
    // J^T r = C^-1 (theta - mean), the gradient of 1/2 |r|^2.
    for (int a = 0; a < 3; ++a) {
      const auto& place = layout.place.at(first + a);
      const int size = layout.blocks[place.block].size;
      double jtr = 0.0;
      for (int q = 0; q < 3; ++q) jtr += jac_store[place.block][q * size + place.offset] * r[q];
      double want = 0.0;
      for (int b = 0; b < 3; ++b) want += closed.inverse[a][b] * d[b];
      EXPECT_NEAR(jtr, want, 1e-9 * std::fabs(want) + 1e-6) << kNames[a];
    }

    // The Laplace approximation's information: the prior precision added on the a block only.
    const int n = with->dim();
    const std::vector<double> information =
        with->PosteriorInformation(std::vector<double>(static_cast<size_t>(n) * n, 0.0));
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        const int a = i - first, b = j - first;
        const double want = a >= 0 && a < 3 && b >= 0 && b < 3 ? closed.inverse[a][b] : 0.0;
        EXPECT_NEAR(information[i * n + j], want, 1e-9 * std::fabs(closed.inverse[0][0]))
            << with->names()[i] << ", " << with->names()[j];
      }
    }

    // The MCMC's log density: the same state in two targets, with and without the prior.
    const std::vector<double> fisher = ev_with->FisherInformation(theta.data());
    const PosteriorTarget t_with(*with, theta, with->PosteriorInformation(fisher), {});
    const PosteriorTarget t_without(*without, theta, fisher, {});
    ASSERT_EQ(t_with.state_map(), t_without.state_map());
    const double l_with = t_with.LogDensity(ev_with.get(), t_with.state_map().data(), nullptr);
    const double l_without =
        t_without.LogDensity(ev_without.get(), t_without.state_map().data(), nullptr);
    ASSERT_TRUE(std::isfinite(l_with) && std::isfinite(l_without));
    EXPECT_NEAR(l_with - l_without, want_log, 1e-7);
  }
}

// The prior binds to the parameters it names, is left out by a model that fits none of them,
// and refuses what is not a Gaussian.
TEST(GaussianPrior, BindsOnlyToAModelThatFitsItsParameters) {
  const GaussianPrior prior = Prior({4.0e-7, 5.5e-7, 1.6e-7}, {3e-8, 5e-8, 2e-8});
  const std::vector<Stamp> stamps = BoundaryShiftSeries(1, 41);
  FitModelOptions plain;
  plain.gaussian_prior = prior;
  auto m = MustCreate(stamps, plain);
  ASSERT_TRUE(m);
  EXPECT_FALSE(m->gaussian_prior().active());
  EXPECT_EQ(m->LogPrior(std::vector<double>(m->dim(), 0.0).data()), 0.0);
  std::string error;
  GaussianPrior partial = prior;
  partial.names[2] = "serial_cti.trail_fraction";
  FitModelOptions options = BoundaryShiftOptions(partial);
  options.flux = FluxMode::kShared;
  EXPECT_EQ(FitModel::Create(stamps, options, &error), nullptr);
  EXPECT_NE(error.find("serial_cti.trail_fraction"), std::string::npos) << error;
  GaussianPrior singular = prior;
  singular.covariance[1] = singular.covariance[3] = 1.2 * 3e-8 * 5e-8;  // correlation 1.2
  EXPECT_FALSE(CheckGaussianPrior(singular, &error));
  EXPECT_NE(error.find("not positive definite"), std::string::npos) << error;
  GaussianPrior zero = prior;
  zero.covariance[0] = 0.0;
  EXPECT_FALSE(CheckGaussianPrior(zero, &error));
  EXPECT_NE(error.find("variance of boundary_shift.a_10"), std::string::npos) << error;
}

// The coefficients' index in theta and a fit (MAP and Laplace, no MCMC) of `stamps`.
FitResult FitSeries(const std::vector<Stamp>& stamps, const GaussianPrior& prior,
                    std::unique_ptr<FitModel>* model) {
  *model = MustCreate(stamps, BoundaryShiftOptions(prior));
  FitResult r;
  std::string error;
  EXPECT_TRUE(*model && RunFit(**model, testing_support::NoMcmc(), &r, &error)) << error;
  return r;
}

// (b) A prior 1e-4 of the spots' sd wide holds the MAP at its mean: the pull of the data moves
// it by (sd_prior / sd_spot)^2 of the data's distance from the mean, < 1e-6 prior sds here,
// so within 0.01 prior sd (the solver's tolerance); the Laplace sd is the prior's within 1 %.
// A prior 1e4 times the flat range wide adds 1e-8 of the spots' information: the fit is the
// flat-prior fit's, its coefficients within 1e-3 of their sd and their sds within 1e-4.
TEST(GaussianPrior, ATightPriorPinsTheCoefficientsAndALooseOneChangesNothing) {
  // Covered in the sanitized build by EveryUseAgreesWithTheClosedFormDensity (the same code
  // paths in the solve's residual block and the Laplace information).
  CCDPSF_RELEASE_ONLY();
  const std::vector<Stamp> stamps = BoundaryShiftSeries(4, 51);
  std::unique_ptr<FitModel> flat_model, tight_model, loose_model;
  const FitResult flat = FitSeries(stamps, GaussianPrior(), &flat_model);
  ASSERT_TRUE(flat_model);
  const int first = flat_model->EffectIndex(EffectKind::kBoundaryShift);
  std::vector<double> spot_sd(3), tight_sd(3);
  for (int a = 0; a < 3; ++a) {
    spot_sd[a] = flat.laplace.sd[first + a];
    ASSERT_TRUE(std::isfinite(spot_sd[a]) && spot_sd[a] > 0) << kNames[a];
    tight_sd[a] = 1e-4 * spot_sd[a];
  }
  const std::vector<double> mean = {0.8 * Truth()[0], 1.2 * Truth()[1], 0.9 * Truth()[2]};
  const FitResult tight = FitSeries(stamps, Prior(mean, tight_sd), &tight_model);
  ASSERT_TRUE(tight_model);
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(tight.map.theta[first + a], mean[a], 0.01 * tight_sd[a]) << kNames[a];
    const double sd = tight.laplace.sd[first + a];
    EXPECT_NEAR(sd / tight_sd[a], 1.0, 0.01) << kNames[a];
  }
  // The MAP's log prior, reported beside its log-likelihood, is the closed form's there.
  double d[3];
  for (int a = 0; a < 3; ++a) d[a] = tight.map.theta[first + a] - mean[a];
  const double want_log = ClosedForm(Prior(mean, tight_sd).covariance).LogDensity(d);
  EXPECT_NEAR(tight.map.log_prior, want_log, 1e-9 * std::fabs(want_log));
  const FitResult loose = FitSeries(stamps, Prior(mean, {1e-2, 1e-2, 1e-2}), &loose_model);
  ASSERT_TRUE(loose_model);
  for (int a = 0; a < 4; ++a) {
    const int i = first + a;
    const double sd = flat.laplace.sd[i];
    EXPECT_NEAR(loose.map.theta[i], flat.map.theta[i], 1e-3 * sd) << flat.names[i];
    EXPECT_NEAR(loose.laplace.sd[i] / sd, 1.0, 1e-4) << flat.names[i];
  }
  EXPECT_NEAR(loose.map.log_likelihood, flat.map.log_likelihood, 1e-3);
}

// (c) The spots-alone estimate from a fit with the prior against a fit without it. The prior
// is as wide as the spots' own sd and its mean 1.5 of those sds off (signs +, -, +), so the
// prior moves the MAP by up to ~1 sd (measured: 0.07, -0.53, 0.94 sd): the formula has to
// undo that. In the Laplace approximation the two agree exactly; what is left is the
// likelihood's curvature changing between the two MAPs (the model is nonlinear in a_ij at
// second order, Q = M + S M / 2 + S^2 M / 6; the shifts are bilinear in the a_ij and the
// anisotropy, which moves with them; and the other parameters move too). An error of 0.25 of
// the spots' sd moves difference_sd by at most 0.25, well below its own scatter of 1: allowed
// 0.25 sd for the centres and 15 % for the sds (measured 0.026-0.038 sd and < 0.7 % before the
// anisotropy was a parameter; with it, up to 0.18 sd and 5.4 %; with the corner term, which
// is quadratic in the a_ij so that their own Fisher information changes with them, 8.3 % and
// 11.7 % on a_10 and a_01).
TEST(GaussianPrior, SpotsAloneEstimateIsTheFitWithoutThePrior) {
  // Covered in the sanitized build by EveryUseAgreesWithTheClosedFormDensity and
  // DataAloneEstimateOfALinearGaussianIsExact.
  CCDPSF_RELEASE_ONLY();
  const std::vector<Stamp> stamps = BoundaryShiftSeries(4, 51);
  std::unique_ptr<FitModel> flat_model, prior_model;
  const FitResult flat = FitSeries(stamps, GaussianPrior(), &flat_model);
  ASSERT_TRUE(flat_model);
  const int first = flat_model->EffectIndex(EffectKind::kBoundaryShift);
  std::vector<double> sd(3), mean(3);
  for (int a = 0; a < 3; ++a) {
    sd[a] = flat.laplace.sd[first + a];
    ASSERT_TRUE(std::isfinite(sd[a])) << kNames[a];
    mean[a] = flat.map.theta[first + a] + (a == 1 ? -1.5 : 1.5) * sd[a];
  }
  const FitResult with = FitSeries(stamps, Prior(mean, sd), &prior_model);
  ASSERT_TRUE(prior_model);
  const DataAloneEstimate& e = with.data_alone;
  ASSERT_TRUE(e.available) << e.why_not;
  double largest_move = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double moved = (with.map.theta[first + a] - flat.map.theta[first + a]) / sd[a];
    largest_move = std::max(largest_move, std::fabs(moved));
    EXPECT_NEAR(e.mean[a], flat.map.theta[first + a], 0.25 * sd[a]) << kNames[a];
    EXPECT_NEAR(e.sd[a] / sd[a], 1.0, 0.15) << kNames[a];
  }
  EXPECT_GT(largest_move, 0.3) << "the prior moved the MAP";

}

// The formula on a likelihood that is exactly Gaussian: F given, two nuisance parameters, one
// of them an exact null direction (as a Gaussian defocus at one focus), the posterior MAP
// computed by hand from (S + P) a_post = S a_true + P mean. The estimate is a_true and S^-1
// to rounding (1e-8 relative: two inversions of a 10 x 10 matrix of condition ~1e2-1e3 in
// the scaled coordinates).
TEST(GaussianPrior, DataAloneEstimateOfALinearGaussianIsExact) {
  const GaussianPrior prior = Prior({4.0e-7, 5.5e-7, 1.6e-7}, {3e-8, 5e-8, 2e-8});
  const std::vector<Stamp> stamps = BoundaryShiftSeries(1, 61);
  FitModelOptions options = BoundaryShiftOptions(prior);
  options.flux = FluxMode::kShared;
  auto m = MustCreate(stamps, options);
  ASSERT_TRUE(m);
  const int n = m->dim(), first = m->EffectIndex(EffectKind::kBoundaryShift);
  // A Fisher information of the form J^T J with random J (n + 3 rows) on every parameter but
  // the defocus, which it leaves out altogether (a null direction).
  std::mt19937_64 engine(7);
  std::normal_distribution<double> normal(0.0, 1.0);
  const int rows = 3 * n;
  std::vector<double> jac(static_cast<size_t>(rows) * n, 0.0);
  for (int r = 0; r < rows; ++r) {
    for (int i = 0; i < n; ++i) {
      if (i == kDefocusPx) continue;
      // In each parameter's units: a unit change of u = theta / width moves r by O(30).
      jac[r * n + i] = 30.0 * normal(engine) / (m->upper()[i] - m->lower()[i]);
    }
  }
  std::vector<double> fisher(static_cast<size_t>(n) * n, 0.0);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      for (int r = 0; r < rows; ++r) fisher[i * n + j] += jac[r * n + i] * jac[r * n + j];
    }
  }
  // S by brute force: the inverse of F restricted to the identified parameters (scaled by
  // their widths, as every parameter is O(1) there), whose a block is the marginal's
  // covariance, by Gauss-Jordan elimination.
  std::vector<int> kept;
  for (int i = 0; i < n; ++i) {
    if (i != kDefocusPx) kept.push_back(i);
  }
  const int nk = static_cast<int>(kept.size());
  auto width = [&](int i) { return m->upper()[i] - m->lower()[i]; };
  std::vector<double> a(static_cast<size_t>(nk) * 2 * nk, 0.0);
  for (int r = 0; r < nk; ++r) {
    for (int c = 0; c < nk; ++c) {
      a[r * 2 * nk + c] = width(kept[r]) * fisher[kept[r] * n + kept[c]] * width(kept[c]);
    }
    a[r * 2 * nk + nk + r] = 1.0;
  }
  for (int c = 0; c < nk; ++c) {
    int pivot = c;
    for (int r = c + 1; r < nk; ++r) {
      if (std::fabs(a[r * 2 * nk + c]) > std::fabs(a[pivot * 2 * nk + c])) pivot = r;
    }
    for (int k = 0; k < 2 * nk; ++k) std::swap(a[c * 2 * nk + k], a[pivot * 2 * nk + k]);
    const double d = a[c * 2 * nk + c];
    for (int k = 0; k < 2 * nk; ++k) a[c * 2 * nk + k] /= d;
    for (int r = 0; r < nk; ++r) {
      if (r == c) continue;
      const double f = a[r * 2 * nk + c];
      for (int k = 0; k < 2 * nk; ++k) a[r * 2 * nk + k] -= f * a[c * 2 * nk + k];
    }
  }
  // The marginal covariance of the a block (kept positions of first..first+2).
  std::vector<double> marginal(9);
  for (int p = 0; p < 3; ++p) {
    for (int q = 0; q < 3; ++q) {
      const int rp = static_cast<int>(std::find(kept.begin(), kept.end(), first + p) - kept.begin());
      const int rq = static_cast<int>(std::find(kept.begin(), kept.end(), first + q) - kept.begin());
      marginal[p * 3 + q] = width(first + p) * a[rp * 2 * nk + nk + rq] * width(first + q);
    }
  }
  const ClosedForm s_inverse_of(marginal);  // its inverse is S
  const ClosedForm prior_closed(prior.covariance);
  // a_post = (S + P)^-1 (S a_true + P mean), by hand.
  const double a_true[3] = {4.4e-7, 5.0e-7, 1.9e-7};
  double lhs[9], rhs[3];
  for (int p = 0; p < 3; ++p) {
    rhs[p] = 0.0;
    for (int q = 0; q < 3; ++q) {
      lhs[p * 3 + q] = s_inverse_of.inverse[p][q] + prior_closed.inverse[p][q];
      rhs[p] += s_inverse_of.inverse[p][q] * a_true[q] + prior_closed.inverse[p][q] * prior.mean[q];
    }
  }
  const ClosedForm posterior(std::vector<double>(lhs, lhs + 9));
  std::vector<double> theta(n, 0.0);
  for (int p = 0; p < 3; ++p) {
    for (int q = 0; q < 3; ++q) theta[first + p] += posterior.inverse[p][q] * rhs[q];
  }
  const DataAloneEstimate e = EstimateFromDataAlone(*m, theta, fisher);
  ASSERT_TRUE(e.available) << e.why_not;
  for (int p = 0; p < 3; ++p) {
    EXPECT_NEAR(e.mean[p], a_true[p], 1e-8 * a_true[p]) << kNames[p];
    for (int q = 0; q < 3; ++q) {
      EXPECT_NEAR(e.covariance[p * 3 + q], marginal[p * 3 + q],
                  1e-8 * std::sqrt(marginal[p * 3 + p] * marginal[q * 3 + q]))
          << kNames[p] << ", " << kNames[q];
    }
  }
  // Data that say nothing of a_11: not available, and a_11 named.
  for (int i = 0; i < n; ++i) {
    fisher[i * n + first + 2] = fisher[(first + 2) * n + i] = 0.0;
  }
  const DataAloneEstimate none = EstimateFromDataAlone(*m, theta, fisher);
  EXPECT_FALSE(none.available);
  EXPECT_NE(none.why_not.find("boundary_shift.a_11"), std::string::npos) << none.why_not;
}

// ptc.json as `ccdpsf ptc` writes it (lags "00", "10", "20", "01", ... of max_lag 2) becomes the
// prior on a_10, a_01, a_11 with the 3 x 3 block of its covariance, rows and columns picked by
// name.
TEST(GaussianPrior, PtcJsonBecomesThePriorOnTheNearestCoefficients) {
  // Lags in ptc's order j * 3 + i: 00 10 20 01 11 21 02 12 22; a diagonal covariance with
  // entry k = (k + 1)^2 1e-16, and a correlation between a_10 (row 1) and a_11 (row 4).
  std::vector<std::string> lags = {"00", "10", "20", "01", "11", "21", "02", "12", "22"};
  nlohmann::json a = nlohmann::json::object(), names = nlohmann::json::array(),
                 matrix = nlohmann::json::array();
  for (size_t k = 0; k < lags.size(); ++k) {
    const double sd = (k + 1) * 1e-8;
    a["a_" + lags[k]] = {{"median", (k + 1) * 1e-7}, {"sd", sd}, {"lo68", 0}, {"hi68", 0}};
    names.push_back("a_" + lags[k]);
    nlohmann::json row = nlohmann::json::array();
    for (size_t l = 0; l < lags.size(); ++l) {
      double v = k == l ? sd * sd : 0.0;
      if ((k == 1 && l == 4) || (k == 4 && l == 1)) v = 0.5 * 2e-8 * 5e-8;
      row.push_back(v);
    }
    matrix.push_back(row);
  }
  const nlohmann::json ptc = {{"a", a},
                              {"a_covariance", {{"names", names}, {"matrix", matrix}}}};
  GaussianPrior prior;
  std::string error;
  ASSERT_TRUE(ParsePtcPrior(ptc.dump(), "dir/ptc.json", &prior, &error)) << error;
  EXPECT_EQ(prior.names, kNames);
  EXPECT_EQ(prior.source, "dir/ptc.json");
  // a_10 is lag 1, a_01 lag 3, a_11 lag 4.
  const std::vector<double> want_mean = {2e-7, 4e-7, 5e-7};
  for (int i = 0; i < 3; ++i) EXPECT_DOUBLE_EQ(prior.mean[i], want_mean[i]) << i;
  const std::vector<double> want = {4e-16, 0.0, 0.5 * 2e-8 * 5e-8, 0.0,  16e-16,
                                    0.0,   0.5 * 2e-8 * 5e-8, 0.0, 25e-16};
  ASSERT_EQ(prior.covariance.size(), 9u);
  for (int i = 0; i < 9; ++i) EXPECT_DOUBLE_EQ(prior.covariance[i], want[i]) << i;
}

}  // namespace
}  // namespace ccdpsf::fit
