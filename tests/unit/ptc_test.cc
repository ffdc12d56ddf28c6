// Photon transfer with pixel covariances (ptc_model.h, flat_covariance.h, ptc.h and
// `ccdpsf ptc`): the covariance model against a brute-force integration of its differential
// equation and against Astier et al.'s series, the covariance estimator on synthetic
// correlated noise of known covariance, and the whole analysis on flat pairs made by the
// independent reference sensor (tests/support/reference_sensor.py) with known a_ij.
#include "ccdpsf/ptc.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/flat_covariance.h"
#include "ccdpsf/photon_transfer_frames.h"
#include "ccdpsf/ptc_model.h"
#include "ccdpsf/random.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"
#include "support/slow_test.h"

namespace ccdpsf {
namespace {

using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::Shell;

// ---------------------------------------------------------------------------------------------
// Real-space lag grids for the independent references: a (2M + 1)^2 array of lags -M..M.

struct LagGrid {
  int m = 0;
  std::vector<double> v;
  explicit LagGrid(int m_in) : m(m_in), v((2 * m_in + 1) * (2 * m_in + 1), 0.0) {}
  double& at(int i, int j) { return v[(j + m) * (2 * m + 1) + (i + m)]; }
  double at(int i, int j) const {
    if (std::abs(i) > m || std::abs(j) > m) return 0.0;
    return v[(j + m) * (2 * m + 1) + (i + m)];
  }
};

// The mirror-symmetric grid of coefficients given for 0 <= i, j <= L in lag order.
LagGrid Mirror(const Eigen::VectorXd& c, int max_lag, int m) {
  LagGrid g(m);
  for (int j = 0; j <= max_lag; ++j) {
    for (int i = 0; i <= max_lag; ++i) {
      for (int sj : {-1, 1}) {
        for (int si : {-1, 1}) g.at(si * i, sj * j) = c(j * (max_lag + 1) + i);
      }
    }
  }
  return g;
}

// Discrete convolution on the grid (terms beyond it dropped).
LagGrid Convolve(const LagGrid& p, const LagGrid& q) {
  LagGrid out(p.m);
  const int m = p.m;
  for (int j = -m; j <= m; ++j) {
    for (int i = -m; i <= m; ++i) {
      double s = 0.0;
      for (int l = -q.m; l <= q.m; ++l) {
        for (int k = -q.m; k <= q.m; ++k) {
          const double qv = q.at(k, l);
          if (qv != 0.0) s += p.at(i - k, j - l) * qv;
        }
      }
      out.at(i, j) = s;
    }
  }
  return out;
}

LagGrid Combine(double x, const LagGrid& p, double y, const LagGrid& q) {
  LagGrid out(p.m);
  for (size_t k = 0; k < out.v.size(); ++k) out.v[k] = x * p.v[k] + y * q.v[k];
  return out;
}

// dK/dmu = 2 a(mu) (*) K + delta, a(mu) = a (1 + b mu) lag by lag (ab: the products a_ij
// b_ij), integrated from K(0) = 0 by fourth-order Runge-Kutta in `steps` steps on a grid of
// lags -m..m.
LagGrid IntegrateCovariance(const LagGrid& a, const LagGrid& ab, double mu, int steps, int m) {
  auto rate = [&](double t, const LagGrid& k) {
    LagGrid r = Combine(2.0, Convolve(k, a), 2.0 * t, Convolve(k, ab));
    r.at(0, 0) += 1.0;
    return r;
  };
  LagGrid k(m);
  const double h = mu / steps;
  for (int s = 0; s < steps; ++s) {
    const double t = s * h;
    const LagGrid k1 = rate(t, k);
    const LagGrid k2 = rate(t + 0.5 * h, Combine(1.0, k, 0.5 * h, k1));
    const LagGrid k3 = rate(t + 0.5 * h, Combine(1.0, k, 0.5 * h, k2));
    const LagGrid k4 = rate(t + h, Combine(1.0, k, h, k3));
    for (size_t n = 0; n < k.v.size(); ++n) {
      k.v[n] += h / 6.0 * (k1.v[n] + 2.0 * k2.v[n] + 2.0 * k3.v[n] + k4.v[n]);
    }
  }
  return k;
}

// Coefficients like a CCD's (the reference sensor's defaults, scaled): a_00 < 0, nearest
// neighbours a few 1e-7 per e-, falling with distance; max lag 2.
Eigen::VectorXd SensorLikeA(double scale) {
  Eigen::VectorXd a(9);
  // lag order (0,0) (1,0) (2,0) (0,1) (1,1) (2,1) (0,2) (1,2) (2,2)
  a << -1.3e-6, 1.7e-7, 1.6e-8, 2.5e-7, 3.2e-8, 9e-9, 2.6e-8, 1.2e-8, 5e-9;
  return a * scale;
}

// ---------------------------------------------------------------------------------------------
// The model

TEST(PtcModel, VarianceAloneIsAstiersExponential) {
  // With a_00 the only coefficient, a^(k) = a_00 at every frequency: K_00 = (exp(2 a_00 mu) - 1)
  // / (2 a_00) exactly (Astier et al. eq. 16) and every other lag 0. Checked at a_00 mu = -0.2
  // (the PTC 17 % below Poisson) and +0.05, to 1e-12 relative (rounding).
  PtcCovarianceModel model(2);
  const struct { double a00, mu; } cases[] = {{-1.3e-6, 0.2 / 1.3e-6}, {1e-6, 5e4}};
  for (const auto& c : cases) {
    Eigen::VectorXd a = Eigen::VectorXd::Zero(9);
    a(0) = c.a00;
    Eigen::VectorXd k;
    model.Evaluate(a, Eigen::VectorXd(), c.mu, &k, nullptr, nullptr, nullptr);
    const double want = std::expm1(2.0 * c.a00 * c.mu) / (2.0 * c.a00);
    EXPECT_NEAR(k(0), want, 1e-12 * want) << c.a00 * c.mu;
    for (int l = 1; l < 9; ++l) EXPECT_NEAR(k(l), 0.0, 1e-12 * want) << l;
  }
}

TEST(PtcModel, MatchesBruteForceIntegrationExactlyInA) {
  // b = 0: the model (closed form per frequency) against RK4 integration of the equation in
  // real space, 400 steps on lags -16..16, at a_00 mu = -0.26 (mu = 2e5 e-): far beyond the
  // range of a truncated series. The RK4 error (~(h |2 a^|)^4 ~ 1e-10 of K_00) and what is
  // lost off the grid (the 8th convolution power, ~(a mu)^8 / 8! ~ 5e-10, first reaches it)
  // are below the tolerance, 1e-9 of K_00 at every lag; the covariances at lags 1..2 are
  // 1e-2 .. 1e-4 of K_00, far above it.
  const int L = 2;
  const Eigen::VectorXd a = SensorLikeA(1.0);
  const double mu = 2e5;
  PtcCovarianceModel model(L);
  Eigen::VectorXd k;
  model.Evaluate(a, Eigen::VectorXd(), mu, &k, nullptr, nullptr, nullptr);
  const LagGrid brute = IntegrateCovariance(Mirror(a, L, 2), LagGrid(2), mu, 400, 16);
  for (int j = 0; j <= L; ++j) {
    for (int i = 0; i <= L; ++i) {
      EXPECT_NEAR(k(j * (L + 1) + i), brute.at(i, j), 1e-9 * brute.at(0, 0)) << i << j;
    }
  }
  // The a_ij leave their mark: K_10 is tens of thousands of sds of this tolerance from 0.
  EXPECT_GT(k(1), 1e-3 * k(0));
}

TEST(PtcModel, FirstOrderInB) {
  // With b: the model is exact in a and first order in b. Against the brute-force integration
  // (which is exact in both), the error must be of second order in b: it falls by 4 (3..5)
  // when b halves, and stays below 10 % of the b terms' contribution at b mu = 0.2.
  const int L = 2;
  const Eigen::VectorXd a = SensorLikeA(1.0);
  const double mu = 1e5;
  PtcCovarianceModel model(L);
  auto error_for = [&](double b_value, double* b_effect) {
    const Eigen::VectorXd b = Eigen::VectorXd::Constant(9, b_value);
    Eigen::VectorXd with_b, without_b;
    model.Evaluate(a, b, mu, &with_b, nullptr, nullptr, nullptr);
    model.Evaluate(a, Eigen::VectorXd(), mu, &without_b, nullptr, nullptr, nullptr);
    const LagGrid brute =
        IntegrateCovariance(Mirror(a, L, 2), Mirror(a.cwiseProduct(b), L, 2), mu, 400, 16);
    double worst = 0.0;
    *b_effect = 0.0;
    for (int l : {0, 1, 3, 4}) {
      const int i = l % 3, j = l / 3;
      worst = std::max(worst, std::fabs(with_b(l) - brute.at(i, j)));
      *b_effect = std::max(*b_effect, std::fabs(with_b(l) - without_b(l)));
    }
    return worst;
  };
  double effect = 0.0, effect_half = 0.0;
  const double e1 = error_for(2e-6, &effect);
  const double e2 = error_for(1e-6, &effect_half);
  EXPECT_LT(e1, 0.1 * effect);
  EXPECT_GT(e1 / e2, 3.0);
  EXPECT_LT(e1 / e2, 5.0);
}

TEST(PtcModel, SeriesIsAstiersEquation20) {
  // Astier et al. eq. (20) in electrons: K = mu [delta + a mu + 2/3 (a (*) a + ab) mu^2
  // + 1/6 (2 a (*) a (*) a + 5 a (*) ab) mu^3], computed here with explicit convolutions. At
  // mu = 2500 e- (|a^ mu| <= 0.008 at every frequency) and b mu = 0.1, the largest terms left
  // out of the series, 3/5 (a mu)^3 (b mu) mu and 2/15 (a mu)^4 mu, are < 4e-8 mu; the
  // tolerance is 1e-7 mu. The b terms (2/3 (a mu)(b mu) mu ~ 2e-4 mu, 5/6 (a mu)^2 (b mu) mu
  // ~ 5e-6 mu) and the a (*) a term (~3e-5 mu) are far above it.
  const int L = 2;
  const Eigen::VectorXd a = SensorLikeA(1.0);
  const double mu = 2500.0;
  const Eigen::VectorXd b = Eigen::VectorXd::Constant(9, 0.1 / mu);
  PtcCovarianceModel model(L);
  Eigen::VectorXd k;
  model.Evaluate(a, b, mu, &k, nullptr, nullptr, nullptr);
  const int m = 8;
  const LagGrid ga = Mirror(a, L, m), gab = Mirror(a.cwiseProduct(b), L, m);
  const LagGrid aa = Convolve(ga, ga), aaa = Convolve(aa, ga), a_ab = Convolve(ga, gab);
  for (int j = 0; j <= L; ++j) {
    for (int i = 0; i <= L; ++i) {
      const double series =
          mu * ((i == 0 && j == 0 ? 1.0 : 0.0) + ga.at(i, j) * mu +
                2.0 / 3.0 * (aa.at(i, j) + gab.at(i, j)) * mu * mu +
                1.0 / 6.0 * (2.0 * aaa.at(i, j) + 5.0 * a_ab.at(i, j)) * mu * mu * mu);
      EXPECT_NEAR(k(j * (L + 1) + i), series, 1e-7 * mu) << i << j;
    }
  }
}

TEST(PtcModel, DerivativesMatchFiniteDifferences) {
  // d K / d a_m, d K / d b_m and d K / d mu against central differences (steps 1e-4 of the
  // scale of each variable; the truncation error ~1e-8 relative), to 1e-6 of the largest
  // derivative in each column.
  const int L = 2;
  const Eigen::VectorXd a = SensorLikeA(1.5);
  const Eigen::VectorXd b = Eigen::VectorXd::Constant(9, 3e-7);
  const double mu = 1.2e5;
  PtcCovarianceModel model(L);
  Eigen::VectorXd k, dk_dmu;
  Eigen::MatrixXd dk_da, dk_db;
  model.Evaluate(a, b, mu, &k, &dk_da, &dk_db, &dk_dmu);
  auto check_column = [&](const Eigen::VectorXd& numeric, const Eigen::VectorXd& analytic,
                          const std::string& what) {
    const double scale = std::max(analytic.cwiseAbs().maxCoeff(), 1e-300);
    for (int l = 0; l < 9; ++l) EXPECT_NEAR(analytic(l), numeric(l), 1e-6 * scale) << what << l;
  };
  for (int m = 0; m < 9; ++m) {
    const double h = 1e-4 * 1e-6;
    Eigen::VectorXd up = a, down = a, kp, km;
    up(m) += h;
    down(m) -= h;
    model.Evaluate(up, b, mu, &kp, nullptr, nullptr, nullptr);
    model.Evaluate(down, b, mu, &km, nullptr, nullptr, nullptr);
    check_column((kp - km) / (2 * h), dk_da.col(m), "a" + std::to_string(m) + " lag ");
    Eigen::VectorXd bu = b, bd = b;
    bu(m) += 1e-4 * 3e-7;
    bd(m) -= 1e-4 * 3e-7;
    model.Evaluate(a, bu, mu, &kp, nullptr, nullptr, nullptr);
    model.Evaluate(a, bd, mu, &km, nullptr, nullptr, nullptr);
    check_column((kp - km) / (2e-4 * 3e-7), dk_db.col(m), "b" + std::to_string(m) + " lag ");
  }
  Eigen::VectorXd kp, km;
  model.Evaluate(a, b, mu * (1 + 1e-4), &kp, nullptr, nullptr, nullptr);
  model.Evaluate(a, b, mu * (1 - 1e-4), &km, nullptr, nullptr, nullptr);
  check_column((kp - km) / (2e-4 * mu), dk_dmu, "mu lag ");
}

TEST(PtcModel, SeriesAndClosedFormsAgreeAtTheirBoundary) {
  // f0 and h switch from series to closed form at |x| = 1: on both sides, against the closed
  // forms in long double (where the cancellation costs nothing at this x), to 1e-13; and their
  // derivatives against central differences of the functions, to 1e-8.
  for (double x : {-1.0000001, -0.9999999, -0.3, 1e-9, 0.0, 0.5, 0.9999999, 1.0000001, 2.5}) {
    double df0 = 0.0, dh = 0.0;
    const double f0 = PtcF0(x, &df0), h = PtcH(x, &dh);
    if (x != 0.0 && std::fabs(x) > 1e-6) {
      const long double lx = x;
      const long double e = std::exp(lx);
      EXPECT_NEAR(f0, static_cast<double>((e - 1) / lx), 1e-13) << x;
      EXPECT_NEAR(h, static_cast<double>(e / lx - 2 * (e - 1 - lx) / (lx * lx * lx)), 1e-12) << x;
    } else {
      EXPECT_NEAR(f0, 1.0 + x / 2, 1e-15);
      EXPECT_NEAR(h, 2.0 / 3.0 + 5.0 / 12.0 * x, 1e-15);
    }
    const double step = 1e-5;
    EXPECT_NEAR(df0, (PtcF0(x + step, nullptr) - PtcF0(x - step, nullptr)) / (2 * step), 1e-8) << x;
    EXPECT_NEAR(dh, (PtcH(x + step, nullptr) - PtcH(x - step, nullptr)) / (2 * step), 1e-8) << x;
  }
}

// ---------------------------------------------------------------------------------------------
// The covariance estimator

// A floating-point frame (no ADC rounding or limits) of nx x ny pixels.
FitsImage Frame(int nx, int ny) {
  FitsImage f;
  f.pixels = Image(nx, ny);
  f.bitpix = -64;
  return f;
}

TEST(FlatCovariance, RecoversTheCovarianceOfCorrelatedNoise) {
  // Two frames of 480 x 360 pixels: bias 500 + a fixed pattern (a 10 % gradient and 2 %
  // pixel response non-uniformity on 3000 ADU, the same in both) + independent noise f = w (*)
  // h, w white of sd 20 ADU, h = 1 at (0,0), 0.3 at (1,0), 0.15 at (0,1), 0.1 at (1,1). Its
  // covariance is C_l = 400 sum_x h_x h_(x+l): C_00 = 449, C_10 = 126, C_01 = 72, C_20 = 0, and
  // C_11 = 40 but C_1-1 = 18, so the estimator (which averages the mirror lags) must give 29.
  // Within 5 sds of the estimate; the sd is the estimator's white-noise formula (C_00 /
  // sqrt(N)) times 1.6: for this kernel the exact variance, (1/N) sum_m (C_m^2 + C_(m+l)
  // C_(m-l)), is at most 1.45^2 that of white noise. A hot pixel (in both frames) and a
  // cosmic ray (in one) are masked, as a defect and an outlier, and the mean is the level less
  // the bias.
  const int nx = 480, ny = 360;
  std::mt19937_64 engine(DeriveSeed(44, 1));
  std::vector<double> pattern(nx * ny);
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) {
      pattern[y * nx + x] =
          3000.0 * (1.0 + 0.1 * (x - nx / 2.0) / nx) * (1.0 + 0.02 * StandardNormal(engine));
    }
  }
  const double h[2][2] = {{1.0, 0.3}, {0.15, 0.1}};  // h[j][i]
  auto noise = [&]() {
    std::vector<double> w((nx + 1) * (ny + 1));
    for (double& v : w) v = 20.0 * StandardNormal(engine);
    std::vector<double> f(nx * ny, 0.0);
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        double s = 0.0;
        for (int j = 0; j <= 1; ++j) {
          for (int i = 0; i <= 1; ++i) s += h[j][i] * w[(y + 1 - j) * (nx + 1) + (x + 1 - i)];
        }
        f[y * nx + x] = s;
      }
    }
    return f;
  };
  FitsImage a = Frame(nx, ny), b = Frame(nx, ny);
  const std::vector<double> fa = noise(), fb = noise();
  double pattern_mean = 0.0;
  for (int k = 0; k < nx * ny; ++k) {
    a.pixels.data[k] = 500.0 + pattern[k] + fa[k];
    b.pixels.data[k] = 500.0 + pattern[k] + fb[k];
    pattern_mean += pattern[k];
  }
  pattern_mean /= nx * ny;
  a.pixels(100, 100) += 5000.0;  // hot pixel
  b.pixels(100, 100) += 5000.0;
  // A cosmic ray of 250 ADU in one frame: 8 sd of the difference, but under 2 sd of the
  // mean image's spread about its neighbours (the 2 % response pattern, ~60 ADU): an outlier
  // of the difference, not a defect.
  a.pixels(300, 200) += 250.0;
  const std::vector<FitsImage> frames = {a, b};  // the set points into these
  TransferFrameSet set;
  std::vector<std::string> warnings;
  std::string error;
  ASSERT_TRUE(PrepareTransferFrames(frames, {}, TransferFrameOptions(), &set, &warnings, &error))
      << error;
  const FlatPairCovariance c = MeasureFlatPair(set.frames[0], set.frames[1], 500.0, 2);
  EXPECT_GE(c.defects, 1);
  EXPECT_GE(c.outliers, 1);
  EXPECT_LT(c.defects + c.outliers, 20);
  EXPECT_NEAR(c.mean_adu, pattern_mean, 1.0);
  const double expected[3][3] = {{449.0, 126.0, 0.0}, {72.0, 29.0, 0.0}, {0.0, 0.0, 0.0}};
  for (int j = 0; j <= 2; ++j) {
    for (int i = 0; i <= 2; ++i) {
      const int l = j * 3 + i;
      const double sd = 1.6 * 449.0 * std::sqrt((l == 0 ? 2.0 : 1.0) / c.products[l]);
      EXPECT_NEAR(c.cov_adu2[l], expected[j][i], 5.0 * sd) << "lag " << i << j;
    }
  }
  // Mirror products double the count of the diagonal lags.
  EXPECT_GT(c.products[4], 1.9 * c.products[1]);
}

// ---------------------------------------------------------------------------------------------
// End to end on the reference sensor's flats

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

TEST(PtcReference, RecoversGainAndBoundaryShiftFromReferenceFlats) {
  CCDPSF_RELEASE_ONLY();  // the reference sensor's flats and a ptc run; the estimator runs
  // sanitized in FlatCovariance.*, the command in PtcCommand.BadInputIsOneLineAndNonZero
  // Flat pairs from the separate photon-shooting sensor (no ccdpsf code): 160 x 160 pixels, a
  // bias pair and 12 levels from 1e3 to 1.6e5 e- (geometric), gain 3.1 e-/ADU, read noise
  // 4.5 e-, 1 % PRNU and a 2 % gradient (cancelled by the differences), the default boundary
  // shift (a_00 = -1.28e-6, a_10 = 1.66e-7, a_01 = 2.55e-7, a_11 = 3.19e-8 per e-) collected
  // in 16 batches. The batches lag the charge by one, so the flats' covariances follow
  // a_ij (1 - 1/16) to first order (truth.json's factor): that is the truth compared with.
  // ptc must recover gain, read noise, a_00, a_10, a_01 and a_11 within 3 of its sds (a
  // failure by chance: < 0.3 % each); its sds must not be so large that the check is empty:
  // a_10 and a_01 are each measured to better than 25 %, the gain to 1 %. Over seeds 1-9 and
  // 44 of this set the pulls' rms was 0.6-1.3 and their means within 0.55 sd of 0.
  std::string why;
  if (Shell("/usr/bin/python3 -c 'import numpy, scipy, astropy'", &why) != 0) {
    GTEST_SKIP() << "/usr/bin/python3 with numpy, scipy and astropy makes the reference flats: "
                 << why;
  }
  const std::string dir = FreshDir("ptc", "reference");
  nlohmann::json levels = {0.0};
  for (int k = 0; k < 12; ++k) levels.push_back(1e3 * std::pow(160.0, k / 11.0));
  const nlohmann::json config = {
      {"seed", 44},
      {"detector",
       {{"gain_e_per_adu", 3.1},
        {"read_noise_e", 4.5},
        {"bias_adu", 1000},
        {"pixel_um", 12},
        {"saturation_adu", 65535},
        {"nx", 160},
        {"ny", 160}}},
      {"boundary_shift", {{"batches", 16}}},
      {"flats", {{"levels_e", levels}, {"prnu", 0.01}, {"gradient", {0.02, -0.01}}}}};
  {
    std::ofstream out(dir + "/config.json");
    out << config.dump(1);
  }
  std::string output;
  ASSERT_EQ(
      Shell("/usr/bin/python3 " + std::string(CCDPSF_SOURCE_DIR) +
                "/tests/support/reference_sensor.py " + dir + "/config.json " + dir + "/flats",
            &output),
      0)
      << output;
  const nlohmann::json truth = nlohmann::json::parse(ReadText(dir + "/flats/truth.json"));
  std::string files;
  for (const nlohmann::json& f : truth["flats"]) {
    files += " " + dir + "/flats/" + f["file"].get<std::string>();
  }
  ASSERT_EQ(RunCcdpsf("ptc --out=" + dir + "/ptc" + files, &output), 0) << output;
  const nlohmann::json ptc = nlohmann::json::parse(ReadText(dir + "/ptc/ptc.json"));
  const double factor = truth["boundary_shift"]["flat_batches_first_order_factor"];
  struct Check {
    std::string name;
    double truth, estimate, sd;
  };
  std::vector<Check> checks = {
      {"gain", 3.1, ptc["gain_e_per_adu"]["median"], ptc["gain_e_per_adu"]["sd"]},
      {"read_noise", 4.5, ptc["read_noise_e"]["median"], ptc["read_noise_e"]["sd"]}};
  for (const char* name : {"a_00", "a_10", "a_01", "a_11"}) {
    checks.push_back({name, truth["boundary_shift"]["a"][name].get<double>() * factor,
                      ptc["a"][name]["median"], ptc["a"][name]["sd"]});
  }
  for (const Check& c : checks) {
    const double pull = (c.estimate - c.truth) / c.sd;
    std::printf("  %-10s truth %.4g estimate %.4g sd %.2g pull %+.2f\n", c.name.c_str(), c.truth,
                c.estimate, c.sd, pull);
    EXPECT_LT(std::fabs(pull), 3.0) << c.name;
  }
  EXPECT_LT(ptc["a"]["a_10"]["sd"].get<double>(), 0.25 * checks[3].truth);
  EXPECT_LT(ptc["a"]["a_01"]["sd"].get<double>(), 0.25 * checks[4].truth);
  EXPECT_LT(ptc["gain_e_per_adu"]["sd"].get<double>(), 0.01 * 3.1);
  // The fit describes the points: chi2 within 4 sd of its dof.
  const double chi2 = ptc["fit"]["chi2"], dof = ptc["fit"]["dof"];
  EXPECT_LT(std::fabs(chi2 - dof), 4.0 * std::sqrt(2.0 * dof));
  // The report, the plots' data and the provenance are there.
  for (const char* f :
       {"report.md", "ptc.csv", "run.json", "ptc_variance.gp", "ptc_covariances.gp"}) {
    EXPECT_FALSE(ReadText(dir + "/ptc/" + f).empty()) << f;
  }
  EXPECT_EQ(ptc["a_covariance"]["names"].size(), 16u);
}

// ---------------------------------------------------------------------------------------------
// Errors

TEST(PtcCommand, BadInputIsOneLineAndNonZero) {
  const std::string dir = FreshDir("ptc", "errors");
  std::string output;
  // No --out, no files: usage errors (exit 2).
  EXPECT_EQ(RunCcdpsf("ptc " + dir + "/none.fits", &output), 2) << output;
  EXPECT_EQ(RunCcdpsf("ptc --out=" + dir + "/o", &output), 2) << output;
  // Options out of range: one line, exit 1, nothing written.
  for (const std::string& flag :
       {std::string("--max_lag=0"), std::string("--max_lag=9"), std::string("--ptc_model=abc")}) {
    EXPECT_EQ(RunCcdpsf("ptc --out=" + dir + "/o " + flag + " " + dir + "/x.fits", &output), 1)
        << flag;
    EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 1) << output;
  }
  EXPECT_EQ(RunCcdpsf("ptc --out=" + dir + "/o " + dir + "/missing.fits", &output), 1);
  EXPECT_NE(output.find("missing.fits"), std::string::npos) << output;
}

}  // namespace
}  // namespace ccdpsf
