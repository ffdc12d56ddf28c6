#include "ccdpsf/fit/fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "ccdpsf/fit/autocorrelation.h"
#include "ccdpsf/fit/posterior_target.h"
#include "ccdpsf/metrics.h"
#include "ccdpsf/random.h"
#include "internal/parallel_for.h"

namespace ccdpsf::fit {
namespace {

// Percentile by linear interpolation between order statistics (values sorted in place).
double Percentile(std::vector<double>& sorted, double q) {
  if (sorted.empty()) return NAN;
  const double pos = q * (sorted.size() - 1);
  const size_t lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(lo + 1, sorted.size() - 1);
  return sorted[lo] + (pos - lo) * (sorted[hi] - sorted[lo]);
}

// Index of the peak_e entry in DerivedNames().
constexpr size_t kPeakIndex = 10;

}  // namespace

std::vector<double> PeakTheta(const FitModel& model, const double* theta) {
  std::vector<double> out(theta, theta + model.dim());
  for (int k = 0; k < model.num_exposures(); ++k) {
    out[FitModel::XIndex(k)] = std::round(out[FitModel::XIndex(k)]);
    out[FitModel::YIndex(k)] = std::round(out[FitModel::YIndex(k)]);
  }
  if (model.through_focus()) out[kDefocusPx] = 0.0;
  return out;
}

void FillPosterior(std::vector<double> values, Summary* s) {
  values.erase(
      std::remove_if(values.begin(), values.end(), [](double v) { return !std::isfinite(v); }),
      values.end());
  std::sort(values.begin(), values.end());
  // 68.27 % and 99.73 % central intervals (1 and 3 sigma of a Gaussian).
  s->median = Percentile(values, 0.5);
  s->lo68 = Percentile(values, 0.158655);
  s->hi68 = Percentile(values, 0.841345);
  s->lo997 = Percentile(values, 0.00135);
  s->hi997 = Percentile(values, 0.99865);
}

const std::vector<std::string>& DerivedNames() {
  static const std::vector<std::string> names = {
      "fwhm_um",     "fwhm_x_um",        "fwhm_y_um",        "r2_px2",        "r2_arcsec2",
      "ellipticity", "total_sigma_x_px", "total_sigma_y_px", "total_fwhm_um", "total_ellipticity",
      "peak_e"};
  return names;
}

std::vector<double> DerivedAt(const FitModel& model, const double* theta) {
  const double pixel_um = model.stamps()[0].info.pixel_um;
  const PsfMetrics ccd = GaussianMetrics(theta[kCcdSigmaXPx], theta[kCcdSigmaYPx], pixel_um);
  // The identified (total) Gaussian widths: defocus and CCD widths in quadrature; a pillbox
  // of radius R contributes its second moment R^2 / 4 per axis. A through-focus fit
  // identifies the CCD widths themselves and has a defocus per exposure: its total widths
  // (and total_fwhm_um, total_ellipticity) are those at best focus, where the defocus is
  // zero, i.e. the CCD widths.
  const double d = model.through_focus() ? 0.0 : theta[kDefocusPx];
  const double d2 =
      model.options().model.defocus == model::DefocusKind::kGaussian ? d * d : d * d / 4;
  const double tx = std::sqrt(theta[kCcdSigmaXPx] * theta[kCcdSigmaXPx] + d2);
  const double ty = std::sqrt(theta[kCcdSigmaYPx] * theta[kCcdSigmaYPx] + d2);
  const PsfMetrics total = GaussianMetrics(tx, ty, pixel_um);
  std::vector<double> out = {ccd.fwhm_um,
                             ccd.fwhm_x_um,
                             ccd.fwhm_y_um,
                             ccd.r2_px2,
                             ccd.r2_arcsec2,
                             ccd.ellipticity,
                             tx,
                             ty,
                             total.fwhm_um,
                             total.ellipticity,
                             NAN};
  return out;
}

void LaplaceInterval68(double map, double sd, bool positive, double* lo, double* hi) {
  *lo = *hi = NAN;
  if (!std::isfinite(sd) || !std::isfinite(map)) return;
  if (positive && map > 0.0) {
    const double factor = std::exp(sd / map);
    *lo = map / factor;
    *hi = map * factor;
  } else {
    *lo = map - sd;
    *hi = map + sd;
  }
}

bool RunFit(const FitModel& model, const FitOptions& options, FitResult* result,
            std::string* error, const MapResult* map) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = FitResult();
  result->names = model.names();
  const int dim = model.dim();
  if (map != nullptr) {
    result->map = *map;
  } else if (!FindMap(model, options.map, &result->map, error)) {
    return false;
  }
  const std::vector<double>& theta_map = result->map.theta;

  std::unique_ptr<FitEvaluator> evaluator = model.NewEvaluator();
  // The likelihood's information, and the posterior's: with a Gaussian prior its precision is
  // added (gaussian_prior.h), so that the Laplace covariance and the sampler's seeds and
  // proposals are the posterior's.
  // The pixels' score outer products come from the same pass: the sandwich's meat below.
  std::vector<double> meat;
  const std::vector<double> fisher = evaluator->FisherInformation(theta_map.data(), &meat);
  const std::vector<double> information = model.PosteriorInformation(fisher);
  result->laplace = ComputeLaplace(model, theta_map, information);
  // The sandwich C M C: the meat is the scores' outer products plus the prior's precision
  // (information - fisher), so that it equals C where the model holds.
  LaplaceResult sandwich = result->laplace;
  {
    for (size_t e = 0; e < meat.size(); ++e) meat[e] += information[e] - fisher[e];
    const std::vector<double>& c = result->laplace.covariance;
    std::vector<double> cm(static_cast<size_t>(dim) * dim, 0.0);
    sandwich.covariance.assign(static_cast<size_t>(dim) * dim, 0.0);
    if (c.size() == cm.size()) {
      for (int a = 0; a < dim; ++a) {
        for (int k = 0; k < dim; ++k) {
          const double cak = c[a * dim + k];
          if (cak == 0.0) continue;
          for (int b = 0; b < dim; ++b) cm[a * dim + b] += cak * meat[k * dim + b];
        }
      }
      for (int a = 0; a < dim; ++a) {
        for (int k = 0; k < dim; ++k) {
          const double cmak = cm[a * dim + k];
          if (cmak == 0.0) continue;
          for (int b = 0; b < dim; ++b) sandwich.covariance[a * dim + b] += cmak * c[k * dim + b];
        }
      }
    }
    result->sandwich_covariance = sandwich.covariance;
  }
  if (model.gaussian_prior().active()) {
    result->data_alone = EstimateFromDataAlone(model, theta_map, fisher);
  }

  // The split of docs/trust.md (single focus) is exact here, whatever the curvature says: at a
  // MAP with zero defocus the model depends on the defocus only through its square, so the
  // Fisher matrix sees the defocus alone as free and would give the CCD widths a small sd,
  // although they trade against the defocus along the whole ridge. Their sds (and those of
  // everything computed from them, below) are withheld, and the degeneracy is named.
  const bool split_unidentified = CcdSplitUnidentified(model.options());
  if (split_unidentified) {
    LaplaceResult& lr = result->laplace;
    // Where the ridge ends: at zero defocus (the default prior), or inside a defocus prior
    // narrower than the physical range (a through-focus series' anchor, or a user's prior),
    // which then bounds the CCD widths.
    const double* box = model.options().priors.defocus_px;
    char bounded[200];
    std::snprintf(bounded, sizeof bounded,
                  "here the defocus prior [%.4g, %.4g] px bounds the ridge, so the CCD "
                  "widths' MCMC intervals are the ridge's stretch inside it",
                  box[0], box[1]);
    const std::string explanation =
        "defocus_sigma_px, ccd_sigma_x_px, ccd_sigma_y_px: the data do not constrain this "
        "combination at all (a Gaussian defocus and the Gaussian CCD kernel convolve to one "
        "Gaussian: only defocus^2 + ccd_sigma_x^2 and defocus^2 + ccd_sigma_y^2 are "
        "identified; see total_sigma_x_px / total_sigma_y_px; " +
        (box[0] <= 0.0
             ? std::string("here the MAP sits at zero defocus, where the ridge meets the bound "
                           "at right angles, so the local curvature sees the defocus alone)")
             : std::string(bounded) + ")");
    bool named = false;
    UnconstrainedDirection* defocus_only = nullptr;
    for (UnconstrainedDirection& d : lr.unconstrained) {
      named = named || d.description.find("convolve to one Gaussian") != std::string::npos;
      if (d.direction[kDefocusPx] != 0.0) defocus_only = &d;
    }
    if (!named && defocus_only != nullptr) {
      defocus_only->description = explanation;
    } else if (!named) {
      UnconstrainedDirection d;
      d.direction.assign(dim, 0.0);
      d.direction[kDefocusPx] = 1.0;
      d.sd_fraction_of_prior = INFINITY;
      d.description = explanation;
      lr.unconstrained.push_back(d);
    }
    for (int i : {static_cast<int>(kDefocusPx), static_cast<int>(kCcdSigmaXPx),
                  static_cast<int>(kCcdSigmaYPx)}) {
      lr.sd[i] = NAN;
      lr.constrained[i] = false;
    }
  }

  // MAP and Laplace for the parameters.
  result->parameters.resize(dim);
  for (int i = 0; i < dim; ++i) {
    result->parameters[i].map = theta_map[i];
    result->parameters[i].laplace_sd = result->laplace.sd[i];
    const double v = sandwich.covariance.empty() ? NAN : sandwich.covariance[i * dim + i];
    result->parameters[i].sandwich_sd =
        std::isfinite(result->laplace.sd[i]) && v >= 0.0 ? std::sqrt(v) : NAN;
  }
  // ... and for the derived quantities (delta method with a numerical gradient; peak_e from
  // the model Jacobian at the brightest pixel of each exposure, averaged).
  const std::vector<std::string>& dnames = DerivedNames();
  const std::vector<double> d_map = DerivedAt(model, theta_map.data());
  result->derived.resize(dnames.size());
  for (size_t j = 0; j < dnames.size(); ++j) {
    result->derived[j].first = dnames[j];
    result->derived[j].second.map = d_map[j];
  }
  for (size_t j = 0; j < dnames.size(); ++j) {
    if (j == kPeakIndex) continue;
    std::vector<double> grad(dim, 0.0), tp = theta_map, tm = theta_map;
    for (int i = 0; i < dim; ++i) {
      const double h = 1e-6 * (model.upper()[i] - model.lower()[i]);
      tp[i] = theta_map[i] + h;
      tm[i] = theta_map[i] - h;
      grad[i] = (DerivedAt(model, tp.data())[j] - DerivedAt(model, tm.data())[j]) / (2 * h);
      tp[i] = tm[i] = theta_map[i];
    }
    result->derived[j].second.laplace_sd = DerivedSd(result->laplace, grad);
    result->derived[j].second.sandwich_sd = DerivedSd(sandwich, grad);
    // The CCD-only metrics (the first six) depend on the unidentified split.
    if (split_unidentified && j < 6) {
      result->derived[j].second.laplace_sd = result->derived[j].second.sandwich_sd = NAN;
    }
  }
  {
    std::vector<double> pixels, jac, grad(dim, 0.0);
    double peak = 0.0;
    const std::vector<double> at = PeakTheta(model, theta_map.data());
    for (int k = 0; k < model.num_exposures(); ++k) {
      evaluator->ModelImage(at.data(), k, &pixels, &jac);
      const size_t q = std::max_element(pixels.begin(), pixels.end()) - pixels.begin();
      peak += pixels[q] / model.num_exposures();
      for (int i = 0; i < dim; ++i) grad[i] += jac[q * dim + i] / model.num_exposures();
    }
    // The centred spot's peak does not depend on the positions, nor at best focus on the
    // defocus rate or the best focus.
    for (int k = 0; k < model.num_exposures(); ++k) {
      grad[FitModel::XIndex(k)] = grad[FitModel::YIndex(k)] = 0.0;
    }
    if (model.through_focus()) grad[kDefocusPx] = grad[model.FocusIndex()] = 0.0;
    result->derived[kPeakIndex].second.map = peak;
    result->derived[kPeakIndex].second.laplace_sd = DerivedSd(result->laplace, grad);
    result->derived[kPeakIndex].second.sandwich_sd = DerivedSd(sandwich, grad);
  }

  if (options.run_mcmc) {
    // The sampler walks the state of posterior_target.h (total widths, the defocus integrated
    // out where the data cannot see it, positions by conditional moves in joint fits), seeded
    // from the Laplace approximation in those coordinates.
    const PosteriorTarget target(model, theta_map, information, options.target);
    // Default walkers: the sampler stops when the chain is min_tau_multiple taus long AND
    // every ESS = walkers x steps / tau reaches target_ess; with target_ess / min_tau_multiple
    // walkers (20 by default) both are met at once, and more walkers only add evaluations.
    // The stretch move needs at least 2 x its dimension + 2.
    int walkers = options.num_walkers;
    if (walkers <= 0) {
      walkers = std::max(2 * target.stretch_dim() + 2,
                         static_cast<int>(std::ceil(options.mcmc.target_ess /
                                                    std::max(1.0, options.mcmc.min_tau_multiple))));
    }
    walkers += walkers % 2;
    std::mt19937_64 engine(DeriveSeed(options.mcmc.seed, 0xC0FFEEULL));
    std::vector<double> initial;
    {
      FitEvaluator* ev = evaluator.get();
      auto density = [&target, ev](const double* state) {
        return target.LogDensity(ev, state, nullptr);
      };
      if (!SeedWalkers(target.laplace(), target.state_map(), walkers, engine, density, &initial,
                       error)) {
        return false;
      }
    }
    const int threads = std::max(1, options.mcmc.num_threads);
    std::vector<std::unique_ptr<FitEvaluator>> evaluators;
    std::vector<FitEvaluator*> evaluator_ptrs;
    for (int t = 0; t < threads; ++t) {
      evaluators.push_back(model.NewEvaluator());
      evaluator_ptrs.push_back(evaluators.back().get());
    }
    // The Laplace-informed independence move (ensemble_sampler.h), where the Laplace
    // covariance of the stretch block is available; otherwise the stretch moves alone.
    SamplerOptions mcmc = options.mcmc;
    mcmc.independence_fraction = 0.0;
    if (options.target.laplace_move_fraction > 0.0 &&
        target.LaplaceProposal(options.target.laplace_move_scale, &mcmc.independence_mean,
                               &mcmc.independence_cholesky)) {
      mcmc.independence_fraction = options.target.laplace_move_fraction;
      target.ProposalBox(&mcmc.independence_lower, &mcmc.independence_upper);
    }
    // The reported parameters of stored state `index`; where the defocus is integrated out,
    // it is drawn from its exact conditional with a uniform fixed by the index, so that the
    // sampler's convergence check and the chain written here see the same values.
    const uint64_t defocus_seed = DeriveSeed(options.mcmc.seed, 0xDEF0C05ULL);
    auto to_theta = [&target, defocus_seed](size_t index, const double* state, double* theta) {
      const double u =
          target.marginal_defocus()
              ? (static_cast<double>(DeriveSeed(defocus_seed, index) >> 11) + 0.5) * 0x1.0p-53
              : 0.0;
      target.ToTheta(state, u, theta);
    };
    // Resume (--resume): a checkpoint's stored log densities include the Gaussian prior's
    // log density; it is taken up only by the run that wrote it, whose fingerprint covers the
    // walkers' initial positions (ensemble_sampler.cc), drawn around the posterior's MAP from
    // its Laplace approximation, both of which a different prior moves.
    mcmc.reported = to_theta;
    mcmc.reported_dim = dim;
    if (!RunEnsembleSampler(target.Make(evaluator_ptrs), target.dim(), initial, mcmc,
                            &result->chain, error)) {
      return false;
    }
    // Back to the fit parameters (the defocus drawn from its exact conditional where it was
    // integrated out): the reported quantities, which the sampler computed once per state for
    // its convergence checks.
    SamplerResult& chain = result->chain;
    chain.chain = std::move(chain.reported);
    chain.reported.clear();
    chain.dim = dim;
    chain.tau.assign(dim, INFINITY);
    chain.ess.assign(dim, 0.0);
    // Their tau and ESS for the report: the same values the sampler's convergence check
    // judged (SamplerOptions::reported), so no second verdict is needed here.
    const int kept_steps = chain.num_steps - chain.burn_in;
    if (kept_steps >= 2) {
      for (int i = 0; i < dim; ++i) {
        const auto t = EnsembleIntegratedAutocorrelationTime(
            chain.chain.data() + static_cast<size_t>(chain.burn_in) * chain.num_walkers * dim + i,
            kept_steps, chain.num_walkers, static_cast<std::ptrdiff_t>(chain.num_walkers) * dim,
            dim);
        chain.tau[i] = t ? t->tau : INFINITY;
        chain.ess[i] = EffectiveSampleSize(chain.num_walkers, kept_steps, chain.tau[i]);
      }
    }
    result->have_mcmc = true;
    const SamplerResult& c = result->chain;
    const int kept = c.num_steps - c.burn_in;
    if (kept <= 0) {
      *error = "the MCMC chain has no steps after burn-in";
      return false;
    }
    const size_t total = static_cast<size_t>(kept) * c.num_walkers;
    std::vector<double> values(total);
    for (int i = 0; i < dim; ++i) {
      for (size_t s = 0; s < total; ++s) {
        values[s] = c.chain[(static_cast<size_t>(c.burn_in) * c.num_walkers + s) * dim + i];
      }
      FillPosterior(values, &result->parameters[i]);
    }
    // Derived quantities on evenly thinned draws.
    const size_t draws = std::min<size_t>(total, std::max(1, options.derived_draws));
    const auto draw_theta = [&](size_t t) {
      const size_t s = t * total / draws;
      return &c.chain[(static_cast<size_t>(c.burn_in) * c.num_walkers + s) * dim];
    };
    std::vector<std::vector<double>> dvals(dnames.size());
    for (size_t t = 0; t < draws; ++t) {
      const std::vector<double> d = DerivedAt(model, draw_theta(t));
      for (size_t j = 0; j < dnames.size(); ++j) {
        if (j != kPeakIndex) dvals[j].push_back(d[j]);
      }
    }
    // The peak pixel needs a render per exposure and draw (~15 % of a joint fit's time on one
    // thread), so its draws are shared out among the MCMC's threads, each with its own
    // evaluator; a draw's peak does not depend on which thread renders it.
    const size_t peak_every = std::max<size_t>(1, draws / std::max(1, options.peak_draws));
    std::vector<double>& peaks = dvals[kPeakIndex];
    peaks.assign((draws + peak_every - 1) / peak_every, 0.0);
    std::vector<std::vector<double>> pixels(threads);
    internal::ParallelFor(static_cast<int>(peaks.size()), threads, [&](int i, int worker) {
      const std::vector<double> at = PeakTheta(model, draw_theta(i * peak_every));
      double peak = 0.0;
      for (int k = 0; k < model.num_exposures(); ++k) {
        evaluators[worker]->ModelImage(at.data(), k, &pixels[worker], nullptr);
        peak +=
            *std::max_element(pixels[worker].begin(), pixels[worker].end()) / model.num_exposures();
      }
      peaks[i] = peak;
    });
    for (size_t j = 0; j < dnames.size(); ++j) FillPosterior(dvals[j], &result->derived[j].second);
  }
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace ccdpsf::fit
