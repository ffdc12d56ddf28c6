// Where a fitted model and the data disagree: normalised residuals stacked over exposures,
// targeted statistics that each catalogue effect would move, and posterior predictive
// p-values from simulations of the fitted model.
//
// Normalised residual of a valid pixel: r = (D - m) / sigma, sigma^2 the noise model's variance
// of the model's charge (effect_fit.h). Distances are taken from the exposure's fitted spot
// centre (dx = i - x_c, dy = j - y_c, rho = hypot(dx, dy) [px], stamp indices). The
// statistics (all dimensionless; "z" ones are sums of r divided by the square root of their
// count, so about N(0, 1) when the model is right and nothing was fitted to them):
//
//   chi2_per_dof      sum r^2 / (pixels - parameters); expected 1 +- sqrt(2 / dof)  (upper)
//   core_z            r summed over rho < 1.5 (peak deficit/excess: nonlinearity, ipc,
//                     brighter_fatter, halo)                                      (two-sided)
//   ring_z            1.5 <= rho < 4 (halo, jitter, ipc)                           (two-sided)
//   outer_z           rho >= 6: a residual pedestal (background; a halo's far wing) (two-sided)
//   odd_x_z           sign(dx) r over 0.5 <= |dx| <= 4.5, |dy| <= 4.5: the odd moment along x,
//                     a one-sided trail (serial_cti)                               (two-sided)
//   odd_y_z           the same along y (parallel_cti)                              (two-sided)
//   neighbour_z       the four edge neighbours of the peak pixel minus its four diagonal
//                     neighbours, / sqrt(8) per exposure (ipc)                     (two-sided)
//   peak_z            r of the peak pixel, summed over exposures / sqrt(K)         (two-sided)
//   peak_trend_z      the exposures' core_z against their intensity I_k (the fitted model's
//                     charge on the stamp, which unlike a peak pixel does not change with
//                     the spot's sub-pixel position): sum core_k (I_k - mean I) /
//                     sqrt(sum (I_k - mean I)^2): a peak deficit growing with intensity
//                     (brighter_fatter, nonlinearity); only with two or more intensities
//                     (intensity ratio > 1.25)                                   (two-sided)
//   width_scatter     per exposure the residual projected on (rho^2 - its mean) over rho < 4,
//                     normalised; their sum of squared deviations from the mean: widths that
//                     differ between exposures (jitter, brighter_fatter); K >= 2   (upper)
//   radial_chi2       sum over 1-px annuli (rho < 10) of (sum r)^2 / count: any radial
//                     structure (halo, background, defocus)                        (upper)
//
// The stacked images align every exposure on the pixel grid: the pixel nearest its fitted
// centre lands on the stack's centre pixel ((n - 1) / 2), with no interpolation (so the
// residual pattern is not smoothed); pixels shifted off the stamp are dropped. They are also
// stacked per intensity class (exposures sorted by their fitted intensity, the model's charge
// on the stamp; a class starts where it exceeds 1.25 x the lowest of the current class, the
// ratio that makes a set multi-intensity; a raw peak pixel varies by more than that with the
// spot's sub-pixel position alone), because an effect that grows with the signal (brighter_fatter,
// nonlinearity) leaves residuals of opposite sign at low and high intensity, which cancel in
// the stack of all exposures.
#ifndef CCDPSF_DIAGNOSE_STATISTICS_H_
#define CCDPSF_DIAGNOSE_STATISTICS_H_

#include <cstdint>
#include <string>
#include <vector>

#include "ccdpsf/diagnose/effect_fit.h"
#include "ccdpsf/image.h"

namespace ccdpsf::diagnose {

// One exposure's data, model and normalised residual at a fitted point (stamp-sized;
// masked pixels NaN in model and normalised).
struct ExposureResidual {
  Image data_e;
  Image model_e;
  Image normalised;
  std::vector<uint8_t> valid;
  double centre_x = 0.0;  // fitted spot centre in stamp indices [px]
  double centre_y = 0.0;
  double peak_e = 0.0;    // the model's largest pixel [e-]
  double flux_e = 0.0;    // the model's charge summed over the stamp [e-]: the exposure's
                          // intensity free of where the spot sits on the pixel grid
  int origin_x = 0;       // frame coordinates of stamp pixel (0, 0)
  int origin_y = 0;
};

// Residuals of every exposure at p, against `data_e` (one image per exposure) or the stamps.
std::vector<ExposureResidual> ComputeResiduals(const EffectModel& model,
                                               const std::vector<double>& p,
                                               const std::vector<Image>* data_e = nullptr);

enum class Tail { kTwoSided, kUpper };

struct NamedStatistic {
  std::string name;
  double value = 0.0;  // NaN when not defined for these data (e.g. one intensity)
  Tail tail = Tail::kTwoSided;
  // Predictive p-value (PredictiveCheck); NaN until computed.
  double p_value = NAN;
  std::string p_method;  // "simulations", "normal tail" or "chi2 distribution"
  // The predictive distribution's mean and sd (NaN until computed).
  double predictive_mean = NAN;
  double predictive_sd = NAN;
};

// The names in the order ComputeStatistics returns them, with a one-line description of what
// each measures and which effects move it.
const std::vector<std::pair<std::string, std::string>>& StatisticDescriptions();

// Exposures summed on the common grid described above; pixels no exposure reached are NaN.
struct ResidualStack {
  Image data, model, residual;  // sums [e-]; residual = data - model
  Image normalised;             // sum of normalised residuals / sqrt(count): N(0, 1) if right
  Image count;                  // how many exposures reached each pixel
};

// One intensity class's stack (peaks are the exposures' model peaks [e-]).
struct IntensityStack {
  double peak_min_e = 0.0, peak_max_e = 0.0;
  int exposures = 0;
  ResidualStack stack;
};

struct ResidualStatistics {
  double chi2 = 0.0;
  int dof = 0;
  double chi2_per_dof = 0.0;
  double chi2_per_dof_sd = 0.0;  // sqrt(2 / dof): the expected scatter of chi2_per_dof
  std::vector<NamedStatistic> values;
  // Every exposure's residuals stacked, aligned as above.
  ResidualStack stack;
  // The same per intensity class, lowest first (one class for a single-intensity set).
  std::vector<IntensityStack> by_intensity;
  // Mean normalised residual in 1-px annuli rho in [b, b + 1), b = 0..9, and the counts.
  std::vector<double> radial_mean, radial_count;
  std::vector<double> peak_e;  // per exposure: the model's peak pixel [e-]
  std::vector<double> flux_e;  // per exposure: the model's charge on the stamp [e-]
  std::vector<double> core_z;  // per exposure

  const NamedStatistic* Find(const std::string& name) const;
};

// The statistics of a set of residuals; `num_parameters` sets the dof of chi^2.
ResidualStatistics ComputeStatistics(const std::vector<ExposureResidual>& residuals,
                                     int num_parameters);

struct PredictiveOptions {
  int num_simulations = 50;
  uint64_t seed = 1;
  // Refit each simulated set (from the fitted point) before taking its statistics: the
  // predictive distribution then includes what fitting absorbs (a fitted position absorbs
  // most of an odd moment, for example), so the p-values are calibrated. Without refitting
  // the simulated residuals are taken against the fitted model itself, which makes the
  // p-values conservative for statistics the fit absorbs.
  bool refit = true;
  EffectFitOptions fit;
  // Simulations run this many at a time, each refit on one thread (fit.num_threads is not
  // used here), so the numbers do not depend on the thread count.
  int threads = 1;
};

// Simulates the model at `p` num_simulations times (SimulateData, noise only), computes the
// statistics of each, and fills p_value / predictive_mean / predictive_sd of *observed:
// upper tail p = (1 + #{sim >= obs}) / (1 + N); two-sided p = min(1, 2 min(upper, lower)).
// With N simulations such a p cannot go below 1 / (N + 1), so a clean set and a gross misfit
// would look alike: where fewer than 5 simulations reach the observed value, p comes from
// the tail of a normal with the simulations' mean and sd instead (p_method "normal tail"),
// and chi2_per_dof, whose distribution is known, always from the chi^2 distribution with its
// dof (p_method "chi2 distribution").
// `draws` (may be null) receives every simulation's values, [statistic][simulation].
void PredictiveCheck(const EffectModel& model, const std::vector<double>& p,
                     const PredictiveOptions& options, ResidualStatistics* observed,
                     std::vector<std::vector<double>>* draws = nullptr);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_STATISTICS_H_
