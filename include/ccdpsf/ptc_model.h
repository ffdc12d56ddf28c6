// The covariances of flat fields under pixel boundaries moved by collected charge: the model
// of Astier et al. 2019 ("The shape of the photon transfer curve of CCD sensors", A&A 629,
// A36), evaluated exactly in the a_ij and to first order in the b_ij.
//
// Physics (derived here; docs/formats.md and the ptc report repeat it). While a flat is
// collected, pixel x holds Q_x electrons and its area is A_x = 1 + sum_y a_{x-y}(Q) Q_y, where
// a_ij [1/e-] is the fractional area change of pixel (i, j) per electron in pixel (0, 0)
// (a_00 < 0: a charged pixel shrinks). Astier et al. let the coefficients depend on the
// charge, a_ij -> a_ij (1 + b_ij mu) (b_ij [1/e-]: boundaries not moving in proportion to the
// source charge). Under uniform light of mean level mu [e-] per pixel, the fluctuations
// dQ_x = Q_x - mu grow as d(dQ) = (a(mu) (*) dQ) dmu + Poisson noise (the mean area stays 1
// when the a_ij sum to 0; (*) is the discrete convolution over lags), so their covariance
// K_ij(mu) = <dQ_x dQ_{x+(i,j)}> [e-^2] obeys
//
//     dK/dmu = 2 a(mu) (*) K + delta_ij,     K(0) = 0.
//
// In Fourier space (k the spatial frequency, ^ the transform over lags) this is an ordinary
// equation per frequency. With alpha = a^(k), beta = (ab)^(k) (the transform of a_ij b_ij) and
// x = 2 alpha mu, its solution to first order in beta is
//
//     K^(k) = mu f0(x) + beta mu^3 h(x),
//     f0(x) = (e^x - 1) / x                 = sum_n x^n / (n + 1)!,
//     h(x)  = e^x / x - 2 (e^x - 1 - x) / x^3 = sum_n [1 / (n + 1)! - 2 / (n + 3)!] x^n.
//
// Expanded in powers of mu this is Astier et al.'s eq. (20): K = mu [delta + a mu
// + 2/3 (a (*) a + ab) mu^2 + 1/6 (2 a (*) a (*) a + 5 a (*) ab) mu^3 + ...] (checked term
// by term in tests/unit/ptc_test.cc); with b = 0 and a_00 alone, K_00 = (exp(2 a_00 mu) - 1) /
// (2 a_00), their eq. (16). Evaluated exactly (not truncated at mu^4), the model stays right
// at a_00 mu ~ -0.2 and beyond, where the truncated series errs by ~2 (a mu)^4 / 15.
//
// The model of a measured covariance [ADU^2] at the mean level mu [ADU] of a flat pair, with
// gain g [e-/ADU] and a constant n_ij [e-^2] (the read noise and the ADC's rounding at lag 0,
// correlated electronic noise elsewhere):
//
//     C_ij(mu) = (K_ij(g mu) + n_ij) / g^2.
//
// The a_ij and b_ij are taken mirror symmetric (a_{-i,j} = a_{i,-j} = a_ij, as a sensor
// symmetric about its column and row axes gives) and 0 beyond the lags 0 <= i, j <= L
// fitted. K is computed on a periodic grid of N = max(64, 16 L) pixels a side: the n-th
// convolution power of a reaches n L lags, so only the terms n > 8 wrap, and they weigh
// |x|^n / (n + 1)! < 1e-7 of K for |x| = |2 a^ mu| < 0.9 (a CCD at 2e5 e-: |x| ~ 0.85).
#ifndef CCDPSF_PTC_MODEL_H_
#define CCDPSF_PTC_MODEL_H_

#include <vector>

#include "Eigen/Dense"

namespace ccdpsf {

// K_ij(mu) of the equation above for lags 0 <= i, j <= max_lag, in the order
// j * (max_lag + 1) + i (a_10 is lag (1, 0): one column along x).
class PtcCovarianceModel {
 public:
  // a and b: (max_lag + 1)^2 values each, in lag order (b may be empty: all 0).
  explicit PtcCovarianceModel(int max_lag);

  int max_lag() const { return max_lag_; }
  int lags() const { return (max_lag_ + 1) * (max_lag_ + 1); }

  // K [e-^2] at mean level mu_e [e-] for every lag, and when the pointers are not null, its
  // derivatives: dk_da (lags x lags: d K_l / d a_m) and dk_db (the same for b), and dk_dmu
  // (d K_l / d mu_e).
  void Evaluate(const Eigen::VectorXd& a, const Eigen::VectorXd& b, double mu_e, Eigen::VectorXd* k,
                Eigen::MatrixXd* dk_da, Eigen::MatrixXd* dk_db, Eigen::VectorXd* dk_dmu) const;

 private:
  int max_lag_;
  // Over the frequencies (kx, ky), 0 <= kx, ky <= N / 2 (K^ is even in each), one row each:
  // forward_(k, l) = m_i m_j cos(2 pi kx i / N) cos(2 pi ky j / N) for lag l = (i, j), m the
  // multiplicity of a lag's mirror images (1 for 0, 2 otherwise), so that a^(k) =
  // forward_ a; inverse_(k, l) = w_kx w_ky cos(..) cos(..) / N^2, w the frequency's
  // multiplicity (1 for 0 and N / 2, 2 otherwise), so that K = inverse_^T K^.
  Eigen::MatrixXd forward_;
  Eigen::MatrixXd inverse_;
};

// f0(x) = (e^x - 1) / x and h(x) = e^x / x - 2 (e^x - 1 - x) / x^3 with their derivatives,
// by series for small |x| (no cancellation), closed forms otherwise.
double PtcF0(double x, double* derivative);
double PtcH(double x, double* derivative);

}  // namespace ccdpsf

#endif  // CCDPSF_PTC_MODEL_H_
