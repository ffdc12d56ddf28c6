// Relations of a PSF metric with wavelength and intensity (paper section 4; docs/metrics.md,
// "Relations"), with uncertainties propagated from the posterior draws of each
// setting's fit, and the combined model of paper section 4.4.
//
//   power law (wavelength):  X(lambda) = a lambda^alpha               lambda in nm
//   linear (intensity):      X(I)      = intercept + slope I          I = peak pixel [e-]
//   combined (section 4.4):  X(I, lambda) = X(I) / X(I0) * X(lambda)  I0 = 157800 e-
//
// Input. A relation is fitted to points; each point is one setting (one joint fit of a
// group of exposures) with an abscissa x_i and the posterior draws of the metric X from that
// fit (any number per point), or, when draws are absent, a Gaussian given by its median and
// sd (flagged "gaussian_approximation"; in a power law's log space it enters as
// N(log median, (sd / median)^2), to first order). The abscissae (wavelength, intensity) are
// treated as EXACT: their errors (monochromator bandwidth, the spread of peak values within a
// setting) are not propagated. A point whose fit failed is passed with a reason: it is excluded and
// listed among the gaps.
//
// Method. Both relations are fitted as a straight line in a transformed space, about a
// pivot x0 (800 nm, 157800 e- by default) inside the data, which largely decorrelates the
// two coefficients (and, for intensity, scales u to order 1 for conditioning):
//
//   power law:  y = log X,  u = log(x / x0):      y = c0 + c1 u,  c1 = alpha,
//               a = exp(c0) x0^-alpha,  X(x0) = exp(c0)
//   linear:     y = X,      u = (x - x0) / x0:    y = c0 + c1 u,  slope = c1 / x0,
//               intercept = c0 - c1 (the value at I = 0, as the paper quotes it), X(x0) = c0
//
// Each point's weight is w_i = 1 / s_i^2 with s_i the sd of its draws in the fitted space
// (the sd of log X for the power law). The weights and the design matrix A = [1, u_i] are
// fixed, so the weighted least-squares solution is a fixed linear map of the data,
//
//   c = H y,   H = (A^T W A)^-1 A^T W.
//
// Propagation. The fit is repeated for R resamplings; resampling r takes one posterior draw
// per point (chosen uniformly, independently across points: the settings are separate fits)
// and gives c_r = H y_r. The coefficients (and a, intercept, X(x0) computed from each c_r) are
// summarised by the median and the central 68.27 % interval (the 15.87th and 84.13th
// percentiles, 1 sigma of a Gaussian, as fit.json's intervals) of that ensemble. No point
// estimate enters: skewed or non-Gaussian posteriors are carried through as they are. Since
// H is linear, Cov(c_r) = H Cov(y) H^T, which for W = Cov(y)^-1 is the textbook (A^T W A)^-1:
// for Gaussian posteriors the ensemble reproduces ordinary weighted least squares (tested).
// The log transform makes the power-law fit linear; for a posterior Gaussian in X of
// relative width s/X, log X is Gaussian to O((s/X)^2), and the draws are used as they are.
//
// It is very easy to read these intervals incorrectly: they are the uncertainty given the
// point errors, i.e. they assume the relation's form is right and the points scatter only
// as much as their posteriors say. The goodness of fit checks that:
//
//   chi^2 = sum_i ((y~_i - c0~ - c1~ u_i) / s_i)^2,  dof = n - 2,  p = Q(dof/2, chi^2/2)
//
// with y~_i the point medians (in the fitted space) and c~ the medians of the c0 and c1
// draws (the "median relation"; each reported coefficient's median is the median of its own
// draws, so median(a) need not equal exp(c0~) x0^-c1~ exactly when the draws are skewed). When
// p < 0.01 and chi^2/dof > 1 the fit is flagged "scatter_exceeds_errors" (the relation's form
// or the per-point errors are incomplete), and a second set of intervals, inflated by
// S = sqrt(chi^2/dof) (the Birge ratio / PDG scale factor: the draws c_r - c~ are scaled by S
// about the medians and a, intercept ... recomputed), is reported in `inflated`. The
// uninflated intervals stay the primary ones: inflation assumes the excess scatter is
// statistical and evenly shared among points, which nothing guarantees. `inflated` uses
// max(1, S) (never shrinks) and exists whenever dof >= 1.
//
// Flags (each with a human-readable reason):
//   not_fitted            fewer than 2 usable points, or all at one abscissa
//   poorly_constrained    dof <= 1 (the interval rests on the point errors alone and cannot
//                         be checked against the scatter); or the abscissa span is < 10 % of
//                         the pivot (short lever arm); or the 68 % half-width of alpha/slope
//                         or of X(x0) exceeds 50 % of |median|. (a and the intercept are
//                         extrapolations to lambda = 1 nm and I = 0: their relative width
//                         measures the lever arm, not how well the data fix the relation.)
//   scatter_exceeds_errors  see above
//   gaussian_approximation  some points had no draws (median/sd Gaussian used)
//   joint_points          points from one joint fit (RelationPoint::joint_set): resampled
//                         state by state, so the intervals are the joint posterior's; their
//                         medians lie on the fit's own curve (a line only if the model's is),
//                         so chi^2 measures its bend, not scatter: with one joint fit's
//                         points alone no scatter_exceeds_errors, inflation or dof flag
//
// Randomness: point k (k-th usable point, in input order) draws from its own
// std::mt19937_64 seeded with DeriveSeed(seed, k), so a result depends only on the usable
// points, the options and the seed; a gap is exactly equivalent to leaving the point out.
// The points of joint set s share one stream, seeded with DeriveSeed(DeriveSeed(seed,
// 2^64 - 1), s), that picks the state of each resampling.
#ifndef CCDPSF_TREND_RELATIONS_H_
#define CCDPSF_TREND_RELATIONS_H_

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "nlohmann/json.hpp"

namespace ccdpsf::trend {

// Default pivots: the paper's reference wavelength and intensity zero point I0.
constexpr double kReferenceWavelengthNm = 800.0;
constexpr double kReferenceIntensityE = 157800.0;

// Flag codes.
inline constexpr char kFlagNotFitted[] = "not_fitted";
inline constexpr char kFlagPoorlyConstrained[] = "poorly_constrained";
inline constexpr char kFlagScatterExceedsErrors[] = "scatter_exceeds_errors";
inline constexpr char kFlagGaussianApproximation[] = "gaussian_approximation";
inline constexpr char kFlagJointPoints[] = "joint_points";

// The metrics `ccdpsf trend` relates (docs/metrics.md; the fit's derived names).
const std::vector<std::string>& TrendMetricNames();

// Whether a metric describes the CCD kernel alone (every trend metric but the total_* ones,
// which hold the defocus too).
bool IsCcdOnlyMetric(const std::string& metric);

// A summary of draws: median, central 68.27 % interval (15.87th / 84.13th percentiles by
// linear interpolation between order statistics) and the sample sd. All NaN for no draws.
// A quantity's median, central 68.27 % and 95 % intervals and sd.
struct Estimate {
  double median = NAN;
  double lo68 = NAN;
  double hi68 = NAN;
  double lo95 = NAN;
  double hi95 = NAN;
  double sd = NAN;
};

// Non-finite draws are ignored.
Estimate SummarizeDraws(std::vector<double> draws);


enum class RelationKind {
  kPowerLaw,  // X = a x^alpha; x = wavelength [nm]
  kLinear,    // X = intercept + slope x; x = peak-pixel intensity [e-]
};

// "power_law" / "linear".
const char* RelationKindName(RelationKind kind);

// "<metric>_vs_wavelength" for kPowerLaw, "<metric>_vs_intensity" for kLinear (trend.json).
std::string RelationName(const std::string& metric, RelationKind kind);

// One setting's measurement of the metric.
struct RelationPoint {
  std::string label;          // names the setting in gaps, flags and reports (e.g. its folder)
  double abscissa = NAN;      // wavelength [nm] or peak-pixel intensity [e-]; treated as exact
  std::vector<double> draws;  // posterior draws of the metric (its fit's MCMC), in X's unit
  double median = NAN;        // used only when draws is empty: a Gaussian N(median, sd^2)
  double sd = NAN;
  // Non-empty: this setting is excluded from the fit and listed as a gap. Draws given with a
  // reason make a "bound only" gap (a measurement the data bound from above only): the gap
  // carries the 95th percentile of its finite draws as an upper limit.
  std::string missing_reason;
  // >= 0: the point is one of a joint fit's (e.g. the settings of an intensity series fitted
  // with the brighter-fatter slope): points with the same joint_set have draws from the same
  // posterior states, draw j of each from state j (equal counts, all finite), and a
  // resampling takes one state for all of them, so their correlation is carried through.
  // -1: an independent fit's point.
  int joint_set = -1;

  static RelationPoint FromDraws(std::string label, double abscissa, std::vector<double> draws);
  static RelationPoint FromGaussian(std::string label, double abscissa, double median,
                                    double sd);
  static RelationPoint Missing(std::string label, double abscissa, std::string reason);
  static RelationPoint BoundOnly(std::string label, double abscissa, std::string reason,
                                 std::vector<double> draws);
};

struct RelationOptions {
  // Resamplings R of the weighted fit (each one draw per point); >= 100. Monte-Carlo error
  // for a Gaussian coefficient of sd sigma: median 1.25 sigma / sqrt(R), a 68 % bound
  // 1.51 sigma / sqrt(R) (2.8 % and 3.4 % of sigma at R = 2000).
  int resamples = 2000;
  uint64_t seed = 1;
  // Pivot x0 in the abscissa's unit; NaN picks kReferenceWavelengthNm for kPowerLaw and
  // kReferenceIntensityE for kLinear. Must be > 0.
  double pivot = NAN;
  // poorly_constrained when (max x - min x) / x0 is below this.
  double min_relative_span = 0.1;
  // poorly_constrained when a shape coefficient's 68 % half-width / |median| exceeds this.
  double max_relative_half_width = 0.5;
  // scatter_exceeds_errors when the chi^2 p-value is below this (and chi^2/dof > 1).
  double scatter_p_value = 0.01;

  bool IsValid(std::string* error) const;
};

struct RelationFlag {
  std::string code;    // one of the kFlag... codes
  std::string reason;  // a sentence for people
};

// A usable point as the fit saw it.
struct PointSummary {
  std::string label;
  double abscissa = NAN;
  Estimate value;             // of X (for a Gaussian point: median, median -+ sd, sd)
  double fit_sd = NAN;        // s_i: sd in the fitted space (of log X for the power law)
  bool gaussian = false;      // true: no draws, N(median, sd^2) used
  int num_draws = 0;          // 0 for a Gaussian point
  double normalized_residual = NAN;  // (y~_i - median relation at x_i) / s_i
  // Where the fit sees the point: the mean of its draws in the fitted space, back in X's unit
  // (mean of X for a linear relation, exp(mean of log X) for a power law); the median for a
  // Gaussian point. The resampled weighted fit is centred on these, so the median relation
  // runs through them; with skewed draws they can differ from value.median.
  double fit_centre = NAN;
};

struct RelationGap {
  std::string label;
  double abscissa = NAN;
  std::string reason;
  // A bound-only point's 95th percentile of its draws, in X's unit (plotted as an upper
  // limit); NaN for a gap with no measurement.
  double upper_limit_95 = NAN;
};

struct Coefficient {
  std::string name;            // "a", "alpha", "intercept", "slope", "value_at_pivot"
  Estimate estimate;           // primary: from the resampling ensemble
  Estimate inflated;           // intervals with the draws scaled by max(1, sqrt(chi^2/dof));
                               // NaN when dof < 1 (sd scaled likewise)
  std::vector<double> draws;   // R draws, aligned across the coefficients of one relation
};

struct RelationFit {
  RelationKind kind = RelationKind::kPowerLaw;
  double pivot = NAN;
  int resamples = 0;
  uint64_t seed = 0;
  bool fitted = false;

  // kPowerLaw: a, alpha, value_at_pivot; kLinear: intercept, slope, value_at_pivot. Present
  // (with NaN estimates and no draws) even when not fitted.
  std::vector<Coefficient> coefficients;

  double chi2 = NAN;         // of the point medians about the median relation (dof >= 1)
  int dof = 0;               // usable points - 2 (0 when not fitted)
  double p_value = NAN;      // ChiSquareUpperTail(chi2, dof) (chi_square.h)
  double scale_factor = NAN;  // sqrt(chi2 / dof)

  std::vector<PointSummary> points;  // usable points, input order
  std::vector<RelationGap> gaps;     // excluded points, input order
  std::vector<RelationFlag> flags;

  // nullptr when absent.
  const Coefficient* Find(const std::string& name) const;
  bool HasFlag(const std::string& code) const;
  // Draws of X at abscissa x (draw r uses coefficient draw r); empty when not fitted.
  std::vector<double> ValueDraws(double x) const;
  // Smallest and largest usable abscissa (NaN without points).
  double MinAbscissa() const;
  double MaxAbscissa() const;
};

// Fits the relation. Returns nullopt (with a one-line reason) only for invalid options; too
// few or unusable points give a RelationFit with fitted = false and a not_fitted flag, so the
// caller can still report the gaps. Unusable points (listed as gaps): a missing_reason; a
// non-finite abscissa (or <= 0 for a power law); fewer than 2 finite draws and no valid
// Gaussian; draws with no spread; for a power law, any draw <= 0 (or a Gaussian median <= 0).
// Non-finite draws are dropped.
std::optional<RelationFit> FitRelation(RelationKind kind, const std::vector<RelationPoint>& points,
                                       const RelationOptions& options, std::string* error);

// trend.json's relation object: {"kind", "model", "abscissa", "pivot", <coefficient>:
// {"median", "lo68", "hi68", "sd"} ..., "inflated": {"scale_factor", <coefficient>: {...}} or
// null, "chi2", "dof", "chi2_per_dof", "p_value", "n_points", "points", "gaps", "flags",
// "resamples", "seed", "abscissa_errors"}. NaN becomes null.
nlohmann::json ToJson(const Estimate& estimate);
nlohmann::json ToJson(const RelationFit& fit);

// The combined model of paper section 4.4 at (intensity_e, wavelength_nm):
//
//   X_r(I, lambda) = X_I,r(I) / X_I,r(I0) * X_lambda,r(lambda)
//
// with draw r of the intensity relation paired with draw r of the wavelength relation (they
// are fitted to different settings, so independent; min(R_I, R_lambda) pairs are used). Like
// the paper, it assumes the intensity dependence does not change with wavelength and that
// the wavelength relation was measured at I0; at I = I0 the ratio is exactly 1 and
// `vs_intensity` may be nullptr. Notes say when (I, lambda) lies outside the fitted ranges.
struct CombinedValue {
  Estimate estimate;
  std::vector<double> draws;
  std::vector<std::string> notes;
};

// nullopt with a reason when a needed relation is absent or not fitted, has the wrong kind,
// X_I(I0) <= 0 on some draw, or the inputs are not finite (or lambda <= 0).
std::optional<CombinedValue> EvaluateCombined(const RelationFit* vs_intensity,
                                              const RelationFit& vs_wavelength,
                                              double intensity_e, double wavelength_nm,
                                              double reference_intensity_e, std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_RELATIONS_H_
