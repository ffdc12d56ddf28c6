// Trend relations against independent computations: the closed-form weighted least-squares
// solution and its (A^T W A)^-1 covariance (Eigen, written without the pivot), coverage over
// synthetic data sets with known truth, closed-form chi-square tails, and the combined model
// by hand.
//
// Monte-Carlo tolerances. With R resamplings of a (near-)Gaussian coefficient of sd sigma,
// the ensemble median has a standard error 1.2533 sigma / sqrt(R), a 68 % bound
// sqrt(0.1587 * 0.8413 / R) / phi(1) = 1.51 sigma / sqrt(R), and the half-width
// (hi68 - lo68) / 2, whose bounds are positively correlated order statistics
// (cov = 0.1587^2 / (R phi(1)^2)), 0.96 sigma / sqrt(R); the sample sd sigma / sqrt(2R). At R = 4000: 0.020 sigma, 0.015
// sigma and 0.011 sigma. The tests allow 4 standard errors: 0.08 sigma on medians, 6 % on
// half-widths, 4.5 % on sds. The draws of each point are made with exactly the stated mean
// and sd, so the closed form's inputs are exactly what the resampling sees.
#include "ccdpsf/trend/relations.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/chi_square.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/random.h"
#include "gtest/gtest.h"
#include "support/slow_test.h"

namespace ccdpsf::trend {
namespace {

// n Gaussian draws standardised to sample mean `mean` and sample sd (n - 1) `sd` exactly.
std::vector<double> ExactGaussian(double mean, double sd, int n, uint64_t seed) {
  std::mt19937_64 engine(seed);
  std::vector<double> z(n);
  double m = 0.0;
  for (double& v : z) {
    v = StandardNormal(engine);
    m += v;
  }
  m /= n;
  double ss = 0.0;
  for (double v : z) ss += (v - m) * (v - m);
  const double s = std::sqrt(ss / (n - 1));
  for (double& v : z) v = mean + sd * (v - m) / s;
  return z;
}

std::vector<double> Exp(std::vector<double> v) {
  for (double& x : v) x = std::exp(x);
  return v;
}

struct Wls {
  Eigen::Vector2d beta;
  Eigen::Matrix2d cov;
};

// Closed-form weighted least squares y = b0 + b1 x, weights 1 / sd^2.
Wls ClosedForm(const std::vector<double>& x, const std::vector<double>& y,
               const std::vector<double>& sd) {
  const int n = static_cast<int>(x.size());
  Eigen::MatrixXd a(n, 2);
  Eigen::VectorXd w(n), yy(n);
  for (int i = 0; i < n; ++i) {
    a(i, 0) = 1.0;
    a(i, 1) = x[i];
    w(i) = 1.0 / (sd[i] * sd[i]);
    yy(i) = y[i];
  }
  const Eigen::Matrix2d normal = a.transpose() * w.asDiagonal() * a;
  Wls out;
  out.cov = normal.inverse();
  out.beta = out.cov * (a.transpose() * w.asDiagonal() * yy);
  return out;
}

double HalfWidth(const Estimate& e) { return 0.5 * (e.hi68 - e.lo68); }

RelationFit MustFit(RelationKind kind, const std::vector<RelationPoint>& points,
                    const RelationOptions& options = RelationOptions()) {
  std::string error;
  std::optional<RelationFit> fit = FitRelation(kind, points, options, &error);
  EXPECT_TRUE(fit.has_value()) << error;
  return fit ? *fit : RelationFit();
}

RelationOptions WithResamples(int r, uint64_t seed = 3) {
  RelationOptions o;
  o.resamples = r;
  o.seed = seed;
  return o;
}

// Paper-like linear data at 800 nm: FWHM = 6.61 + 1.14e-5 I [um], six settings, different
// errors and numbers of draws, centres displaced from the truth by fixed multiples of sd.
struct LinearData {
  std::vector<double> x = {7.0e3, 2.0e4, 4.0e4, 8.0e4, 1.2e5, 1.6e5};
  std::vector<double> sd = {0.05, 0.03, 0.04, 0.02, 0.06, 0.03};
  std::vector<double> offset = {0.7, -1.1, 0.2, 0.9, -0.4, -0.6};
  std::vector<int> num_draws = {1000, 2000, 4000, 1500, 3000, 2500};
  std::vector<double> centre;
  std::vector<RelationPoint> points;
  LinearData() {
    for (size_t i = 0; i < x.size(); ++i) {
      centre.push_back(6.61 + 1.14e-5 * x[i] + offset[i] * sd[i]);
      points.push_back(RelationPoint::FromDraws(
          "I" + std::to_string(i), x[i], ExactGaussian(centre[i], sd[i], num_draws[i], 100 + i)));
    }
  }
};

// The percentiles of the draws 0, 1, ..., 1000 in shuffled order are q x 1000 exactly
// (linear interpolation between order statistics at position q (n - 1)); non-finite draws
// are ignored. Tolerance: rounding only.
TEST(Relations, SummaryPercentilesOfAKnownSample) {
  std::vector<double> draws;
  for (int i = 0; i <= 1000; ++i) draws.push_back(i);
  std::mt19937_64 engine(5);
  std::shuffle(draws.begin(), draws.end(), engine);
  draws.push_back(NAN);
  draws.push_back(INFINITY);
  const Estimate e = SummarizeDraws(draws);
  EXPECT_NEAR(e.lo95, 25.0, 1e-9);
  EXPECT_NEAR(e.lo68, 158.655, 1e-9);
  EXPECT_NEAR(e.median, 500.0, 1e-9);
  EXPECT_NEAR(e.hi68, 841.345, 1e-9);
  EXPECT_NEAR(e.hi95, 975.0, 1e-9);
}

TEST(Relations, LinearMatchesClosedFormWeightedLeastSquares) {
  const LinearData d;
  const RelationFit fit = MustFit(RelationKind::kLinear, d.points, WithResamples(4000));
  ASSERT_TRUE(fit.fitted);
  EXPECT_EQ(fit.dof, 4);
  EXPECT_TRUE(fit.gaps.empty());
  const Wls wls = ClosedForm(d.x, d.centre, d.sd);
  const Estimate intercept = fit.Find("intercept")->estimate;
  const Estimate slope = fit.Find("slope")->estimate;
  const double s0 = std::sqrt(wls.cov(0, 0)), s1 = std::sqrt(wls.cov(1, 1));
  EXPECT_NEAR(intercept.median, wls.beta(0), 0.08 * s0);
  EXPECT_NEAR(slope.median, wls.beta(1), 0.08 * s1);
  EXPECT_NEAR(HalfWidth(intercept), s0, 0.06 * s0);
  EXPECT_NEAR(HalfWidth(slope), s1, 0.06 * s1);
  EXPECT_NEAR(intercept.sd, s0, 0.045 * s0);
  EXPECT_NEAR(slope.sd, s1, 0.045 * s1);
  // The value at the pivot I0: b0 + b1 I0 with variance g^T C g, g = (1, I0).
  const Eigen::Vector2d g(1.0, kReferenceIntensityE);
  const double sp = std::sqrt(g.dot(wls.cov * g));
  const Estimate at_pivot = fit.Find("value_at_pivot")->estimate;
  EXPECT_NEAR(at_pivot.median, g.dot(wls.beta), 0.08 * sp);
  EXPECT_NEAR(HalfWidth(at_pivot), sp, 0.06 * sp);
  // The draws' correlation reproduces the off-diagonal of the covariance: the sample
  // correlation of R = 4000 pairs has standard error (1 - rho^2) / sqrt(R) < 0.016.
  const std::vector<double>& di = fit.Find("intercept")->draws;
  const std::vector<double>& ds = fit.Find("slope")->draws;
  ASSERT_EQ(di.size(), 4000u);
  double mi = 0, ms = 0;
  for (size_t r = 0; r < di.size(); ++r) {
    mi += di[r];
    ms += ds[r];
  }
  mi /= di.size();
  ms /= ds.size();
  double cis = 0, cii = 0, css = 0;
  for (size_t r = 0; r < di.size(); ++r) {
    cis += (di[r] - mi) * (ds[r] - ms);
    cii += (di[r] - mi) * (di[r] - mi);
    css += (ds[r] - ms) * (ds[r] - ms);
  }
  EXPECT_NEAR(cis / std::sqrt(cii * css), wls.cov(0, 1) / (s0 * s1), 0.064);
}

TEST(Relations, PowerLawMatchesClosedFormWeightedLeastSquaresInLogSpace) {
  // FWHM = 52.2 lambda^-0.272 (paper), posteriors Gaussian in log X with 1.5-3 % widths.
  const std::vector<double> lambda = {600, 650, 700, 750, 800, 850, 890};
  const std::vector<double> s = {0.03, 0.02, 0.025, 0.015, 0.02, 0.03, 0.025};
  const std::vector<double> offset = {-0.5, 1.2, 0.3, -0.8, 0.1, 0.9, -1.0};
  std::vector<double> log_lambda, centre;
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < lambda.size(); ++i) {
    log_lambda.push_back(std::log(lambda[i]));
    centre.push_back(std::log(52.2) - 0.272 * std::log(lambda[i]) + offset[i] * s[i]);
    points.push_back(RelationPoint::FromDraws(
        std::to_string(lambda[i]), lambda[i], Exp(ExactGaussian(centre[i], s[i], 2000, 7 + i))));
  }
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points, WithResamples(4000));
  ASSERT_TRUE(fit.fitted);
  const Wls wls = ClosedForm(log_lambda, centre, s);
  const double s_log_a = std::sqrt(wls.cov(0, 0)), s_alpha = std::sqrt(wls.cov(1, 1));
  const Estimate alpha = fit.Find("alpha")->estimate;
  const Estimate a = fit.Find("a")->estimate;
  EXPECT_NEAR(alpha.median, wls.beta(1), 0.08 * s_alpha);
  EXPECT_NEAR(HalfWidth(alpha), s_alpha, 0.06 * s_alpha);
  // a = exp(log a): medians and bounds map through exp, so compare in log space.
  EXPECT_NEAR(std::log(a.median), wls.beta(0), 0.08 * s_log_a);
  EXPECT_NEAR(0.5 * (std::log(a.hi68) - std::log(a.lo68)), s_log_a, 0.06 * s_log_a);
  // X(800 nm) = exp(b0 + b1 log 800).
  const Eigen::Vector2d g(1.0, std::log(800.0));
  const double sp = std::sqrt(g.dot(wls.cov * g));
  const Estimate at_pivot = fit.Find("value_at_pivot")->estimate;
  EXPECT_NEAR(std::log(at_pivot.median), g.dot(wls.beta), 0.08 * sp);
  EXPECT_NEAR(0.5 * (std::log(at_pivot.hi68) - std::log(at_pivot.lo68)), sp, 0.06 * sp);
  // The fitted sd of each point is its sd in log space.
  for (size_t i = 0; i < lambda.size(); ++i) EXPECT_NEAR(fit.points[i].fit_sd, s[i], 1e-12);
  // chi^2 of the point medians about the median relation. Reference: the minimum chi^2,
  // of the closed-form fit to the same medians. The relation used differs from that minimum
  // by delta ~ 0.03 sigma (medians vs means of 2000 draws) + 0.02 sigma (MC) per
  // coefficient, which raises chi^2 only at second order, delta^T (A^T W A) delta ~ 0.01.
  std::vector<double> medians;
  for (size_t i = 0; i < lambda.size(); ++i) {
    std::vector<double> logs;
    for (double v : points[i].draws) logs.push_back(std::log(v));
    std::sort(logs.begin(), logs.end());
    medians.push_back(0.5 * (logs[logs.size() / 2 - 1] + logs[logs.size() / 2]));
  }
  const Wls at_medians = ClosedForm(log_lambda, medians, s);
  double chi2_min = 0.0;
  for (size_t i = 0; i < lambda.size(); ++i) {
    const double r =
        (medians[i] - at_medians.beta(0) - at_medians.beta(1) * log_lambda[i]) / s[i];
    chi2_min += r * r;
  }
  EXPECT_GE(fit.chi2, chi2_min - 1e-9);
  EXPECT_LT(fit.chi2 - chi2_min, 0.05);
  EXPECT_EQ(fit.dof, 5);
  EXPECT_DOUBLE_EQ(fit.p_value, ChiSquareUpperTail(fit.chi2, 5));
}

TEST(Relations, GaussianPointsWithoutDrawsAreFlaggedAndFitted) {
  const LinearData d;
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < d.x.size(); ++i) {
    points.push_back(RelationPoint::FromGaussian("I" + std::to_string(i), d.x[i], d.centre[i],
                                                 d.sd[i]));
  }
  const RelationFit fit = MustFit(RelationKind::kLinear, points, WithResamples(4000));
  ASSERT_TRUE(fit.fitted);
  EXPECT_TRUE(fit.HasFlag(kFlagGaussianApproximation));
  EXPECT_TRUE(fit.points[0].gaussian);
  const Wls wls = ClosedForm(d.x, d.centre, d.sd);
  const double s1 = std::sqrt(wls.cov(1, 1));
  // Fresh Gaussian deviates add their own sampling error of the mean, sigma / sqrt(R), to
  // the median's 1.25 sigma / sqrt(R): 4 standard errors of the sum are 0.1 sigma.
  EXPECT_NEAR(fit.Find("slope")->estimate.median, wls.beta(1), 0.1 * s1);
  EXPECT_NEAR(HalfWidth(fit.Find("slope")->estimate), s1, 0.06 * s1);
}

// Over many synthetic data sets with known truth, the 68.27 % interval must cover the truth
// in 68.27 % of them. With N = 1000 sets the binomial standard error is 1.5 %; +-4 % is 2.7
// standard errors (and leaves room for the ~3 % Monte-Carlo jitter of each bound at R = 1000,
// which changes the coverage only at second order).
TEST(Relations, IntervalsCoverTheTruth) {
  CCDPSF_RELEASE_ONLY();  // many relation fits; the relations run sanitized in the other Relations
  // cases
  const int num_sets = 1000;
  const std::vector<double> lambda = {600, 680, 750, 820, 890};
  const std::vector<double> intensity = {1.0e4, 5.0e4, 1.0e5, 1.5e5};
  std::mt19937_64 engine(2024);
  int cover_alpha = 0, cover_slope = 0, cover_pivot = 0;
  for (int k = 0; k < num_sets; ++k) {
    std::vector<RelationPoint> wl, in;
    for (size_t i = 0; i < lambda.size(); ++i) {
      const double s = 0.02 + 0.01 * i;  // log-space sd
      const double truth = std::log(52.2) - 0.272 * std::log(lambda[i]);
      const double observed = truth + s * StandardNormal(engine);
      std::vector<double> draws(500);
      for (double& v : draws) v = std::exp(observed + s * StandardNormal(engine));
      wl.push_back(RelationPoint::FromDraws("", lambda[i], std::move(draws)));
    }
    for (size_t i = 0; i < intensity.size(); ++i) {
      const double s = 0.05;
      const double observed = 6.61 + 1.14e-5 * intensity[i] + s * StandardNormal(engine);
      std::vector<double> draws(500);
      for (double& v : draws) v = observed + s * StandardNormal(engine);
      in.push_back(RelationPoint::FromDraws("", intensity[i], std::move(draws)));
    }
    const RelationFit fw = MustFit(RelationKind::kPowerLaw, wl, WithResamples(1000, k));
    const RelationFit fi = MustFit(RelationKind::kLinear, in, WithResamples(1000, k));
    const Estimate alpha = fw.Find("alpha")->estimate;
    const Estimate slope = fi.Find("slope")->estimate;
    const Estimate at_pivot = fw.Find("value_at_pivot")->estimate;
    const double pivot_truth = 52.2 * std::pow(800.0, -0.272);
    cover_alpha += alpha.lo68 <= -0.272 && -0.272 <= alpha.hi68;
    cover_slope += slope.lo68 <= 1.14e-5 && 1.14e-5 <= slope.hi68;
    cover_pivot += at_pivot.lo68 <= pivot_truth && pivot_truth <= at_pivot.hi68;
  }
  EXPECT_NEAR(cover_alpha / double(num_sets), 0.6827, 0.04);
  EXPECT_NEAR(cover_slope / double(num_sets), 0.6827, 0.04);
  EXPECT_NEAR(cover_pivot / double(num_sets), 0.6827, 0.04);
}

// A point with a 10x larger error, displaced by 2 of its own sd, barely moves the fit: the
// ensemble follows the weighted closed form, whose shift is ~1/100 of the unweighted one.
TEST(Relations, WeightsFollowThePointErrors) {
  const std::vector<double> x = {2.0e4, 5.0e4, 8.0e4, 1.1e5, 1.5e5};
  std::vector<double> sd = {0.02, 0.02, 0.2, 0.02, 0.02};
  std::vector<double> centre, truth;
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < x.size(); ++i) {
    truth.push_back(6.61 + 1.14e-5 * x[i]);
    centre.push_back(truth.back() + (i == 2 ? 2.0 * sd[i] : 0.0));
    points.push_back(RelationPoint::FromDraws("", x[i], ExactGaussian(centre[i], sd[i], 2000, i)));
  }
  const RelationFit fit = MustFit(RelationKind::kLinear, points, WithResamples(4000));
  const Wls wls = ClosedForm(x, centre, sd);
  const Wls ols = ClosedForm(x, centre, std::vector<double>(x.size(), 1.0));
  const Estimate at_pivot = fit.Find("value_at_pivot")->estimate;
  const double truth_pivot = 6.61 + 1.14e-5 * kReferenceIntensityE;
  const Eigen::Vector2d g(1.0, kReferenceIntensityE);
  const double sp = std::sqrt(g.dot(wls.cov * g));
  EXPECT_NEAR(at_pivot.median, g.dot(wls.beta), 0.08 * sp);
  const double weighted_shift = std::fabs(g.dot(wls.beta) - truth_pivot);
  const double unweighted_shift = std::fabs(g.dot(ols.beta) - truth_pivot);
  EXPECT_LT(weighted_shift, 0.05 * unweighted_shift);
  EXPECT_LT(std::fabs(at_pivot.median - truth_pivot), 0.2 * sp);
  EXPECT_GT(std::fabs(g.dot(ols.beta) - truth_pivot), 2.0 * sp);  // the unweighted fit would move
}

TEST(Relations, ThreePointsArePoorlyConstrained) {
  const std::vector<double> x = {2.0e4, 8.0e4, 1.5e5};
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < x.size(); ++i) {
    points.push_back(
        RelationPoint::FromDraws("", x[i], ExactGaussian(6.61 + 1.14e-5 * x[i], 0.03, 1000, i)));
  }
  const RelationFit fit = MustFit(RelationKind::kLinear, points);
  ASSERT_TRUE(fit.fitted);
  EXPECT_EQ(fit.dof, 1);
  ASSERT_TRUE(fit.HasFlag(kFlagPoorlyConstrained));
  std::string reason;
  for (const RelationFlag& f : fit.flags) {
    if (f.code == kFlagPoorlyConstrained) reason = f.reason;
  }
  EXPECT_NE(reason.find("3 points, 1 degree of freedom"), std::string::npos) << reason;
  EXPECT_TRUE(std::isfinite(fit.chi2));
  EXPECT_FALSE(fit.HasFlag(kFlagNotFitted));
}

TEST(Relations, TwoPointsHaveNoDegreesOfFreedom) {
  std::vector<RelationPoint> points = {
      RelationPoint::FromDraws("", 600, Exp(ExactGaussian(std::log(9.8), 0.02, 1000, 1))),
      RelationPoint::FromDraws("", 890, Exp(ExactGaussian(std::log(8.8), 0.02, 1000, 2)))};
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  ASSERT_TRUE(fit.fitted);
  EXPECT_EQ(fit.dof, 0);
  EXPECT_TRUE(std::isnan(fit.chi2));
  EXPECT_TRUE(fit.HasFlag(kFlagPoorlyConstrained));
  const nlohmann::json j = ToJson(fit);
  EXPECT_TRUE(j["chi2"].is_null());
  EXPECT_TRUE(j["p_value"].is_null());
  EXPECT_TRUE(j["inflated"].is_null());
  // Through both points: alpha = log(8.8 / 9.8) / log(890 / 600) (MC error 0.08 sigma).
  const double expected = std::log(8.8 / 9.8) / std::log(890.0 / 600.0);
  const double sigma = std::sqrt(2.0) * 0.02 / std::log(890.0 / 600.0);
  EXPECT_NEAR(fit.Find("alpha")->estimate.median, expected, 0.08 * sigma);
}

TEST(Relations, OnePointIsNotFitted) {
  std::vector<RelationPoint> points = {
      RelationPoint::FromDraws("800nm", 800, ExactGaussian(8.8, 0.1, 1000, 1)),
      RelationPoint::Missing("700nm", 700, "MCMC did not converge")};
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  EXPECT_FALSE(fit.fitted);
  EXPECT_TRUE(fit.HasFlag(kFlagNotFitted));
  ASSERT_EQ(fit.coefficients.size(), 3u);
  EXPECT_TRUE(std::isnan(fit.Find("alpha")->estimate.median));
  EXPECT_TRUE(fit.ValueDraws(800).empty());
  const nlohmann::json j = ToJson(fit);
  EXPECT_FALSE(j["fitted"].get<bool>());
  EXPECT_TRUE(j["alpha"]["median"].is_null());
  EXPECT_TRUE(j["a"]["lo68"].is_null());
  ASSERT_EQ(j["gaps"].size(), 1u);
  EXPECT_EQ(j["gaps"][0]["reason"], "MCMC did not converge");
  EXPECT_EQ(j["flags"][0]["flag"], "not_fitted");
}

TEST(Relations, AllPointsAtOneAbscissaAreNotFitted) {
  std::vector<RelationPoint> points = {
      RelationPoint::FromDraws("", 800, ExactGaussian(8.8, 0.1, 100, 1)),
      RelationPoint::FromDraws("", 800, ExactGaussian(8.9, 0.1, 100, 2))};
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  EXPECT_FALSE(fit.fitted);
  EXPECT_TRUE(fit.HasFlag(kFlagNotFitted));
}

TEST(Relations, MissingPointIsAGapAndExcludedExactly) {
  const LinearData d;
  std::vector<RelationPoint> with_gap = d.points;
  with_gap.insert(with_gap.begin() + 2,
                  RelationPoint::Missing("I_failed", 6.0e4, "MCMC did not converge"));
  const RelationFit fit = MustFit(RelationKind::kLinear, with_gap);
  const RelationFit reference = MustFit(RelationKind::kLinear, d.points);
  ASSERT_EQ(fit.gaps.size(), 1u);
  EXPECT_EQ(fit.gaps[0].label, "I_failed");
  EXPECT_EQ(fit.gaps[0].abscissa, 6.0e4);
  EXPECT_EQ(fit.gaps[0].reason, "MCMC did not converge");
  EXPECT_EQ(fit.points.size(), d.points.size());
  EXPECT_EQ(fit.dof, static_cast<int>(d.points.size()) - 2);
  // A gap is exactly equivalent to leaving the point out (per-point random streams).
  EXPECT_EQ(fit.Find("slope")->draws, reference.Find("slope")->draws);
  EXPECT_EQ(fit.chi2, reference.chi2);
}

TEST(Relations, UnusablePointsBecomeGapsWithReasons) {
  std::vector<RelationPoint> points = {
      RelationPoint::FromDraws("negative", 600, {0.1, -0.2, 0.3}),
      RelationPoint::FromDraws("constant", 650, {0.1, 0.1, 0.1}),
      RelationPoint::FromDraws("nan_x", NAN, {0.1, 0.2}),
      RelationPoint::FromDraws("one_finite", 700, {0.1, NAN}),
      RelationPoint::FromGaussian("no_sd", 750, 0.1, 0.0),
      RelationPoint::FromDraws("ok1", 800, ExactGaussian(0.05, 0.005, 500, 1)),
      RelationPoint::FromDraws("ok2", 850, ExactGaussian(0.045, 0.005, 500, 2)),
      RelationPoint::FromDraws("ok3", 890, ExactGaussian(0.044, 0.005, 500, 3))};
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  ASSERT_EQ(fit.gaps.size(), 5u);
  EXPECT_NE(fit.gaps[0].reason.find("1 of 3 draws are <= 0"), std::string::npos);
  EXPECT_NE(fit.gaps[1].reason.find("no spread"), std::string::npos);
  EXPECT_NE(fit.gaps[2].reason.find("abscissa"), std::string::npos);
  EXPECT_NE(fit.gaps[3].reason.find("1 finite"), std::string::npos);
  EXPECT_NE(fit.gaps[4].reason.find("sd > 0"), std::string::npos);
  EXPECT_EQ(fit.points.size(), 3u);
  EXPECT_TRUE(fit.fitted);
}

TEST(Relations, ExcessScatterIsFlaggedAndInflatedIntervalsReported) {
  // Points with 1 % errors scattered by ~5 %: chi^2/dof ~ 25.
  const std::vector<double> lambda = {600, 650, 700, 750, 800, 850, 890};
  const std::vector<double> offset = {5, -4, 6, -5, 3, -6, 4};
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < lambda.size(); ++i) {
    const double c = std::log(52.2) - 0.272 * std::log(lambda[i]) + 0.01 * offset[i];
    points.push_back(RelationPoint::FromDraws("", lambda[i], Exp(ExactGaussian(c, 0.01, 1000, i))));
  }
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  ASSERT_TRUE(fit.fitted);
  EXPECT_TRUE(fit.HasFlag(kFlagScatterExceedsErrors));
  EXPECT_LT(fit.p_value, 0.01);
  EXPECT_GT(fit.scale_factor, 3.0);
  // alpha is the fitted c1 itself, so its inflated interval is exactly S times wider about
  // the same median (percentiles commute with the linear rescaling).
  const Coefficient& alpha = *fit.Find("alpha");
  EXPECT_NEAR(alpha.inflated.median, alpha.estimate.median, 1e-12);
  EXPECT_NEAR(alpha.inflated.hi68 - alpha.inflated.median,
              fit.scale_factor * (alpha.estimate.hi68 - alpha.estimate.median), 1e-9);
  EXPECT_NEAR(alpha.inflated.median - alpha.inflated.lo68,
              fit.scale_factor * (alpha.estimate.median - alpha.estimate.lo68), 1e-9);
  // Normalised residuals reproduce chi^2.
  double chi2 = 0.0;
  for (const PointSummary& p : fit.points) chi2 += p.normalized_residual * p.normalized_residual;
  EXPECT_NEAR(chi2, fit.chi2, 1e-9 * fit.chi2);
  const nlohmann::json j = ToJson(fit);
  EXPECT_NEAR(j["inflated"]["scale_factor"].get<double>(), fit.scale_factor, 1e-12);
  // Points consistent with their errors: not flagged, inflated == primary (max(1, S)).
  const RelationFit clean = MustFit(RelationKind::kLinear, LinearData().points);
  EXPECT_FALSE(clean.HasFlag(kFlagScatterExceedsErrors));
  EXPECT_LT(clean.scale_factor, 1.0);
  EXPECT_EQ(clean.Find("slope")->inflated.hi68, clean.Find("slope")->estimate.hi68);
  EXPECT_EQ(ToJson(clean)["inflated"]["scale_factor"].get<double>(), 1.0);
}

TEST(Relations, ShortLeverArmAndWideCoefficientsArePoorlyConstrained) {
  std::vector<RelationPoint> points;
  for (int i = 0; i < 5; ++i) {
    const double x = 790.0 + 5.0 * i;  // span 20 nm = 2.5 % of 800 nm
    points.push_back(RelationPoint::FromDraws(
        "", x, Exp(ExactGaussian(std::log(52.2 * std::pow(x, -0.272)), 0.02, 500, i))));
  }
  const RelationFit fit = MustFit(RelationKind::kPowerLaw, points);
  ASSERT_TRUE(fit.HasFlag(kFlagPoorlyConstrained));
  const std::string reason = fit.flags[0].reason;
  EXPECT_NE(reason.find("short lever arm"), std::string::npos) << reason;
  EXPECT_NE(reason.find("alpha: 68 % half-width"), std::string::npos) << reason;
  // The paper-like data are not flagged.
  EXPECT_FALSE(MustFit(RelationKind::kLinear, LinearData().points).HasFlag(kFlagPoorlyConstrained));
}

TEST(Relations, DeterministicForASeed) {
  const LinearData d;
  const RelationFit a = MustFit(RelationKind::kLinear, d.points, WithResamples(500, 9));
  const RelationFit b = MustFit(RelationKind::kLinear, d.points, WithResamples(500, 9));
  const RelationFit c = MustFit(RelationKind::kLinear, d.points, WithResamples(500, 10));
  EXPECT_EQ(a.Find("slope")->draws, b.Find("slope")->draws);
  EXPECT_EQ(ToJson(a).dump(), ToJson(b).dump());
  EXPECT_NE(a.Find("slope")->draws, c.Find("slope")->draws);
  EXPECT_EQ(ToJson(a)["seed"].get<uint64_t>(), 9u);
}

// Points of one joint fit (RelationPoint::joint_set): state j of a posterior puts every
// point on its own line, y_k = a_j + b_j x_k. Resampled state by state, the weighted fit
// through exactly collinear points returns that state's line whatever the weights, so
// every intercept and slope draw is one of the states' (to rounding, 1e-9 relative), and
// their summaries are those of the states' a_j and b_j. Resampled independently (no joint
// set), the draws mix states: most are none of them, and the slope's spread differs.
TEST(Relations, JointPointsAreResampledStateByState) {
  std::mt19937_64 engine(7);
  const int states = 500;
  std::vector<double> a(states), b(states);
  for (int j = 0; j < states; ++j) {
    a[j] = 6.6 + 0.05 * StandardNormal(engine);
    // Anticorrelated with the intercept, as a kernel width and its slope are.
    b[j] = 1.1e-5 - 2e-7 * (a[j] - 6.6) / 0.05 + 3e-8 * StandardNormal(engine);
  }
  const double xs[] = {3.0e4, 8.0e4, 1.6e5};
  auto points = [&](int joint_set) {
    std::vector<RelationPoint> out;
    for (double x : xs) {
      std::vector<double> draws(states);
      for (int j = 0; j < states; ++j) draws[j] = a[j] + b[j] * x;
      RelationPoint p = RelationPoint::FromDraws("x" + std::to_string(x), x, draws);
      p.joint_set = joint_set;
      out.push_back(p);
    }
    return out;
  };
  RelationOptions options;
  std::string error;
  auto joint = FitRelation(RelationKind::kLinear, points(0), options, &error);
  ASSERT_TRUE(joint.has_value()) << error;
  ASSERT_TRUE(joint->fitted);
  EXPECT_TRUE(joint->HasFlag(kFlagJointPoints));
  EXPECT_FALSE(joint->HasFlag(kFlagPoorlyConstrained));  // 1 dof, but one fit's own line
  const Coefficient* intercept = joint->Find("intercept");
  const Coefficient* slope = joint->Find("slope");
  ASSERT_EQ(intercept->draws.size(), slope->draws.size());
  for (size_t r = 0; r < slope->draws.size(); ++r) {
    bool found = false;
    for (int j = 0; j < states && !found; ++j) {
      found = std::fabs(slope->draws[r] - b[j]) <= 1e-9 * std::fabs(b[j]) &&
              std::fabs(intercept->draws[r] - a[j]) <= 1e-9 * std::fabs(a[j]);
    }
    ASSERT_TRUE(found) << "resampling " << r << ": slope " << slope->draws[r];
  }
  auto independent = FitRelation(RelationKind::kLinear, points(-1), options, &error);
  ASSERT_TRUE(independent.has_value()) << error;
  int matching = 0;
  for (double d : independent->Find("slope")->draws) {
    for (int j = 0; j < states; ++j) {
      if (std::fabs(d - b[j]) <= 1e-9 * std::fabs(b[j])) {
        ++matching;
        break;
      }
    }
  }
  // A resampling picks the same state for all three points with probability 1 / states^2.
  EXPECT_LT(matching, 20);
}

TEST(Relations, InvalidOptionsAreRejected) {
  RelationOptions o;
  o.resamples = 10;
  std::string error;
  EXPECT_FALSE(FitRelation(RelationKind::kLinear, LinearData().points, o, &error).has_value());
  EXPECT_NE(error.find("resamples"), std::string::npos);
  o = RelationOptions();
  o.pivot = -1.0;
  EXPECT_FALSE(FitRelation(RelationKind::kLinear, LinearData().points, o, &error).has_value());
}

TEST(Relations, JsonHasTheTrendFields) {
  const RelationFit fit = MustFit(RelationKind::kLinear, LinearData().points);
  const nlohmann::json j = ToJson(fit);
  for (const char* c : {"intercept", "slope", "value_at_pivot"}) {
    for (const char* f : {"median", "lo68", "hi68", "lo95", "hi95", "sd"}) {
      EXPECT_TRUE(j[c][f].is_number()) << c << "." << f;
    }
  }
  for (const char* f : {"chi2", "dof", "p_value", "n_points", "pivot", "resamples"}) {
    EXPECT_TRUE(j[f].is_number()) << f;
  }
  EXPECT_EQ(j["kind"], "linear");
  EXPECT_EQ(j["n_points"].get<int>(), 6);
  EXPECT_TRUE(j["gaps"].is_array());
  EXPECT_TRUE(j["flags"].is_array());
  EXPECT_EQ(j["points"][0]["source"], "posterior_draws");
}

// Reference values from closed forms independent of the incomplete-gamma code:
// odd dof 1, 3: Q = erfc(sqrt(x/2)) [+ sqrt(2x/pi) e^(-x/2)]; even dof 2k:
// Q = e^(-x/2) sum_{j<k} (x/2)^j / j!. Relative tolerance 1e-10 (both are accurate to
// ~1e-14; the sum loses a little to rounding for large k).
TEST(Relations, ChiSquarePValueMatchesClosedForms) {
  for (double x : {1e-4, 0.3, 1.0, 3.841458820694124, 7.0, 20.0, 60.0, 200.0}) {
    const double q1 = std::erfc(std::sqrt(x / 2));
    EXPECT_NEAR(ChiSquareUpperTail(x, 1), q1, 1e-10 * q1) << x;
    const double q3 = q1 + std::sqrt(2 * x / M_PI) * std::exp(-x / 2);
    EXPECT_NEAR(ChiSquareUpperTail(x, 3), q3, 1e-10 * q3) << x;
    for (int k = 1; k <= 20; ++k) {
      double sum = 0.0, term = 1.0;
      for (int j = 0; j < k; ++j) {
        sum += term;
        term *= (x / 2) / (j + 1);
      }
      const double q = std::exp(-x / 2) * sum;
      EXPECT_NEAR(ChiSquareUpperTail(x, 2 * k), q, 1e-10 * q) << x << " dof " << 2 * k;
    }
  }
  EXPECT_NEAR(ChiSquareUpperTail(3.841458820694124, 1), 0.05, 1e-12);
  EXPECT_NEAR(ChiSquareUpperTail(23.209251158954356, 10), 0.01, 1e-10);
  EXPECT_TRUE(std::isnan(ChiSquareUpperTail(1.0, 0)));
}

// The combined model on exact relations (errors 1e-7 relative) equals the formula by hand.
TEST(Relations, CombinedModelMatchesTheFormulaByHand) {
  auto linear = [](double i) { return 6.61 + 1.14e-5 * i; };
  auto power = [](double l) { return 52.2 * std::pow(l, -0.272); };
  std::vector<RelationPoint> in, wl;
  for (double i : {1.0e4, 6.0e4, 1.2e5, 1.6e5}) {
    in.push_back(RelationPoint::FromDraws("", i, ExactGaussian(linear(i), 1e-7, 200, 1)));
  }
  for (double l : {600.0, 700.0, 800.0, 890.0}) {
    wl.push_back(RelationPoint::FromDraws("", l, Exp(ExactGaussian(std::log(power(l)), 1e-7,
                                                                   200, 2))));
  }
  const RelationFit fi = MustFit(RelationKind::kLinear, in);
  const RelationFit fw = MustFit(RelationKind::kPowerLaw, wl);
  std::string error;
  const std::optional<CombinedValue> v =
      EvaluateCombined(&fi, fw, 5.0e4, 650.0, kReferenceIntensityE, &error);
  ASSERT_TRUE(v.has_value()) << error;
  const double expected = linear(5.0e4) / linear(kReferenceIntensityE) * power(650.0);
  EXPECT_NEAR(v->estimate.median, expected, 1e-6 * expected);
  EXPECT_TRUE(v->notes.empty());
  EXPECT_NEAR(fw.Find("a")->estimate.median, 52.2, 1e-4 * 52.2);
  EXPECT_NEAR(fi.Find("intercept")->estimate.median, 6.61, 1e-5 * 6.61);
  // At I0 the intensity relation cancels and may be absent; outside the range: a note.
  const std::optional<CombinedValue> at_i0 =
      EvaluateCombined(nullptr, fw, kReferenceIntensityE, 550.0, kReferenceIntensityE, &error);
  ASSERT_TRUE(at_i0.has_value()) << error;
  EXPECT_NEAR(at_i0->estimate.median, power(550.0), 1e-6 * power(550.0));
  ASSERT_EQ(at_i0->notes.size(), 1u);
  EXPECT_NE(at_i0->notes[0].find("extrapolated"), std::string::npos);
  EXPECT_FALSE(EvaluateCombined(nullptr, fw, 5.0e4, 650.0, kReferenceIntensityE, &error));
  EXPECT_NE(error.find("intensity relation"), std::string::npos);
}

// Draw r of one relation is paired with draw r of the other: independent, so the relative
// variances add. Checked to 8 % (the sds come from R = 4000 draws: 1.1 % each).
TEST(Relations, CombinedModelPropagatesBothRelations) {
  const LinearData d;
  const RelationFit fi = MustFit(RelationKind::kLinear, d.points, WithResamples(4000, 1));
  std::vector<RelationPoint> wl;
  for (double l : {600.0, 700.0, 800.0, 890.0}) {
    wl.push_back(RelationPoint::FromDraws(
        "", l, Exp(ExactGaussian(std::log(52.2 * std::pow(l, -0.272)), 0.02, 1000, l))));
  }
  const RelationFit fw = MustFit(RelationKind::kPowerLaw, wl, WithResamples(4000, 2));
  std::string error;
  const std::optional<CombinedValue> v =
      EvaluateCombined(&fi, fw, 2.0e4, 650.0, kReferenceIntensityE, &error);
  ASSERT_TRUE(v.has_value()) << error;
  const std::vector<double> num = fi.ValueDraws(2.0e4), den = fi.ValueDraws(kReferenceIntensityE);
  std::vector<double> ratio(num.size());
  for (size_t r = 0; r < num.size(); ++r) ratio[r] = num[r] / den[r];
  const Estimate er = SummarizeDraws(ratio);
  const Estimate ew = SummarizeDraws(fw.ValueDraws(650.0));
  const double rel = std::hypot(er.sd / er.median, ew.sd / ew.median);
  EXPECT_NEAR(v->estimate.sd / v->estimate.median, rel, 0.08 * rel);
  EXPECT_NEAR(v->estimate.median, er.median * ew.median, 0.1 * v->estimate.sd);
}

TEST(Relations, TrendMetricsAreFitDerivedQuantities) {
  const std::vector<std::string>& derived = fit::DerivedNames();
  for (const std::string& m : TrendMetricNames()) {
    EXPECT_NE(std::find(derived.begin(), derived.end(), m), derived.end()) << m;
  }
  EXPECT_EQ(RelationName("fwhm_um", RelationKind::kPowerLaw), "fwhm_um_vs_wavelength");
  EXPECT_EQ(RelationName("fwhm_um", RelationKind::kLinear), "fwhm_um_vs_intensity");
}

}  // namespace
}  // namespace ccdpsf::trend
