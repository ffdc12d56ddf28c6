// The autocorrelation-time estimator against a brute-force autocorrelation function and
// against AR(1) processes, whose integrated time is known in closed form:
//
//   x_t = phi x_{t-1} + e_t,  e_t ~ N(0, 1)  =>  rho(t) = phi^t,  tau = (1 + phi) / (1 - phi).
//
// Tolerances for tau come from the estimator's own sampling error (Sokal 1996, section 3),
//   sd(tau_hat) ~= tau sqrt(2 (2 M + 1) / N),
// M the window the estimator chose and N the total number of values (independent chains
// add up). We allow 4 sd. The biases are much smaller and are neglected: the truncated tail
// 2 phi^(M+1) / (1 - phi) < 1e-3 for phi = 0.9 and M ~ 95; each chain's subtracted mean
// lowers every rho(t) by ~tau / n, so tau by ~(2 M + 1) / n relative: < 1 % (0.3 sd) for the
// shortest chains here (n = 20000). A replicate check (400 chains of 2^17 steps per phi, 200
// ensembles of 16 x 20000) found empirical sds 0.87-0.97 times the formula's and biases
// within 1 %: the formula is, if anything, conservative.
#include "ccdpsf/fit/autocorrelation.h"

#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <vector>

#include "ccdpsf/random.h"
#include "gtest/gtest.h"

namespace ccdpsf::fit {
namespace {

// A stationary AR(1) chain of unit innovations (x_0 drawn from the stationary law).
std::vector<double> Ar1(double phi, int n, std::mt19937_64& engine) {
  std::vector<double> x(n);
  x[0] = StandardNormal(engine) / std::sqrt(1.0 - phi * phi);
  for (int t = 1; t < n; ++t) x[t] = phi * x[t - 1] + StandardNormal(engine);
  return x;
}

double Ar1Tau(double phi) { return (1.0 + phi) / (1.0 - phi); }

// Sokal's sd of tau_hat for a window M and N values in all.
double TauSd(double tau, int window, double total_values) {
  return tau * std::sqrt(2.0 * (2.0 * window + 1.0) / total_values);
}

// rho(t) by the definition, O(n^2): (1/n) sum (x_s - m)(x_{s+t} - m), over lag 0.
std::vector<double> DirectAcf(const std::vector<double>& x) {
  const int n = static_cast<int>(x.size());
  double mean = 0.0;
  for (double v : x) mean += v;
  mean /= n;
  std::vector<double> c(n, 0.0);
  for (int t = 0; t < n; ++t) {
    for (int s = 0; s + t < n; ++s) c[t] += (x[s] - mean) * (x[s + t] - mean);
  }
  std::vector<double> rho(n);
  for (int t = 0; t < n; ++t) rho[t] = c[t] / c[0];
  return rho;
}

TEST(Autocorrelation, FftMatchesDirectSums) {
  std::mt19937_64 engine(DeriveSeed(1, 0));
  // Powers of two and not, so the zero padding is exercised both ways; 1e-12 is ~1e4 times
  // the rounding of an FFT of these lengths.
  for (int n : {2, 3, 37, 64, 100, 513}) {
    const std::vector<double> x = Ar1(0.7, n, engine);
    const std::vector<double> fft = AutocorrelationFunction(x);
    const std::vector<double> direct = DirectAcf(x);
    ASSERT_EQ(fft.size(), direct.size());
    for (int t = 0; t < n; ++t) EXPECT_NEAR(fft[t], direct[t], 1e-12) << "n " << n << " t " << t;
  }
}

TEST(Autocorrelation, EnsembleIsMeanOfWalkerFunctionsWithStridedLayout) {
  // Three walkers (an odd count: the last one goes through the FFT unpaired), two
  // parameters, stored as a sampler chain [(step * walkers + walker) * dim + k].
  const int n = 300, walkers = 3, dim = 2;
  std::mt19937_64 engine(DeriveSeed(2, 0));
  std::vector<std::vector<double>> series(walkers * dim);
  for (auto& s : series) s = Ar1(0.5, n, engine);
  std::vector<double> chain(n * walkers * dim);
  for (int t = 0; t < n; ++t) {
    for (int w = 0; w < walkers; ++w) {
      for (int k = 0; k < dim; ++k) chain[(t * walkers + w) * dim + k] = series[w * dim + k][t];
    }
  }
  for (int k = 0; k < dim; ++k) {
    const std::vector<double> ensemble =
        EnsembleAutocorrelationFunction(chain.data() + k, n, walkers, walkers * dim, dim);
    ASSERT_EQ(ensemble.size(), static_cast<size_t>(n));
    std::vector<double> mean(n, 0.0);
    for (int w = 0; w < walkers; ++w) {
      const std::vector<double> rho = DirectAcf(series[w * dim + k]);
      for (int t = 0; t < n; ++t) mean[t] += rho[t] / walkers;
    }
    for (int t = 0; t < n; ++t) EXPECT_NEAR(ensemble[t], mean[t], 1e-12) << "k " << k;
  }
}

TEST(Autocorrelation, Ar1SingleChainMatchesClosedForm) {
  const int n = 1 << 17;
  for (double phi : {0.0, 0.5, 0.9}) {
    std::mt19937_64 engine(DeriveSeed(3, static_cast<uint64_t>(phi * 10)));
    const std::optional<AutocorrelationTime> estimate =
        IntegratedAutocorrelationTime(Ar1(phi, n, engine));
    ASSERT_TRUE(estimate.has_value());
    ASSERT_TRUE(estimate->window_found);
    const double tau = Ar1Tau(phi);
    EXPECT_NEAR(estimate->tau, tau, 4.0 * TauSd(tau, estimate->window, n))
        << "phi " << phi << " window " << estimate->window;
    // The window is where M >= 5 tau first holds: about 5 tau.
    EXPECT_GE(estimate->window, 5.0 * estimate->tau);
    EXPECT_LT(estimate->window, 5.0 * tau * 1.5 + 2.0) << "phi " << phi;
  }
}

TEST(Autocorrelation, WhiteNoiseHasTauOne) {
  const int n = 100000;
  std::mt19937_64 engine(DeriveSeed(4, 0));
  std::vector<double> x(n);
  for (double& v : x) v = 3.0 + 2.0 * StandardNormal(engine);
  const std::optional<AutocorrelationTime> estimate = IntegratedAutocorrelationTime(x);
  ASSERT_TRUE(estimate.has_value());
  ASSERT_TRUE(estimate->window_found);
  // sd ~= sqrt(2 * 11 / 1e5) = 0.015 for M ~ 5.
  EXPECT_NEAR(estimate->tau, 1.0, 4.0 * TauSd(1.0, estimate->window, n));
  EXPECT_GE(estimate->window, 5);
  EXPECT_LE(estimate->window, 7);
  EXPECT_NEAR(EffectiveSampleSize(1, n, estimate->tau), n, 0.1 * n);
}

TEST(Autocorrelation, EnsembleAveragingAddsUpChainsAndIgnoresOffsetsAndScales) {
  // 16 independent AR(1) walkers of 20000 steps: the error of the ensemble estimate is that
  // of one chain of 16 x 20000 values, half that of the 2^17-step single chain above.
  const int n = 20000, walkers = 16;
  const double phi = 0.9;
  std::mt19937_64 engine(DeriveSeed(5, 0));
  std::vector<double> plain(n * walkers), shifted(n * walkers);
  for (int w = 0; w < walkers; ++w) {
    const std::vector<double> x = Ar1(phi, n, engine);
    for (int t = 0; t < n; ++t) {
      plain[t * walkers + w] = x[t];
      // Walkers sitting at different places, with different widths (as walkers still
      // spreading out would): per-walker normalisation must make this irrelevant.
      shifted[t * walkers + w] = 100.0 * w + (1.0 + w) * x[t];
    }
  }
  const std::optional<AutocorrelationTime> a =
      EnsembleIntegratedAutocorrelationTime(plain.data(), n, walkers, walkers, 1);
  const std::optional<AutocorrelationTime> b =
      EnsembleIntegratedAutocorrelationTime(shifted.data(), n, walkers, walkers, 1);
  ASSERT_TRUE(a.has_value() && b.has_value());
  ASSERT_TRUE(a->window_found);
  const double tau = Ar1Tau(phi);
  EXPECT_NEAR(a->tau, tau, 4.0 * TauSd(tau, a->window, static_cast<double>(n) * walkers));
  // Identical up to the rounding of adding offsets of up to 1500 to O(1) values.
  EXPECT_NEAR(b->tau, a->tau, 1e-9 * a->tau);
  EXPECT_EQ(b->window, a->window);

  // Pooling the walkers into one series instead would read the offsets as an enormous
  // correlation: the reason emcee, and this code, average per-walker functions.
  std::vector<double> pooled;
  for (int w = 0; w < walkers; ++w) {
    for (int t = 0; t < n; ++t) pooled.push_back(shifted[t * walkers + w]);
  }
  EXPECT_GT(IntegratedAutocorrelationTime(pooled)->tau, 10.0 * tau);
}

TEST(Autocorrelation, ConstantChainHasNoWindow) {
  const std::vector<double> x(50, 2.5);
  const std::vector<double> rho = AutocorrelationFunction(x);
  ASSERT_EQ(rho.size(), 50u);
  for (double r : rho) EXPECT_EQ(r, 1.0);
  const std::optional<AutocorrelationTime> estimate = IntegratedAutocorrelationTime(x);
  ASSERT_TRUE(estimate.has_value());
  EXPECT_FALSE(estimate->window_found);
  EXPECT_EQ(estimate->tau, 2.0 * 50 - 1.0);  // 1 + 2 * 49
}

TEST(Autocorrelation, DegenerateInputs) {
  EXPECT_TRUE(AutocorrelationFunction({}).empty());
  EXPECT_EQ(AutocorrelationFunction({1.0}).size(), 1u);
  EXPECT_FALSE(IntegratedAutocorrelationTime({}).has_value());
  EXPECT_FALSE(IntegratedAutocorrelationTime({1.0}).has_value());
  EXPECT_FALSE(IntegratedAutocorrelationTime({1.0, 2.0, 0.5}, 0.0).has_value());
  EXPECT_FALSE(IntegratedTimeFromAcf({1.0}).has_value());
  EXPECT_EQ(EffectiveSampleSize(32, 1000, 16.0), 2000.0);
  EXPECT_EQ(EffectiveSampleSize(32, 1000, std::numeric_limits<double>::infinity()), 0.0);
  EXPECT_EQ(EffectiveSampleSize(32, 1000, 0.0), 0.0);
}

}  // namespace
}  // namespace ccdpsf::fit
