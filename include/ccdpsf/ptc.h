// Photon transfer with pixel covariances (`ccdpsf ptc`): the gain [e-/ADU], the read noise
// [e-] and the boundary-shift coefficients a_ij [1/e-] of a CCD from flat-field pairs at
// several levels, by the model of Astier et al. 2019 (ptc_model.h).
//
// Frames pair as `ccdpsf gain` pairs them (photon_transfer_frames.h: the same exposure time,
// scene, WAVELEN and FOCUSPOS, and size). The bias level is required (option, BIASLVL, bias
// section or zero-second frames): the model is not linear in the level, so the level must
// be measured from zero. Each pair gives its mean level mu [ADU, bias subtracted] and the
// covariances C_ij [ADU^2] of its difference image at lags 0 <= i, j <= L
// (flat_covariance.h). A pair is left out when
//   - over 0.1 % of its pixels sit at a clipped black level (its noise is cut),
//   - its level's noise reaches the top: raw level + 3.1 sqrt(C_00) at or above the ceiling
//     less half an ADC step (over 0.1 % of its pixels would be clipped),
//   - its raw level lies above 90 % of the ADC's range (compression before full scale),
//   - fewer than 100 of its pixels are kept.
// The model C_ij(mu) = (K_ij(g mu; a, b) + n_ij) / g^2 (ptc_model.h) is fitted to all
// covariances of the pairs used at once by weighted least squares: the parameters are g, a_ij
// and n_ij [e-^2] for every lag (and b_ij [1/e-] with the "ab" model), the weights the inverse
// sampling variances of the estimates, C_00(mu)^2 / N_ij (2 C_00^2 / N_00 at lag 0), with
// C_00 the fitted model's (iterated to convergence, so that the weights do not follow the
// noise of the points). The minimum is found by Levenberg-Marquardt from a start made of
// weighted linear fits (C_00 = c0 + mu / g + a_00 mu^2; C_ij = n_ij / g^2 + a_ij mu^2), so
// it is deterministic. Parameter covariance: the inverse of J^T W J at the minimum, scaled by
// chi2 / dof when that exceeds 1 (points that scatter more than their counting errors).
// Derived: read noise RN = sqrt(n_00 - q g^2) [e-] (q: the ADC's rounding, ADU^2), given when
// RN^2 > 2 sd (else an upper bound); the sum of the a_ij over all lags within the range
// (each lag with its mirror images), which physics sets to 0 over all lags: far lags outside
// the range make it negative.
#ifndef CCDPSF_PTC_H_
#define CCDPSF_PTC_H_

#include <limits>
#include <string>
#include <vector>

#include "Eigen/Dense"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/flat_covariance.h"
#include "ccdpsf/photon_transfer_frames.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

enum class PtcModelKind { kA, kAB };  // "a" (b_ij = 0), "ab" (b_ij fitted)
const char* PtcModelName(PtcModelKind kind);
bool ParsePtcModel(const std::string& text, PtcModelKind* kind);

struct PtcOptions : TransferFrameOptions {
  int max_lag = 3;  // lags 0 <= i, j <= max_lag (1..8)
  PtcModelKind model = PtcModelKind::kA;

  bool IsValid(std::string* error) const;
};

// An estimate with its sd from the fit's covariance (NaN: not determined).
struct PtcValue {
  double value = std::numeric_limits<double>::quiet_NaN();
  double sd = std::numeric_limits<double>::quiet_NaN();
};

// One flat pair and what the fit made of it.
struct PtcPair {
  std::string first, second;  // the frames' names
  double exptime_s = std::numeric_limits<double>::quiet_NaN();
  FlatPairCovariance cov;
  bool used = false;
  std::string excluded_because;    // empty when used
  std::vector<double> model_adu2;  // per lag, the fitted model at the pair's level
  std::vector<double> sd_adu2;     // per lag, the sampling sd used as the weight
};

struct PtcResult {
  int max_lag = 3;
  PtcModelKind model = PtcModelKind::kA;
  PtcValue gain_e_per_adu;
  PtcValue read_noise_e;  // value NaN when not significant: then read_noise_upper_e
  double read_noise_upper_e = std::numeric_limits<double>::quiet_NaN();
  std::vector<std::string> lag_names;  // "00", "10", ... in lag order j * (L + 1) + i
  std::vector<PtcValue> a;             // [1/e-]
  std::vector<PtcValue> b;             // [1/e-]; empty with the "a" model
  std::vector<PtcValue> n;             // [e-^2]
  Eigen::MatrixXd a_covariance;        // [1/e-^2], lags x lags
  PtcValue a_sum;                      // [1/e-]
  double chi2 = 0.0;
  int dof = 0;
  double sd_scale = 1.0;  // sqrt(max(1, chi2 / dof)), applied to every sd
  int iterations = 0;
  double bias_adu = std::numeric_limits<double>::quiet_NaN();
  double bias_sd_adu = std::numeric_limits<double>::quiet_NaN();
  std::string bias_source;
  double rounding_adu2 = 0.0;
  int pairs_used = 0;
  double min_level_adu = 0.0, max_level_adu = 0.0;
  std::vector<PtcPair> pairs;
  std::vector<PtcFrameInfo> frames;
  std::vector<std::string> warnings;
  // The fitted parameters, for ModelAdu2.
  Eigen::VectorXd fitted_a, fitted_b, fitted_n;

  // The fitted model C_lag(mu) [ADU^2] at mean level mu [ADU].
  double ModelAdu2(int lag, double mu_adu) const;
};

// Measures and fits `frames` (names label them in messages; empty: "frame N"). False with a
// one-line reason when there is no estimate: options not valid, no bias level, fewer than 3
// usable pairs, or a fit that does not converge to a positive gain.
bool EstimatePtc(const std::vector<FitsImage>& frames, const std::vector<std::string>& names,
                 const PtcOptions& options, PtcResult* result, std::string* error);

// Reads each file with ReadFitsImage and calls the above.
bool EstimatePtcFromFiles(const std::vector<std::string>& paths, const PtcOptions& options,
                          PtcResult* result, std::string* error);

// ptc.json (docs/formats.md) and ptc.csv (one row per pair and lag).
nlohmann::json PtcJson(const PtcResult& result);
std::string PtcCsv(const PtcResult& result);

}  // namespace ccdpsf

#endif  // CCDPSF_PTC_H_
