// The fit's findings (fit_quality.h).
#include "ccdpsf/fit/fit_quality.h"

#include <cmath>
#include <cstdio>

#include "ccdpsf/chi_square.h"
#include "ccdpsf/fit/pixel_likelihood.h"

namespace ccdpsf::fit {
namespace {

std::string Fmt(double v) {
  char text[48];
  std::snprintf(text, sizeof(text), "%.4g", v);
  return text;
}

// Standard normal quantile of an upper tail probability p (for the message only): solved
// by bisection on log Phi, which is accurate in the tails.
double UpperQuantile(double p) {
  double lo = 0.0, hi = 40.0;
  for (int i = 0; i < 200; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (LogNormalCdf(-mid) > std::log(p)) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return 0.5 * (lo + hi);
}

}  // namespace

void ExpectedChi2PerDofRange(int dof, double tail_p, double* low, double* high) {
  const double z = UpperQuantile(tail_p);
  const double sd = std::sqrt(2.0 / std::max(1, dof));
  *low = std::max(0.0, 1.0 - z * sd);
  *high = 1.0 + z * sd;
}

void AssessFit(const FitModel& model, const FitResult& r, const FitQualityOptions& options,
               Quality* quality) {
  AssessChi2(r.map.chi2, r.map.dof, options, quality);
  AssessIntervalsUnderMisfit(r, options, quality);
  AssessSampling(model, r, options, quality);
  AssessBounds(model, r, quality);
  // Censored pixels add no chi^2: one the model puts well on the wrong side of its level
  // (a saturated pixel predicted far below saturation) is a misfit of its own.
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  double worst = INFINITY;
  const int wrong = ev->CensoredViolations(r.map.theta.data(), options.censored_sd, &worst);
  if (wrong > 0) {
    quality->Add("censored_misfit", Severity::kSuspect,
                 std::to_string(wrong) + " censored (saturated or clipped) pixel(s) lie more than " +
                     Fmt(options.censored_sd) + " sd on the wrong side of their level under the "
                     "fitted model (worst " + Fmt(-worst) + " sd): the model does not describe "
                     "the core that the detector cut off");
  }
}

void AssessSampling(const FitModel& model, const FitResult& r, const FitQualityOptions& options,
                    Quality* quality) {
  // The largest share of an exposure's modelled light that falls in its brightest pixel.
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  std::vector<double> pixels;
  double worst = 0.0;
  for (int k = 0; k < model.num_exposures(); ++k) {
    if (!ev->ModelImage(r.map.theta.data(), k, &pixels, nullptr)) return;
    double sum = 0.0, peak = 0.0;
    for (double v : pixels) {
      sum += std::max(v, 0.0);
      peak = std::max(peak, v);
    }
    if (sum > 0.0) worst = std::max(worst, peak / sum);
  }
  if (!(worst > options.undersampled_peak_fraction)) return;
  char percent[16];
  std::snprintf(percent, sizeof percent, "%.0f", 100.0 * worst);
  quality->Add("undersampled", Severity::kNote,
               std::string(percent) +
                   " % of the spot's modelled light falls in one pixel: the widths then rest on "
                   "the assumed pixel response (the whole pixel, a box: FIT.json's "
                   "pixel_response_width) and sampling (" +
                   model::ToString(model.options().model.sampling) +
                   ") more than on the data; a narrower response or another sampling can move "
                   "them by more than their interval (docs/trust.md, Undersampled spots)");
}

void AssessIntervalsUnderMisfit(const FitResult& r, const FitQualityOptions& options,
                                Quality* quality) {
  if (!(r.map.dof >= 1) || !std::isfinite(r.map.chi2) ||
      !(ChiSquareUpperTail(r.map.chi2, r.map.dof) < options.chi2_tail_p)) {
    return;
  }
  // Where the misfit widens the uncertainty most: the largest sandwich / Laplace sd ratio.
  double worst = 0.0;
  std::string where;
  auto consider = [&](const std::string& name, const Summary& s) {
    const double ratio = s.sandwich_sd / s.laplace_sd;
    if (std::isfinite(ratio) && ratio > worst) {
      worst = ratio;
      where = name + " " + Fmt(s.laplace_sd) + " -> " + Fmt(s.sandwich_sd);
    }
  };
  for (size_t i = 0; i < r.parameters.size(); ++i) consider(r.names[i], r.parameters[i]);
  for (const auto& [name, s] : r.derived) consider(name, s);
  if (!(worst > 0.0)) return;
  quality->Add("intervals_assume_model", Severity::kNote,
               "the intervals assume the model, which chi2/dof = " +
                   Fmt(r.map.chi2 / r.map.dof) +
                   " rejects: the misspecification-robust (sandwich) sd is up to " + Fmt(worst) +
                   " times the Laplace sd (" + where + "; fit.json sandwich_sd)");
}

void AssessChi2(double chi2, int dof, const FitQualityOptions& options, Quality* quality) {
  if (dof >= 1 && std::isfinite(chi2)) {
    const double per_dof = chi2 / dof;
    double low = 0, high = 0;
    ExpectedChi2PerDofRange(dof, options.chi2_tail_p, &low, &high);
    const std::string range = "[" + Fmt(low) + ", " + Fmt(high) + "]";
    if (per_dof > options.gross_chi2_per_dof) {
      quality->Add("gross_misfit", Severity::kInvalid,
                   "chi2/dof = " + Fmt(per_dof) + " (expected " + range +
                       "): the model does not describe this source");
    } else if (ChiSquareUpperTail(chi2, dof) < options.chi2_tail_p) {
      char p[32];
      std::snprintf(p, sizeof(p), "%.2g", ChiSquareUpperTail(chi2, dof));
      quality->Add("chi2_high", Severity::kSuspect,
                   "chi2/dof = " + Fmt(per_dof) + " is above its expected range " + range +
                       " (p = " + p +
                       "): the model misses something in these data (`ccdpsf diagnose` looks "
                       "for what)");
    } else if (ChiSquareLowerTail(chi2, dof) < options.chi2_tail_p) {
      char p[32];
      std::snprintf(p, sizeof(p), "%.2g", ChiSquareLowerTail(chi2, dof));
      quality->Add("chi2_low", Severity::kSuspect,
                   "chi2/dof = " + Fmt(per_dof) + " is below its expected range " + range +
                       " (p = " + p +
                       "): the noise model overstates the noise (read noise or gain too large, "
                       "or clipped, quantised or smoothed data)");
    }
  }

}

// Whether theta index i is a fitted effect's parameter whose effect's strength (its first
// parameter, with a prior starting at 0, "no effect") is at zero or within 2 Laplace sd of it.
bool EffectConsistentWithZero(const FitModel& model, const FitResult& r, int i) {
  const int first = model.EffectsFirstIndex();
  if (first < 0 || i < first) return false;
  for (const FitEffect& e : model.options().effects) {
    const int start = model.EffectIndex(e.kind);
    const int size = model.EffectSize(e.kind);
    if (i < start || i >= start + size) continue;
    if (e.kind == model::EffectKind::kJitter) {
      // Each exposure's variance is its own strength.
      return r.map.theta[i] <= 0.0 || !std::isfinite(r.laplace.sd[i]) ||
             r.map.theta[i] < 2.0 * r.laplace.sd[i];
    }
    if (model.lower()[start] != 0.0) return false;
    const double strength = r.map.theta[start], sd = r.laplace.sd[start];
    return strength <= 0.0 || !(std::isfinite(sd)) || strength < 2.0 * sd;
  }
  return false;
}

void AssessBounds(const FitModel& model, const FitResult& r, Quality* quality) {
  // Parameters at prior bounds.
  const bool split_unidentified = model.options().model.sampling == model::Sampling::kIntegrated &&
                                  model.options().model.defocus == model::DefocusKind::kGaussian &&
                                  !model.through_focus();
  const std::vector<double>& lo = model.lower();
  const std::vector<double>& hi = model.upper();
  const std::vector<double>& theta = r.map.theta;
  int shape_at_bound = 0;
  for (int i : r.laplace.at_bound) {
    const std::string& name = r.names[i];
    const bool at_lower = theta[i] - lo[i] <= hi[i] - theta[i];
    const std::string where = name + " = " + Fmt(theta[i]) + " sits at its prior's " +
                              (at_lower ? "lower" : "upper") + " bound (" +
                              Fmt(at_lower ? lo[i] : hi[i]) + ")";
    const bool shape = i == kAiryRadiusPx || i == kDefocusPx || i == kCcdSigmaXPx ||
                       i == kCcdSigmaYPx;
    if (i == kDefocusPx && at_lower && split_unidentified) {
      // The unidentified split puts the MAP at zero defocus by construction.
      ++shape_at_bound;
      continue;
    }
    if (shape) ++shape_at_bound;
    if (EffectConsistentWithZero(model, r, i)) {
      // An effect's strength at zero is its "no effect" value: an upper limit, not a fault;
      // and its shape (a trail's length, a halo's width) is then not measured at all.
      quality->Add("effect_at_zero", Severity::kNote,
                   where +
                       ": the data show no sign of the effect (its strength is consistent "
                       "with zero), so this is an upper limit or unmeasured, not a fault");
      continue;
    }
    if ((i == kCcdSigmaXPx || i == kCcdSigmaYPx) && at_lower) {
      quality->Add("width_upper_limit", Severity::kSuspect,
                   where + ": the spot is narrower than the model resolves there, so the width "
                           "is only an upper limit");
    } else if ((i == kCcdSigmaXPx || i == kCcdSigmaYPx) && !at_lower) {
      quality->Add("width_at_upper_bound", Severity::kInvalid,
                   where + ": the source is broader than the model allows");
    } else {
      quality->Add("at_bound", Severity::kSuspect,
                   where + ": the prior cuts its interval there");
    }
  }
  if (shape_at_bound >= 4) {
    quality->Add("all_at_bounds", Severity::kInvalid,
                 "every shape parameter (Airy radius, defocus, CCD widths) sits at a prior "
                 "bound: the model does not describe this source");
  }
  if (r.have_mcmc && !r.chain.converged) {
    quality->Add("mcmc_not_converged", Severity::kSuspect,
                 "the MCMC did not converge (" + r.chain.stop_reason +
                     "): its intervals are not reliable");
  }
}

}  // namespace ccdpsf::fit
