// The pixel covariances of one flat-field pair at lags (i, j), 0 <= i, j <= L, from the
// pair's difference image (`ccdpsf ptc`, ptc.h).
//
// d = A - B cancels everything fixed between the two frames (the illumination pattern, pixel
// response non-uniformity, the bias structure), leaving twice the single-frame noise. Pixels
// left out (masked):
//   limits    either frame at or below its floor or at or above its ceiling
//             (photon_transfer_frames.h), or not finite;
//   defects   pixels unlike their neighbours in the pair's mean image m = (A + B) / 2 (hot,
//             dead or strongly non-uniform pixels, whose noise is not the flat's): the residual
//             r = m - (median of the 8 neighbours) beyond kFlatDefectSigma robust sds (1.4826
//             MAD) of r from its median. m and d are independent for Gaussian noise of equal
//             variance in A and B, so this choice does not bias d's statistics;
//   outliers  d beyond kTransferOutlierClipSigma sds of its mean (cosmic rays, a pixel that
//             changed between the frames), clipped iteratively.
// With v = d - mean(d) over the pixels kept,
//
//     C_ij = sum v(x) v(x + (i, j)) / (2 N_ij)   [ADU^2]
//
// over the N_ij pairs of kept pixels; for i, j > 0 the mirror lag (i, -j) is summed too (the
// model is mirror symmetric; this doubles the products). The sampling variance of C_ij under
// nearly white noise is C_00^2 / N_ij, and 2 C_00^2 / N_00 at lag 0 (each product of two
// independent normal differences of variance 2 C_00 has variance 4 C_00^2, of a square
// 8 C_00^2; the estimates at different lags are uncorrelated).
#ifndef CCDPSF_FLAT_COVARIANCE_H_
#define CCDPSF_FLAT_COVARIANCE_H_

#include <vector>

#include "ccdpsf/photon_transfer_frames.h"

namespace ccdpsf {

// Defects: beyond this many robust sds of the residual from the neighbours' median. Pure
// noise exceeds 6 sd in 2e-9 of pixels, so no pixel of a clean 4k x 4k frame is lost.
inline constexpr double kFlatDefectSigma = 6.0;

struct FlatPairCovariance {
  int max_lag = 0;
  double mean_adu = 0.0;    // (mean A + mean B) / 2 - bias over the kept pixels [ADU]
  double mean_a_adu = 0.0;  // each frame's mean - bias [ADU]
  double mean_b_adu = 0.0;
  double raw_mean_adu = 0.0;    // mean_adu + bias: where the ADC's limits are [ADU]
  long long region_pixels = 0;  // pixels of the shared data region
  long long kept = 0;
  long long at_floor = 0;    // region pixels at the floor in either frame
  long long at_ceiling = 0;  // at or above the ceiling in either frame
  long long not_finite = 0;
  long long defects = 0;
  long long outliers = 0;
  std::vector<double> cov_adu2;     // per lag, index j * (max_lag + 1) + i
  std::vector<long long> products;  // N_ij
};

// The covariances of the pair (a, b) (same size; their shared data region) for lags up to
// max_lag, with the bias level [ADU] subtracted for the means.
FlatPairCovariance MeasureFlatPair(const TransferFrame& a, const TransferFrame& b, double bias_adu,
                                   int max_lag);

}  // namespace ccdpsf

#endif  // CCDPSF_FLAT_COVARIANCE_H_
