// The missing-effect workflow of `ccdpsf diagnose`: fit a baseline, find where it and the
// data disagree, name the catalogue effect that explains the disagreement, add it, refit,
// repeat until nothing significant is left.
//
// Each round, for the current model M (the baseline in round 0):
//   1. M's MAP (effect_fit.h) and its residual statistics with posterior predictive p-values
//      from simulations of M at its MAP (statistics.h).
//   2. Every catalogue effect not in M is either skipped with a reason, when the data cannot
//      identify it (see below), or fitted as M + effect (MAP from the current MAP with the
//      effect at 2-3 starting strengths, each also with a CCD width that sits at its bound
//      reset to the other axis's width: such a width is usually absorbing the missing
//      effect) and scored against M:
//        delta log L  = log L(M + effect) - log L(M), both at their MAP (>= 0; a fit that
//                       ends lower is counted as 0);
//        LR           = 2 delta log L, with a p-value from the chi-bar-square mixture of a
//                       likelihood-ratio test whose null value lies on the boundary of the
//                       prior: with b such parameters (a strength that cannot be negative)
//                       and f others, LR ~ sum_{i=0..b} C(b, i) 2^-b chi2_{i+f} (Self & Liang
//                       1987). A shape parameter that the null leaves undefined (a trail's
//                       length at zero trail, a halo's width at zero fraction) is counted in
//                       f: an approximation to the supremum over it (Davies' problem) that
//                       the clean-data benchmark checks;
//        delta BIC    = k ln(pixels) - LR (negative favours the effect);
//        log BF       = Laplace-approximate log Bayes factor with the catalogue's flat priors:
//                       delta log L + (k/2) ln 2 pi + 1/2 ln det Sigma_e - sum ln w_i + the log
//                       of the prior box's share of the Gaussian, over the effect's
//                       constrained parameters (Sigma_e their Laplace covariance, w_i their
//                       prior widths); unconstrained ones contribute 0.
//      An effect is significant when p < alpha / (number tested) (Bonferroni over the
//      catalogue) AND delta BIC < 0.
//      Model alternatives (alternatives.h: a pillbox defocus, a pixel response narrower than
//      the pixel) are candidates too, scored the same way (the pillbox, not nested, by delta
//      BIC < -10 alone). The significant candidate with the lowest delta BIC is adopted;
//      others significant within 6 of it are its rivals (signatures.h). A nonlinearity
//      must also lose the signal it implies where exposure times set the intensity: the
//      light per second must fall at high signal as its compression says (brighter-fatter,
//      which moves charge but keeps it, does not); if the data contradict that by more than
//      3 sd it is set aside, with the reason. Likewise a halo (a fixed share of the light)
//      or a background (a fixed level) whose fitted strength trends with the signal across
//      a multi-intensity set (> 4 sd, and by more than half its strength): that is a spot
//      broadening with signal. After a first adoption, a further candidate needs strong
//      evidence (delta BIC < kStrongDeltaBic = -6): a weaker one could not explain (rule (d)
//      below) and mostly absorbs the shape the adopted effect misses.
//   3. If one is adopted, M + it (already fitted) becomes the next round's model. After a
//      pillbox, whose renders cost 50 times a Gaussian's, the next round only reports the
//      statistics (predictive simulations without refits) and says how to go on.
// The loop stops when nothing is significant or after max_rounds rounds of testing; the last
// round then only reports the final model's statistics.
//
// Then the judgement ("unexplained" is an answer). Each adopted candidate A, adopted in round
// r, EXPLAINS when (a) every statistic flagged in round r (p < 1e-3) that A's signature moves
// (signatures.h; chi2_per_dof is in every signature) is back within noise (p >= 0.01) in the
// final model, (b) none of A's parameters sits at a prior bound, and (c) for brighter_fatter
// with a width trend measured (width_trend.h), the slope of the total width it implies agrees
// with the trend's within 3 sd, and (d) it was adopted on strong evidence (delta BIC below
// kStrongDeltaBic = -6). Otherwise A is PARTIAL (it helped without explaining), with
// the reason; with rivals it is AMBIGUOUS, with the data that would separate them. The data
// are EXPLAINED when the final model has no flagged statistic and nothing is partial;
// otherwise the flagged statistics say where the misfit is. Only candidates that explain are
// the diagnosis's named effects.
//
// Not identifiable, and therefore never claimed (the output says why):
//   defocus          in the baseline already; without it (baseline_defocus = false) only in
//                    pixel_centre sampling or with a pillbox: a Gaussian defocus convolved
//                    with the Gaussian CCD kernel is one Gaussian (docs/trust.md, single focus).
//   brighter_fatter  needs two or more intensities (IsMultiIntensity): at one intensity the
//                    slope is exactly a change of the CCD widths.
//   jitter           needs two or more exposures: one exposure's jitter is its CCD widths.
//   defocus_offset   integrated sampling: a shifted defocus kernel is exactly a shift of the
//                    spot (the fitted position absorbs it). In pixel_centre sampling it is
//                    tested (the 2015 F kernel moves, the Airy does not), but only with the
//                    defocus in the model.
// In pixel_centre sampling a model without the defocus leaves the 2015 code's defocus step
// out altogether (pixel_centre_renderer.cc), and "defocus" is tested.
//
// Weakly identified, and therefore reported with wide intervals:
//   brighter_fatter with the paper's Gaussian defocus in the model (integrated sampling): the
//                    slope is that of the CCD widths, whose split from the defocus is only
//                    identified through the slope itself. Measured (bench, five intensities
//                    1.5e5 to 3.7e4 e- peak, slope 4e-7 px/e-): named, chi2/dof 1.285 ->
//                    1.029, slopes 7.0e-7 +- 3.5e-7 (x) and 5.0e-7 +- 1.4e-7 (y), within 1 sd
//                    of the truth but 20-50 times wider than with the data in focus and no
//                    defocus in the baseline (4.04e-7 +- 6e-9). diagnose.json adds the slope
//                    of the total width (total_slope_*), the better-determined quantity.
#ifndef CCDPSF_DIAGNOSE_DIAGNOSE_H_
#define CCDPSF_DIAGNOSE_DIAGNOSE_H_

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/diagnose/alternatives.h"
#include "ccdpsf/diagnose/effect_fit.h"
#include "ccdpsf/diagnose/signatures.h"
#include "ccdpsf/diagnose/statistics.h"
#include "ccdpsf/diagnose/width_trend.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/quality.h"

namespace ccdpsf::diagnose {

enum class FluxChoice { kAuto, kShared, kPerExposure };

struct ThresholdOptions {
  // Strengths tried, weakest first, as multiples of the catalogue default (the realistic
  // strength) of the effect's strength parameter (capped at its prior's upper end). Several
  // effects are detected well below their realistic strength in bright data, hence the low end.
  std::vector<double> multiples = {1.0 / 16, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0};
  int num_simulations = 10;  // per strength
  double detection_rate = 0.8;  // "detected" = named in at least this share
  uint64_t seed = 7;
};

struct DiagnoseOptions {
  // The baseline: the paper's model (with defocus) by default.
  bool baseline_defocus = true;
  std::vector<model::EffectKind> baseline_effects;
  // kAuto: a flux per exposure for a multi-intensity set (IsMultiIntensity), else shared (the
  // paper's joint fit).
  FluxChoice flux = FluxChoice::kAuto;
  // The catalogue effects and model alternatives that may be adopted: exactly these, or,
  // when both are empty, every effect and every alternative.
  std::vector<model::EffectKind> candidates;
  std::vector<AlternativeKind> alternatives;
  int max_rounds = 3;
  double alpha = 0.01;  // family-wise false-claim rate per round (Bonferroni)
  PredictiveOptions predictive;
  EffectFitOptions fit;
  fit::MapOptions map;  // for the baseline's starting point (fit::FindMap)
  bool compute_thresholds = false;
  ThresholdOptions thresholds;
  // Called on the calling thread as the work advances, one line each (no newline): the
  // baseline fit, each round's predictive check and candidate tests with its verdict, each
  // detection-threshold study. Empty: silent.
  std::function<void(const std::string&)> progress;

  bool IsValid(std::string* error) const;
};

struct ParameterEstimate {
  std::string name;
  double map = NAN;
  double sd = NAN;  // Laplace; NaN when the data do not constrain it
  bool at_bound = false;
};

struct CandidateResult {
  model::EffectKind kind;  // for a catalogue effect (unused for a model alternative)
  std::optional<AlternativeKind> alternative;  // set for a model alternative (alternatives.h)
  std::string name;        // the catalogue effect's or the alternative's name
  bool nested = true;      // false: no LR test (pillbox_defocus), significant by delta BIC
  enum class Status { kTested, kNotIdentifiable, kInModel, kFitFailed };
  Status status = Status::kTested;
  std::string reason;  // for every status but kTested; for a tested one, why it was set
                       // aside despite its p-value (a contradicted nonlinearity)
  int num_parameters = 0;
  int boundary_parameters = 0;  // b of the chi-bar-square mixture
  double delta_log_likelihood = NAN;
  double lr = NAN;
  double p_value = NAN;
  double delta_bic = NAN;
  double log_bayes_factor = NAN;
  bool significant = false;
  std::vector<ParameterEstimate> parameters;  // the effect's, at the MAP of M + effect
  double chi2_per_dof = NAN;                  // of M + effect
  double seconds = 0.0;
};

std::string ToString(CandidateResult::Status status);

struct RoundResult {
  ModelSpec spec;
  std::vector<std::string> names;  // parameter names of the model
  std::vector<double> lower, upper;  // its prior range (the Ceres bounds)
  EffectFitResult fit;
  ResidualStatistics statistics;
  std::vector<std::vector<double>> predictive_draws;  // [statistic][simulation]
  bool tested = false;                  // false for a final round past the round limit
  std::vector<CandidateResult> candidates;
  int num_tested = 0;
  double p_threshold = NAN;  // alpha / num_tested
  std::optional<model::EffectKind> named;  // a catalogue effect adopted this round
  std::string adopted;  // the name of what was adopted (effect or alternative), empty if none
  // Other significant candidates within kAmbiguousDeltaBic of the adopted one (signatures.h).
  std::vector<std::string> rivals;
  std::string model_description;  // e.g. "baseline (pillbox defocus) + ipc"
  std::string verdict;  // one line
};

// The judgement on something the workflow added to the model (see the top of this file).
struct Attribution {
  std::string name;  // catalogue effect or model alternative
  int round = 0;     // where it was adopted
  enum class Status { kExplains, kPartial, kAmbiguous };
  Status status = Status::kExplains;
  std::string reason;  // partial / ambiguous: why, one line
  std::vector<std::string> rivals;  // ambiguous: the close candidates
  std::string separate_by;          // ambiguous: data that would tell them apart
  // Model alternatives: their parameter (pixel_response.width_px, defocus_radius_px).
  std::vector<ParameterEstimate> parameters;
};
std::string ToString(Attribution::Status status);

struct DetectionThreshold {
  model::EffectKind kind;
  std::string parameter;  // the strength parameter varied
  std::vector<double> strengths;  // as injected (clamped to the model's bounds)
  // Share of the simulations in which it was named, of those whose fits succeeded; the
  // failures per strength are counted in failed_fits (a rate is NaN if all failed).
  std::vector<double> rates;
  std::vector<int> failed_fits;
  double threshold = NAN;     // weakest strength with rate >= detection_rate (NaN: none)
  int num_simulations = 0;
};

struct DiagnoseResult {
  std::vector<RoundResult> rounds;
  std::vector<model::EffectKind> named;  // catalogue effects added to the model, in order
  // Everything added to the model (effects and alternatives), in order, with its judgement.
  std::vector<Attribution> attributions;
  // True when the final model leaves no statistic flagged and nothing added is partial.
  bool explained = false;
  // Where the final model still misfits: one line per flagged statistic.
  std::vector<std::string> unexplained;
  // The spot's width against its signal, exposure by exposure (width_trend.h); measured for
  // multi-intensity sets.
  WidthTrend width_trend;
  FluxMode flux = FluxMode::kShared;
  bool multi_intensity = false;
  std::vector<double> peak_e;  // per exposure (data)
  int jitter_reference = 0;
  bool round_limit_reached = false;
  std::vector<std::string> notes;
  bool thresholds_computed = false;
  std::vector<DetectionThreshold> thresholds;
  double seconds = 0.0;
  // The verdict on the data and the diagnosis (quality.h): calibration's findings, the set
  // checks', and the noise check (the baseline's chi^2: the tests assume the noise model).
  // Filled by the caller (the command), which knows how the data were read.
  Quality quality;
};

// The names of what explains the data (attributions with status kExplains), in order.
std::vector<std::string> ExplainingNames(const DiagnoseResult& result);
// One line: "no missing effect", "missing: halo", "unexplained: ...; partial: ipc; left in:
// core_z, chi2_per_dof".
std::string DiagnosisVerdict(const DiagnoseResult& result);

// Detection thresholds measured once by bench/diagnose_benchmark.cc --thresholds (section 3)
// on paper-like five-exposure sets, for reports whose own thresholds were not simulated: what
// such data detect, not what the data at hand detect. `threshold` is the weakest strength of
// the grid (1/64 to 16 times the catalogue default) named in >= 80 % of 10 simulations, with
// the decision rule of RunDiagnosis; NaN when none was; `weakest_tried` marks a threshold at
// the grid's lowest strength (the true one may be lower).
struct ReferenceThreshold {
  model::EffectKind kind;
  model::Sampling sampling;
  bool baseline_defocus;   // the baseline it was measured with
  std::string parameter;   // "<effect>.<parameter>"
  double threshold;
  bool weakest_tried;
  std::string conditions;  // the data set and baseline it was measured on
};
const std::vector<ReferenceThreshold>& ReferenceThresholds();

// The chi-bar-square tail probability P(LR >= lr) for b boundary and f free parameters.
double ChiBarSquarePValue(double lr, int boundary, int free);

// Runs the workflow on the stamps of `base` (its model options and priors are the baseline's;
// not through-focus). False with a one-line reason when the baseline cannot be fitted or the
// options are invalid.
bool RunDiagnosis(const fit::FitModel& base, const DiagnoseOptions& options,
                  DiagnoseResult* result, std::string* error);

// Detection threshold of `kind` for data like `base`'s: the model `spec` at `p` (a fitted
// point) with the effect added at each strength, simulated and diagnosed for that effect
// alone with the same decision rule (p < p_threshold and delta BIC < 0). Strengths are the
// options' multiples of the catalogue default, capped at the prior's upper end (a capped
// strength is tried once); the study stops at the first detected strength. False if `spec`
// already has `kind`.
// Caveat: each simulation's null fit starts at the truth, not from the global search
// RunDiagnosis makes, so where the null model has competing optima the threshold is
// optimistic. Measured case: pixel_centre defocus_offset, detected from 0.025 px here, while
// on a three-exposure set with a 0.1 px offset the baseline fit absorbs it in another optimum
// (Airy radius 0.25 instead of 0.47, positions moved) from which the offset is not recovered.
bool ComputeDetectionThreshold(const fit::FitModel& base, const ModelSpec& spec,
                               const std::vector<double>& p, model::EffectKind kind,
                               double p_threshold, const DiagnoseOptions& options,
                               DetectionThreshold* out, std::string* error);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_DIAGNOSE_H_
