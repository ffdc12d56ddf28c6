// The ensemble sampler on densities with known moments, its determinism across thread
// counts, its convergence bookkeeping and its input checks.
//
// Moment tolerances: for any function f of the parameters, the post-burn-in chain average
// of f has Monte Carlo standard error SE = sd(f) / sqrt(ESS_f), ESS_f = walkers * steps /
// tau_f, with tau_f the ensemble autocorrelation time of the series f(theta) itself (the
// Markov-chain central limit theorem). Means use f = theta_k, variances f = (theta_k -
// mu_k)^2, covariances f = (theta_i - mu_i)(theta_j - mu_j), each with its own tau. We allow
// 5 SE: about 25 such checks run here, and 5 SE leaves room for the uncertainty of tau_f
// itself (~10 %) while a wrong move (e.g. a missing z^(dim-1) factor, which biases variances
// by tens of per cent) still fails by a wide margin.
#include "ccdpsf/fit/ensemble_sampler.h"
#include "ccdpsf/fit/sampler_checkpoint.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Cholesky"
#include "Eigen/Core"
#include "Eigen/LU"
#include "ccdpsf/fit/autocorrelation.h"
#include "ccdpsf/random.h"
#include "gtest/gtest.h"
#include "support/slow_test.h"

namespace ccdpsf::fit {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Gaussian {
  Eigen::VectorXd mean;
  Eigen::MatrixXd covariance;
  Eigen::MatrixXd precision;

  Gaussian(const Eigen::VectorXd& m, const Eigen::MatrixXd& c)
      : mean(m),
        covariance(c),
        precision(c.llt().solve(Eigen::MatrixXd::Identity(m.size(), m.size()))) {}

  double operator()(const double* theta) const {
    const Eigen::VectorXd d = Eigen::Map<const Eigen::VectorXd>(theta, mean.size()) - mean;
    return -0.5 * d.dot(precision * d);
  }
};

// The 2-D case: means (1, -2), sds (0.5, 3), correlation 0.9.
Gaussian Correlated2d() {
  Eigen::VectorXd mean(2);
  mean << 1.0, -2.0;
  Eigen::MatrixXd cov(2, 2);
  cov << 0.25, 0.9 * 0.5 * 3.0, 0.9 * 0.5 * 3.0, 9.0;
  return Gaussian(mean, cov);
}

// The 5-D case: sds from 0.01 to 100 (four decades, which an affine-invariant move must
// not notice) and correlations 0.5^|i - j|.
Gaussian Scaled5d() {
  const double sd[5] = {0.01, 1.0, 100.0, 0.3, 5.0};
  Eigen::VectorXd mean(5);
  mean << 0.5, -1.0, 300.0, 0.0, 20.0;
  Eigen::MatrixXd cov(5, 5);
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 5; ++j) cov(i, j) = sd[i] * sd[j] * std::pow(0.5, std::abs(i - j));
  }
  return Gaussian(mean, cov);
}

// A tight ball (1e-3 sd) centred `offset_sd` standard deviations from the mean in every
// coordinate, so the sampler has to travel and expand: what burn-in is for.
std::vector<double> InitialBall(const Gaussian& g, int walkers, double offset_sd, uint64_t seed) {
  const int dim = static_cast<int>(g.mean.size());
  std::mt19937_64 engine(seed);
  std::vector<double> initial(walkers * dim);
  for (int w = 0; w < walkers; ++w) {
    for (int k = 0; k < dim; ++k) {
      const double sd = std::sqrt(g.covariance(k, k));
      initial[w * dim + k] = g.mean(k) + sd * (offset_sd + 1e-3 * StandardNormal(engine));
    }
  }
  return initial;
}

std::vector<LogDensity> PerThread(const LogDensity& f, int threads) {
  return std::vector<LogDensity>(threads, f);
}

SamplerOptions QuietOptions(uint64_t seed) {
  SamplerOptions options;
  options.progress = false;
  options.seed = seed;
  return options;
}

struct McEstimate {
  double mean = 0.0;
  double se = 0.0;
};

// Post-burn-in average of f and its Monte Carlo standard error (see the file comment).
McEstimate Estimate(const SamplerResult& r, const std::function<double(const double*)>& f) {
  const int n = r.num_steps - r.burn_in;
  const int walkers = r.num_walkers;
  std::vector<double> values(static_cast<size_t>(n) * walkers);
  for (int t = 0; t < n; ++t) {
    for (int w = 0; w < walkers; ++w) {
      values[t * walkers + w] = f(&r.chain[((r.burn_in + t) * walkers + w) * r.dim]);
    }
  }
  double mean = 0.0;
  for (double v : values) mean += v;
  mean /= values.size();
  double var = 0.0;
  for (double v : values) var += (v - mean) * (v - mean);
  var /= values.size() - 1;
  const std::optional<AutocorrelationTime> tau =
      EnsembleIntegratedAutocorrelationTime(values.data(), n, walkers, walkers, 1);
  EXPECT_TRUE(tau.has_value() && tau->window_found);
  const double ess = EffectiveSampleSize(walkers, n, tau ? tau->tau : kInf);
  return {mean, std::sqrt(var / ess)};
}

// Means, variances and covariances of a Gaussian's samples within 5 SE.
void ExpectGaussianMoments(const SamplerResult& r, const Gaussian& g) {
  const int dim = static_cast<int>(g.mean.size());
  for (int i = 0; i < dim; ++i) {
    const McEstimate m = Estimate(r, [i](const double* x) { return x[i]; });
    EXPECT_NEAR(m.mean, g.mean(i), 5.0 * m.se) << "mean of parameter " << i;
    for (int j = i; j < dim; ++j) {
      const double mi = g.mean(i), mj = g.mean(j);
      const McEstimate c = Estimate(r, [=](const double* x) { return (x[i] - mi) * (x[j] - mj); });
      EXPECT_NEAR(c.mean, g.covariance(i, j), 5.0 * c.se) << "covariance " << i << "," << j;
    }
  }
}

void ExpectConsistentShapes(const SamplerResult& r, int walkers, int dim) {
  EXPECT_EQ(r.num_walkers, walkers);
  EXPECT_EQ(r.dim, dim);
  EXPECT_EQ(r.chain.size(), static_cast<size_t>(r.num_steps) * walkers * dim);
  EXPECT_EQ(r.log_prob.size(), static_cast<size_t>(r.num_steps) * walkers);
  EXPECT_EQ(r.acceptance_fraction.size(), static_cast<size_t>(walkers));
  EXPECT_EQ(r.tau.size(), static_cast<size_t>(dim));
  EXPECT_EQ(r.ess.size(), static_cast<size_t>(dim));
  EXPECT_GE(r.burn_in, 0);
  EXPECT_LE(r.burn_in, r.num_steps / 2);
}

TEST(EnsembleSampler, Correlated2dGaussianMoments) {
  const Gaussian g = Correlated2d();
  const int walkers = 16;
  SamplerOptions options = QuietOptions(11);
  SamplerResult r;
  std::string error;
  ASSERT_TRUE(
      RunEnsembleSampler(PerThread(g, 2), 2, InitialBall(g, walkers, 2.0, 1), options, &r, &error))
      << error;
  ExpectConsistentShapes(r, walkers, 2);
  EXPECT_TRUE(r.converged) << r.stop_reason;
  EXPECT_EQ(r.num_threads_used, 2);
  ExpectGaussianMoments(r, g);
  EXPECT_GT(r.mean_acceptance, 0.2);
  EXPECT_LT(r.mean_acceptance, 0.8);
}

TEST(EnsembleSampler, Scaled5dGaussianMomentsAndAcceptance) {
  const Gaussian g = Scaled5d();
  const int walkers = 32;
  SamplerResult r;
  std::string error;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 5, InitialBall(g, walkers, 3.0, 2),
                                 QuietOptions(12), &r, &error))
      << error;
  ExpectConsistentShapes(r, walkers, 5);
  EXPECT_TRUE(r.converged) << r.stop_reason;
  ExpectGaussianMoments(r, g);
  EXPECT_GT(r.mean_acceptance, 0.2);
  EXPECT_LT(r.mean_acceptance, 0.8);
  for (double a : r.acceptance_fraction) {
    EXPECT_GT(a, 0.1);
    EXPECT_LT(a, 0.9);
  }
}

TEST(EnsembleSampler, UniformBoxMomentsAndSupport) {
  CCDPSF_RELEASE_ONLY();  // long chains; see EnsembleSampler.Correlated2dGaussianMoments for the
  // sanitized run
  // Density 1 on [-1, 3] x [0, 0.5] x [10, 20], -inf outside: mean (lo + hi) / 2 and
  // variance (hi - lo)^2 / 12 per coordinate, and no sample may leave the box.
  const double lo[3] = {-1.0, 0.0, 10.0};
  const double hi[3] = {3.0, 0.5, 20.0};
  const LogDensity box = [&](const double* x) {
    for (int k = 0; k < 3; ++k) {
      if (x[k] < lo[k] || x[k] > hi[k]) return -kInf;
    }
    return 0.0;
  };
  const int walkers = 16;
  std::mt19937_64 engine(3);
  std::vector<double> initial(walkers * 3);
  for (int w = 0; w < walkers; ++w) {
    for (int k = 0; k < 3; ++k) initial[w * 3 + k] = lo[k] + (hi[k] - lo[k]) * Uniform01(engine);
  }
  SamplerResult r;
  std::string error;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(box, 2), 3, initial, QuietOptions(13), &r, &error))
      << error;
  ExpectConsistentShapes(r, walkers, 3);
  EXPECT_TRUE(r.converged) << r.stop_reason;
  for (size_t i = 0; i < r.chain.size(); ++i) {
    const int k = static_cast<int>(i % 3);
    ASSERT_GE(r.chain[i], lo[k]);
    ASSERT_LE(r.chain[i], hi[k]);
  }
  for (int k = 0; k < 3; ++k) {
    const double mu = 0.5 * (lo[k] + hi[k]);
    const double var = (hi[k] - lo[k]) * (hi[k] - lo[k]) / 12.0;
    const McEstimate m = Estimate(r, [k](const double* x) { return x[k]; });
    EXPECT_NEAR(m.mean, mu, 5.0 * m.se) << "mean of parameter " << k;
    const McEstimate v =
        Estimate(r, [k, mu](const double* x) { return (x[k] - mu) * (x[k] - mu); });
    EXPECT_NEAR(v.mean, var, 5.0 * v.se) << "variance of parameter " << k;
  }
}

// The Laplace-informed independence move of ensemble_sampler.h with the proposal centred
// `shift_sd` standard deviations from g's mean in every coordinate and a scale matrix of
// scale^2 times g's covariance (shift 0, scale 1: the exact Laplace approximation of g).
void SetLaplaceMove(const Gaussian& g, double fraction, double shift_sd, double scale,
                    SamplerOptions* options) {
  const int dim = static_cast<int>(g.mean.size());
  const Eigen::MatrixXd l = (scale * scale * g.covariance).llt().matrixL();
  options->independence_fraction = fraction;
  options->independence_mean.resize(dim);
  options->independence_cholesky.assign(static_cast<size_t>(dim) * dim, 0.0);
  for (int i = 0; i < dim; ++i) {
    options->independence_mean[i] = g.mean(i) + shift_sd * std::sqrt(g.covariance(i, i));
    for (int j = 0; j <= i; ++j) options->independence_cholesky[i * dim + j] = l(i, j);
  }
}

// Both with the stretch move alone and with the independence move mixed in (whose choice
// and proposals come from the walker's own stream too).
TEST(EnsembleSampler, SameSeedIsBitIdenticalForAnyThreadCount) {
  for (const double fraction : {0.0, 0.5}) {
    SCOPED_TRACE("independence_fraction " + std::to_string(fraction));
    const Gaussian g = Correlated2d();
    // 10 walkers: halves of 5, split unevenly over 2 and 3 threads.
    const std::vector<double> initial = InitialBall(g, 10, 1.0, 4);
    SamplerOptions options = QuietOptions(14);
    options.max_steps = 250;  // not a multiple of check_interval: the final check runs too
    SetLaplaceMove(g, fraction, 0.3, 1.2, &options);
    std::vector<SamplerResult> runs(3);
    for (int threads = 1; threads <= 3; ++threads) {
      options.num_threads = threads;
      std::string error;
      SamplerResult& r = runs[threads - 1];
      ASSERT_TRUE(RunEnsembleSampler(PerThread(g, threads), 2, initial, options, &r, &error))
          << error;
      EXPECT_EQ(r.num_threads_used, threads);
      EXPECT_EQ(r.num_steps, 250);
    }
    for (int i = 1; i < 3; ++i) {
      // operator== on vector<double> compares values exactly: bit-identical for non-NaN data.
      EXPECT_TRUE(runs[i].chain == runs[0].chain) << "threads " << i + 1;
      EXPECT_TRUE(runs[i].log_prob == runs[0].log_prob);
      EXPECT_TRUE(runs[i].acceptance_fraction == runs[0].acceptance_fraction);
      EXPECT_TRUE(runs[i].tau == runs[0].tau);
      EXPECT_EQ(runs[i].burn_in, runs[0].burn_in);
      EXPECT_EQ(runs[i].stop_reason, runs[0].stop_reason);
      EXPECT_EQ(runs[i].independence_proposed, runs[0].independence_proposed);
      EXPECT_TRUE(runs[i].independence_acceptance == runs[0].independence_acceptance ||
                  (std::isnan(runs[i].independence_acceptance) &&
                   std::isnan(runs[0].independence_acceptance)));
    }
    if (fraction > 0) {
      // About fraction x 250 x 10 updates take the move: 1250 +- 5 binomial sd (25).
      EXPECT_NEAR(runs[0].independence_proposed, fraction * 2500, 125);
    } else {
      EXPECT_EQ(runs[0].independence_proposed, 0);
      EXPECT_TRUE(std::isnan(runs[0].independence_acceptance));
    }

    options.num_threads = 2;
    options.seed = 15;
    SamplerResult other;
    std::string error;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &other, &error));
    EXPECT_FALSE(other.chain == runs[0].chain);
  }
}

// A run that stops after a checkpoint (as if killed) and is run again continues from it and
// ends with exactly the chain, log densities, acceptance and diagnostics of a run never
// interrupted; a checkpoint of another run (other seed) or a damaged one is not used.
// With the independence move on as well (its per-walker counts are part of the state), and a
// checkpoint of the same run with another move configuration is not used.
TEST(EnsembleSampler, ResumesFromACheckpointToTheSameChain) {
  for (const double fraction : {0.0, 0.4}) {
    SCOPED_TRACE("independence_fraction " + std::to_string(fraction));
    const Gaussian g = Correlated2d();
    const std::vector<double> initial = InitialBall(g, 10, 1.0, 4);
    SamplerOptions options = QuietOptions(21);
    SetLaplaceMove(g, fraction, 0.2, 1.1, &options);
    options.max_steps = 450;
    options.check_fraction = 0;  // checks at 100, 200, 300, 400 and 450
    options.target_ess = 1e9;    // never converged: every check is passed through
    std::string error;
    SamplerResult whole;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &whole, &error)) << error;

    const std::string path = ::testing::TempDir() + "/ccdpsf_checkpoint_" +
                             std::to_string(static_cast<long>(::getpid())) + ".bin";
    std::remove(path.c_str());
    options.checkpoint_path = path;
    options.checkpoint_seconds = 0;
    // With a checkpoint at every check, a run leaves that of step 400 (none is written at the
    // final step): what a run killed between steps 400 and 450 leaves.
    SamplerResult first;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &first, &error)) << error;
    EXPECT_EQ(first.resumed_from_step, 0);
    EXPECT_TRUE(first.chain == whole.chain);  // checkpointing changes nothing
    SamplerCheckpoint saved;
    ASSERT_TRUE(ReadSamplerCheckpoint(path, &saved, &error)) << error;
    EXPECT_EQ(saved.steps, 400);

    SamplerResult resumed;
    options.num_threads = 1;  // the threads are not part of a run's identity
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &resumed, &error))
        << error;
    EXPECT_EQ(resumed.resumed_from_step, 400);
    EXPECT_TRUE(resumed.chain == whole.chain);
    EXPECT_TRUE(resumed.log_prob == whole.log_prob);
    EXPECT_TRUE(resumed.acceptance_fraction == whole.acceptance_fraction);
    EXPECT_TRUE(resumed.tau == whole.tau);
    EXPECT_EQ(resumed.burn_in, whole.burn_in);
    EXPECT_EQ(resumed.stop_reason, whole.stop_reason);
    EXPECT_EQ(resumed.independence_proposed, whole.independence_proposed);
    EXPECT_TRUE(resumed.independence_acceptance == whole.independence_acceptance ||
                std::isnan(whole.independence_acceptance));

    // Another independence configuration (on where it was off, or another proposal scale):
    // not this run's checkpoint.
    {
      SamplerOptions changed = options;
      SetLaplaceMove(g, fraction > 0 ? fraction : 0.4, 0.2, 1.3, &changed);
      ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, changed, &resumed, &error))
          << error;
      EXPECT_EQ(resumed.resumed_from_step, 0);
      // That run replaced the checkpoint: the original configuration resumes from nothing.
      ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &resumed, &error))
          << error;
      EXPECT_EQ(resumed.resumed_from_step, 0);
      EXPECT_TRUE(resumed.chain == whole.chain);
    }

    // Another seed: the checkpoint is not this run's.
    options.seed = 22;
    SamplerResult other;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &other, &error)) << error;
    EXPECT_EQ(other.resumed_from_step, 0);
    // A damaged checkpoint (cut short) is not used either.
    options.seed = 21;
    ASSERT_TRUE(ReadSamplerCheckpoint(path, &saved, &error)) << error;  // seed 22's, step 400
    std::filesystem::resize_file(path, std::filesystem::file_size(path) / 2);
    EXPECT_FALSE(ReadSamplerCheckpoint(path, &saved, &error));
    SamplerResult after_damage;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &after_damage, &error));
    EXPECT_EQ(after_damage.resumed_from_step, 0);
    EXPECT_TRUE(after_damage.chain == whole.chain);
    // Nor one with a single bit flipped in its chain (its checksum fails), and it is said.
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &first, &error));
    {
      std::fstream file(path, std::ios::in | std::ios::out | std::ios::binary);
      file.seekg(static_cast<std::streamoff>(std::filesystem::file_size(path) / 2));
      const char byte = static_cast<char>(file.get() ^ 0x04);
      file.seekp(static_cast<std::streamoff>(std::filesystem::file_size(path) / 2));
      file.put(byte);
    }
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 1), 2, initial, options, &after_damage, &error));
    EXPECT_EQ(after_damage.resumed_from_step, 0);
    EXPECT_NE(after_damage.checkpoint_discarded.find("damaged"), std::string::npos)
        << after_damage.checkpoint_discarded;
    EXPECT_TRUE(after_damage.chain == whole.chain);
    std::remove(path.c_str());
  }
}

TEST(EnsembleSampler, LogProbIsTheDensityOfTheChain) {
  const Gaussian g = Scaled5d();
  SamplerOptions options = QuietOptions(16);
  options.max_steps = 100;
  SamplerResult r;
  std::string error;
  ASSERT_TRUE(
      RunEnsembleSampler(PerThread(g, 3), 5, InitialBall(g, 12, 0.0, 5), options, &r, &error))
      << error;
  ASSERT_EQ(r.log_prob.size(), 100u * 12);
  for (size_t i = 0; i < r.log_prob.size(); ++i) {
    ASSERT_EQ(r.log_prob[i], g(&r.chain[i * 5])) << "entry " << i;
  }
}

TEST(EnsembleSampler, ConvergesWithEnoughStepsAndSaysWhyNotOtherwise) {
  CCDPSF_RELEASE_ONLY();  // long chains; the sampler runs sanitized in
  // EnsembleSampler.Correlated2dGaussianMoments and ...SameSeedIsBitIdenticalForAnyThreadCount
  const Gaussian g = Correlated2d();
  const std::vector<double> initial = InitialBall(g, 16, 0.5, 6);
  SamplerOptions options = QuietOptions(17);
  options.target_ess = 2000;
  SamplerResult r;
  std::string error;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &r, &error)) << error;
  ASSERT_TRUE(r.converged) << r.stop_reason;
  EXPECT_LT(r.num_steps, options.max_steps);
  // Checks fall on the check_interval grid, or earlier where a grid check predicts
  // convergence: checked every 5 steps, the same chain (checks draw no random numbers)
  // converges no later, and the schedule stops it well within one interval of that (on the
  // grid alone, with check_fraction's spacing at this length, it could run ~200 steps past).
  {
    SamplerOptions every_step = options;
    every_step.check_interval = 5;
    every_step.check_fraction = 0.0;
    SamplerResult earliest;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, every_step, &earliest, &error));
    ASSERT_TRUE(earliest.converged) << earliest.stop_reason;
    EXPECT_LE(earliest.num_steps, r.num_steps);
    EXPECT_LT(r.num_steps, earliest.num_steps + options.check_interval / 2)
        << "earliest " << earliest.num_steps;
  }
  double max_tau = 0.0;
  for (int k = 0; k < 2; ++k) {
    EXPECT_GE(r.ess[k], options.target_ess);
    EXPECT_NEAR(r.ess[k], 16.0 * (r.num_steps - r.burn_in) / r.tau[k], 1e-9 * r.ess[k]);
    max_tau = std::max(max_tau, r.tau[k]);
  }
  EXPECT_GT(r.num_steps - r.burn_in, options.min_tau_multiple * max_tau);
  EXPECT_NE(r.stop_reason.find("converged after"), std::string::npos) << r.stop_reason;

  // Too few steps for either criterion.
  options.max_steps = 50;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &r, &error)) << error;
  EXPECT_FALSE(r.converged);
  EXPECT_EQ(r.num_steps, 50);
  EXPECT_NE(r.stop_reason.find("not converged at max_steps = 50"), std::string::npos)
      << r.stop_reason;
  EXPECT_NE(r.stop_reason.find("<= 50 x max tau"), std::string::npos) << r.stop_reason;
  EXPECT_NE(r.stop_reason.find("< target 2000"), std::string::npos) << r.stop_reason;

  // Long enough relative to tau, but an unreachable ESS: only that criterion is blamed.
  options.max_steps = 2000;
  options.target_ess = 1e9;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &r, &error)) << error;
  EXPECT_FALSE(r.converged);
  EXPECT_NE(r.stop_reason.find("> 50 x max tau"), std::string::npos) << r.stop_reason;
  EXPECT_NE(r.stop_reason.find("< target 1e+09"), std::string::npos) << r.stop_reason;
}

// Convergence is judged on the reported quantities too (SamplerOptions::reported). A copy of
// the state changes nothing: the same taus, so the same stopping step and chain. A reported
// quantity that drifts with the step number (a slowly mixing function of the chain, at the
// extreme) has no finite tau on any window, so the run cannot converge, and the reason names
// it; the state's own tau and ESS are still those reported.
TEST(EnsembleSampler, ConvergenceIsJudgedOnTheReportedQuantities) {
  CCDPSF_RELEASE_ONLY();  // long chains; see EnsembleSampler.Correlated2dGaussianMoments for the
  // sanitized run
  const Gaussian g = Correlated2d();
  const std::vector<double> initial = InitialBall(g, 16, 0.5, 6);
  SamplerOptions options = QuietOptions(17);
  SamplerResult plain, copied, drifting;
  std::string error;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &plain, &error)) << error;
  ASSERT_TRUE(plain.converged) << plain.stop_reason;

  options.reported = [](size_t, const double* state, double* out) {
    out[0] = state[0];
    out[1] = state[1];
  };
  options.reported_dim = 2;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &copied, &error)) << error;
  EXPECT_TRUE(copied.converged) << copied.stop_reason;
  EXPECT_EQ(copied.num_steps, plain.num_steps);
  EXPECT_EQ(copied.chain, plain.chain);
  EXPECT_EQ(copied.tau, plain.tau);

  constexpr int kWalkers = 16;
  options.reported = [](size_t index, const double* state, double* out) {
    out[0] = state[0] + 0.01 * static_cast<double>(index / kWalkers);  // + 0.01 x step
  };
  options.reported_dim = 1;
  options.max_steps = 2 * plain.num_steps;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &drifting, &error)) << error;
  EXPECT_FALSE(drifting.converged) << drifting.stop_reason;
  EXPECT_EQ(drifting.num_steps, options.max_steps);
  EXPECT_NE(drifting.stop_reason.find("reported quantity 0"), std::string::npos)
      << drifting.stop_reason;
  EXPECT_EQ(drifting.tau.size(), 2u);

  options.reported_dim = 0;
  EXPECT_FALSE(RunEnsembleSampler(PerThread(g, 2), 2, initial, options, &drifting, &error));
  EXPECT_NE(error.find("reported_dim"), std::string::npos) << error;
}

// The largest per-parameter tau of a run, and the log-density evaluations per effective sample
// (walkers x steps / smallest ESS: the cost measure of issue 18).
double MaxTau(const SamplerResult& r) { return *std::max_element(r.tau.begin(), r.tau.end()); }
double EvaluationsPerEffectiveSample(const SamplerResult& r) {
  return static_cast<double>(r.num_walkers) * r.num_steps /
         *std::min_element(r.ess.begin(), r.ess.end());
}

// On the 2-D and 5-D Gaussians with their exact Laplace approximations, the mixture gets the
// moments right (5 SE, file comment) and, with most proposals accepted, needs far fewer steps than
// the stretch move alone. The stretch move's tau here is ~30 steps in 2 and ~55 in 5
// dimensions (a property of the move); a mixture taking the independence move in a fraction f of
// the updates with acceptance alpha has tau ~ 1 / (f alpha) at most (each update redraws the state
// with probability f alpha, whatever the stretch moves do), ~1.5-2 steps for f = 0.8, alpha ~0.8.
// A quarter of the stretch-only tau leaves a wide margin on both sides and still fails if
// the move were never accepted or did not decorrelate the chain.
TEST(EnsembleSampler, LaplaceMoveGetsTheMomentsWithFewerEvaluations) {
  for (const int dim : {2, 5}) {
    const Gaussian g = dim == 2 ? Correlated2d() : Scaled5d();
    const int walkers = dim == 2 ? 16 : 32;  // as in the moment tests above
    SCOPED_TRACE(std::to_string(dim) + "-D Gaussian");
    const std::vector<double> initial = InitialBall(g, walkers, 3.0, 2);
    SamplerOptions options = QuietOptions(31);
    SamplerResult stretch, mixture;
    std::string error;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), dim, initial, options, &stretch, &error))
        << error;
    SetLaplaceMove(g, 0.8, 0.0, 1.0, &options);
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), dim, initial, options, &mixture, &error))
        << error;
    ExpectConsistentShapes(mixture, walkers, dim);
    ASSERT_TRUE(mixture.converged) << mixture.stop_reason;
    ExpectGaussianMoments(mixture, g);
    // A t_5 proposal with the target's own covariance: p / q is bounded and close to 1 over
    // most of the mass, so most proposals are accepted.
    EXPECT_GT(mixture.independence_acceptance, 0.6);
    EXPECT_LT(MaxTau(mixture), 0.25 * MaxTau(stretch));
    EXPECT_LT(EvaluationsPerEffectiveSample(mixture), EvaluationsPerEffectiveSample(stretch));
    // The numbers, for the record (issue 18's before / after on analytic targets).
    std::printf(
        "%d-D Gaussian, %d walkers: stretch only tau %.2f, %d steps, %.0f evaluations, "
        "%.1f evaluations / ESS; mixture (f 0.8, acceptance %.2f) tau %.2f, %d steps, "
        "%.0f evaluations, %.1f evaluations / ESS\n",
        dim, walkers, MaxTau(stretch), stretch.num_steps,
        static_cast<double>(walkers) * stretch.num_steps, EvaluationsPerEffectiveSample(stretch),
        mixture.independence_acceptance, MaxTau(mixture), mixture.num_steps,
        static_cast<double>(walkers) * mixture.num_steps, EvaluationsPerEffectiveSample(mixture));
  }
}

// A deliberately wrong Laplace approximation - the centre 1.5 sd off in every coordinate
// and the scale matrix a quarter of the covariance (sds halved) - still gives the right
// moments, 5 SE as in the file comment, each SE from the ESS of that very quantity: the
// mixture stays correct, only slower. The proposal is accepted often enough (checked) that
// a wrong acceptance ratio would show: without the q(x) / q(y) factor the chain would be
// pulled towards the proposal's centre, biasing every mean by a sizeable fraction of an sd
// (tens of SE at the ESS reached here), and an over-narrow proposal taken at face value
// would shrink the variances.
TEST(EnsembleSampler, WrongLaplaceMoveStillGivesTheRightMoments) {
  CCDPSF_RELEASE_ONLY();  // long chains; the Laplace move runs sanitized in
  // EnsembleSampler.BlockedTargetWithLaplaceMove
  for (const Gaussian& g : {Correlated2d(), Scaled5d()}) {
    const int dim = static_cast<int>(g.mean.size());
    SCOPED_TRACE(std::to_string(dim) + "-D Gaussian");
    const int walkers = 2 * dim + 6;
    SamplerOptions options = QuietOptions(32);
    SetLaplaceMove(g, 0.5, 1.5, 0.5, &options);
    SamplerResult r;
    std::string error;
    ASSERT_TRUE(RunEnsembleSampler(PerThread(g, 2), dim, InitialBall(g, walkers, 2.0, 3), options,
                                   &r, &error))
        << error;
    ASSERT_TRUE(r.converged) << r.stop_reason;
    ExpectGaussianMoments(r, g);
    EXPECT_GT(r.independence_acceptance, 0.002);
    EXPECT_GT(r.independence_proposed * r.independence_acceptance, 500.0);
  }
}

// The independence move drawn inside a box (ensemble_sampler.h, Bounds) on a posterior piled
// against its bounds: three independent normals (sds 1, 2, 0.5, centred at 0) cut to x0 >=
// -0.2 and x1 <= 1 (0.2 and 0.5 sd from the centre; x2 free), the proposal the uncut
// Gaussian's own Laplace approximation, as a fit's is at a MAP near a bound. The chain's
// means and variances must be the cut normals' (brute-force integrals on a fine grid; 5 SE,
// file comment), with the box and without, and the box must raise the move's acceptance:
// without it, the t_5 proposal falls outside with probability ~0.5 and each such draw is a
// wasted update; inside, the proposal is the target's own shape (acceptance ~0.8, as on the
// uncut Gaussians above). Measured: 0.86 with the box, 0.33 without (max tau 3.1 and 7.0,
// 225 and 475 steps); required: above 0.6,
// and 1.5 times the acceptance without it.
TEST(EnsembleSampler, LaplaceMoveInsideABoxKeepsTheCutPosteriorAndIsAcceptedMore) {
  const double sd[3] = {1.0, 2.0, 0.5};
  const double lo[3] = {-0.2, -kInf, -kInf}, hi[3] = {kInf, 1.0, kInf};
  const LogDensity cut = [&](const double* x) {
    double log_p = 0.0;
    for (int k = 0; k < 3; ++k) {
      if (!(x[k] >= lo[k] && x[k] <= hi[k])) return -kInf;
      log_p -= 0.5 * x[k] * x[k] / (sd[k] * sd[k]);
    }
    return log_p;
  };
  // Mean and variance of N(0, s^2) cut to [a, b] by the midpoint rule on 2e5 intervals over
  // [max(a, -12 s), min(b, 12 s)] (error far below the 5 SE allowed).
  auto cut_moments = [](double s, double a, double b) {
    const double from = std::max(a, -12.0 * s), to = std::min(b, 12.0 * s);
    const int n = 200000;
    const double h = (to - from) / n;
    double m0 = 0.0, m1 = 0.0, m2 = 0.0;
    for (int i = 0; i < n; ++i) {
      const double x = from + (i + 0.5) * h, w = std::exp(-0.5 * x * x / (s * s));
      m0 += w;
      m1 += w * x;
      m2 += w * x * x;
    }
    return std::pair<double, double>{m1 / m0, m2 / m0 - (m1 / m0) * (m1 / m0)};
  };
  const int walkers = 16;
  std::mt19937_64 engine(5);
  std::vector<double> initial(walkers * 3);
  for (int w = 0; w < walkers; ++w) {
    initial[w * 3 + 0] = 0.3 + 0.1 * Uniform01(engine);
    initial[w * 3 + 1] = -0.3 + 0.1 * Uniform01(engine);
    initial[w * 3 + 2] = 0.1 * StandardNormal(engine);
  }
  SamplerOptions options = QuietOptions(41);
  options.independence_fraction = 0.6;
  options.independence_mean.assign(3, 0.0);
  options.independence_cholesky = {sd[0], 0.0, 0.0, 0.0, sd[1], 0.0, 0.0, 0.0, sd[2]};
  SamplerResult open, boxed;
  std::string error;
  ASSERT_TRUE(RunEnsembleSampler(PerThread(cut, 2), 3, initial, options, &open, &error)) << error;
  options.independence_lower.assign(lo, lo + 3);
  options.independence_upper.assign(hi, hi + 3);
  ASSERT_TRUE(RunEnsembleSampler(PerThread(cut, 2), 3, initial, options, &boxed, &error)) << error;
  for (const SamplerResult* r : {&open, &boxed}) {
    SCOPED_TRACE(r == &open ? "without the box" : "with the box");
    ASSERT_TRUE(r->converged) << r->stop_reason;
    for (int k = 0; k < 3; ++k) {
      const auto [mu, var] = cut_moments(sd[k], lo[k], hi[k]);
      const McEstimate m = Estimate(*r, [k](const double* x) { return x[k]; });
      EXPECT_NEAR(m.mean, mu, 5.0 * m.se) << "mean of parameter " << k;
      const McEstimate v = Estimate(*r, [k, mu = mu](const double* x) {
        return (x[k] - mu) * (x[k] - mu);
      });
      EXPECT_NEAR(v.mean, var, 5.0 * v.se) << "variance of parameter " << k;
    }
  }
  std::printf("cut Gaussian: independence acceptance %.2f with the box, %.2f without; "
              "max tau %.2f and %.2f, %d and %d steps\n",
              boxed.independence_acceptance, open.independence_acceptance, MaxTau(boxed),
              MaxTau(open), boxed.num_steps, open.num_steps);
  EXPECT_GT(boxed.independence_acceptance, 0.6);
  EXPECT_GT(boxed.independence_acceptance, 1.5 * open.independence_acceptance);
}

// A false return with a non-empty one-line message, and the result left alone.
void ExpectRejected(const std::vector<LogDensity>& f, int dim, const std::vector<double>& initial,
                    const SamplerOptions& options, const std::string& what) {
  SamplerResult r;
  r.num_steps = -7;
  std::string error;
  EXPECT_FALSE(RunEnsembleSampler(f, dim, initial, options, &r, &error)) << what;
  EXPECT_FALSE(error.empty()) << what;
  EXPECT_EQ(error.find('\n'), std::string::npos) << what << ": " << error;
  EXPECT_EQ(r.num_steps, -7) << what;
}

TEST(EnsembleSampler, RejectsBadInput) {
  const Gaussian g = Correlated2d();
  const std::vector<LogDensity> f = PerThread(g, 2);
  const SamplerOptions options = QuietOptions(18);
  const std::vector<double> good = InitialBall(g, 8, 0.0, 7);
  {
    SamplerResult r;
    std::string error;
    SamplerOptions short_run = options;
    short_run.max_steps = 5;
    EXPECT_TRUE(RunEnsembleSampler(f, 2, good, short_run, &r, &error)) << error;
  }
  ExpectRejected(f, 2, InitialBall(g, 7, 0.0, 7), options, "odd walker count");
  ExpectRejected(f, 2, InitialBall(g, 4, 0.0, 7), options, "4 walkers < 2 * 2 + 2");
  const LogDensity half_plane = [&g](const double* x) { return x[0] > 5.0 ? -kInf : g(x); };
  std::vector<double> one_outside = good;
  one_outside[3 * 2] = 6.0;
  ExpectRejected(PerThread(half_plane, 2), 2, one_outside, options, "-inf initial walker");
  const LogDensity nan_density = [](const double*) { return std::nan(""); };
  ExpectRejected(PerThread(nan_density, 2), 2, good, options, "NaN initial log-density");
  std::vector<double> ragged = good;
  ragged.push_back(0.0);
  ExpectRejected(f, 2, ragged, options, "initial size not a multiple of dim");
  ExpectRejected(f, 2, {}, options, "no walkers");
  ExpectRejected({}, 2, good, options, "no log-density");
  ExpectRejected({LogDensity()}, 2, good, options, "empty log-density function");
  ExpectRejected(f, 0, good, options, "dim 0");
  SamplerOptions bad = options;
  bad.stretch_a = 1.0;
  ExpectRejected(f, 2, good, bad, "stretch_a = 1");
  bad = options;
  bad.check_interval = 0;
  ExpectRejected(f, 2, good, bad, "check_interval = 0");
  bad = options;
  SetLaplaceMove(g, 1.5, 0.0, 1.0, &bad);
  ExpectRejected(f, 2, good, bad, "independence_fraction > 1");
  bad = options;
  SetLaplaceMove(g, 0.5, 0.0, 1.0, &bad);
  bad.independence_nu = 0;
  ExpectRejected(f, 2, good, bad, "independence_nu = 0");
  bad = options;
  SetLaplaceMove(g, 0.5, 0.0, 1.0, &bad);
  bad.independence_mean.pop_back();
  ExpectRejected(f, 2, good, bad, "independence_mean of the wrong size");
  bad = options;
  SetLaplaceMove(g, 0.5, 0.0, 1.0, &bad);
  bad.independence_cholesky.assign(3, 1.0);
  ExpectRejected(f, 2, good, bad, "independence_cholesky of the wrong size");
  bad = options;
  SetLaplaceMove(g, 0.5, 0.0, 1.0, &bad);
  bad.independence_cholesky[3] = 0.0;
  ExpectRejected(f, 2, good, bad, "a zero on the Cholesky diagonal");
  bad = options;
  SetLaplaceMove(g, 0.5, 0.0, 1.0, &bad);
  bad.independence_lower = {0.0, 0.0};
  ExpectRejected(f, 2, good, bad, "a box with lower bounds only");
  bad.independence_upper = {1.0, -1.0};
  ExpectRejected(f, 2, good, bad, "a box with an upper bound below its lower");
  bad.independence_upper = {1.0, NAN};
  ExpectRejected(f, 2, good, bad, "a box with a NaN bound");
  // All walkers on one line through the mean: the ensemble could never leave it.
  std::vector<double> line(good.size());
  for (int w = 0; w < 8; ++w) {
    line[w * 2] = 1.0 + 0.01 * w;
    line[w * 2 + 1] = -2.0 + 0.03 * w;
  }
  ExpectRejected(f, 2, line, options, "degenerate initial ensemble");
}

}  // namespace
}  // namespace ccdpsf::fit

namespace ccdpsf::fit {
namespace {

// A blocked target on the 5-D Gaussian: stretch moves on coordinates 0-2, and coordinates
// 3-4 updated by an independence Metropolis-Hastings move whose proposal is deliberately
// wrong (the exact conditional mean shifted by 0.3 sd, widths x 1.5, correlation ignored),
// so the moments come out right only if the acceptance ratio and the kept aux value (the
// current log-density, which the move reads instead of recomputing) are right.
BlockedTarget BlockedGaussian(const Gaussian& g, int threads) {
  const Eigen::MatrixXd s_ss = g.covariance.topLeftCorner(3, 3);
  const Eigen::MatrixXd s_cs = g.covariance.bottomLeftCorner(2, 3);
  const Eigen::MatrixXd gain = s_cs * s_ss.inverse();
  const Eigen::MatrixXd cond = g.covariance.bottomRightCorner(2, 2) - gain * s_cs.transpose();
  const double sd[2] = {std::sqrt(cond(0, 0)), std::sqrt(cond(1, 1))};
  BlockedTarget target;
  target.stretch_dim = 3;
  target.aux_dim = 1;
  for (int t = 0; t < threads; ++t) {
    target.log_density.push_back([g](const double* x, double* aux) {
      const double lp = g(x);
      if (aux != nullptr) aux[0] = lp;
      return lp;
    });
    target.conditional.push_back(
        [g, gain, sd](double* x, double* aux, double* log_prob, std::mt19937_64& engine) {
          const Eigen::Vector3d xs(x[0] - g.mean(0), x[1] - g.mean(1), x[2] - g.mean(2));
          const Eigen::Vector2d mean = g.mean.tail(2) + gain * xs;
          double proposal[5] = {x[0], x[1], x[2], 0.0, 0.0};
          double log_q_new = 0.0, log_q_old = 0.0;
          for (int i = 0; i < 2; ++i) {
            const double centre = mean(i) + 0.3 * sd[i], width = 1.5 * sd[i];
            const double z = StandardNormal(engine);
            proposal[3 + i] = centre + width * z;
            log_q_new += -0.5 * z * z;
            const double r = (x[3 + i] - centre) / width;
            log_q_old += -0.5 * r * r;
          }
          const double lp_new = g(proposal);
          if (std::log(Uniform01(engine)) < lp_new - aux[0] + log_q_old - log_q_new) {
            x[3] = proposal[3];
            x[4] = proposal[4];
            aux[0] = lp_new;
            *log_prob = lp_new;
            return 1.0;
          }
          return 0.0;
        });
  }
  return target;
}

// Samples the blocked 5-d Gaussian g (stretch block 0-2, conditional moves for the rest)
// with 16 walkers from `initial`, with two threads and with one: the first run converges
// with the right shapes, moments (5 SE) and stored log densities (which follow the
// conditional moves too), and the second's chain is bit-identical. Returns the first run.
SamplerResult RunBlockedAndCheck(const Gaussian& g, const std::vector<double>& initial,
                                 SamplerOptions options) {
  SamplerResult r;
  std::string error;
  EXPECT_TRUE(RunEnsembleSampler(BlockedGaussian(g, 2), 5, initial, options, &r, &error)) << error;
  ExpectConsistentShapes(r, 16, 5);
  EXPECT_TRUE(r.converged) << r.stop_reason;
  ExpectGaussianMoments(r, g);
  for (size_t s = 0; s < r.log_prob.size(); s += 997) {
    EXPECT_NEAR(r.log_prob[s], g(&r.chain[s * 5]), 1e-9 * (1.0 + std::fabs(r.log_prob[s])));
  }
  options.num_threads = 1;
  SamplerResult r1;
  EXPECT_TRUE(RunEnsembleSampler(BlockedGaussian(g, 1), 5, initial, options, &r1, &error)) << error;
  EXPECT_EQ(r1.chain, r.chain);
  EXPECT_EQ(r1.log_prob, r.log_prob);
  return r;
}

TEST(EnsembleSampler, BlockedTargetMomentsAndDeterminism) {
  const Gaussian g = Scaled5d();
  const int walkers = 16;  // >= 2 x 3 + 2 for the stretch block
  const SamplerResult r = RunBlockedAndCheck(g, InitialBall(g, walkers, 2.0, 5), QuietOptions(21));
  EXPECT_GT(r.conditional_acceptance, 0.2);
  EXPECT_LT(r.conditional_acceptance, 1.0);
}

// The independence move on the stretch block of a blocked target (coordinates 0-2, proposal
// from their marginal, slightly widened) beside the conditional moves of the rest: the
// moments (5 SE) and the stored log densities stay right, and the chain is bit-identical
// for one and two threads.
TEST(EnsembleSampler, BlockedTargetWithLaplaceMove) {
  const Gaussian g = Scaled5d();
  const Gaussian marginal(g.mean.head(3), g.covariance.topLeftCorner(3, 3));
  const int walkers = 16;
  const std::vector<double> initial = InitialBall(g, walkers, 2.0, 5);
  SamplerOptions options = QuietOptions(33);
  SetLaplaceMove(marginal, 0.6, 0.0, 1.2, &options);
  const SamplerResult r = RunBlockedAndCheck(g, initial, options);
  EXPECT_GT(r.independence_acceptance, 0.5);

  // A proposal of the wrong size for the stretch block (all five coordinates) is refused.
  SamplerResult r1;
  std::string error;
  SetLaplaceMove(g, 0.6, 0.0, 1.2, &options);
  EXPECT_FALSE(RunEnsembleSampler(BlockedGaussian(g, 1), 5, initial, options, &r1, &error));
  EXPECT_NE(error.find("independence"), std::string::npos) << error;
}

TEST(EnsembleSampler, BlockedTargetRejectsMissingConditional) {
  const Gaussian g = Scaled5d();
  BlockedTarget target = BlockedGaussian(g, 1);
  target.conditional.clear();
  SamplerResult r;
  std::string error;
  EXPECT_FALSE(
      RunEnsembleSampler(target, 5, InitialBall(g, 16, 0.0, 6), QuietOptions(1), &r, &error));
  EXPECT_NE(error.find("conditional"), std::string::npos) << error;
  target = BlockedGaussian(g, 1);
  EXPECT_FALSE(
      RunEnsembleSampler(target, 5, InitialBall(g, 6, 0.0, 6), QuietOptions(1), &r, &error));
  EXPECT_NE(error.find("walkers"), std::string::npos) << error;
}

}  // namespace
}  // namespace ccdpsf::fit
