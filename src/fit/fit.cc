#include "ccdpsf/fit/fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "ccdpsf/fit/autocorrelation.h"
#include "ccdpsf/fit/sampling_coordinates.h"
#include "ccdpsf/metrics.h"
#include "ccdpsf/random.h"

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

void FillPosterior(std::vector<double> values, Summary* s) {
  values.erase(std::remove_if(values.begin(), values.end(),
                              [](double v) { return !std::isfinite(v); }),
               values.end());
  std::sort(values.begin(), values.end());
  // 68.27 % and 99.73 % central intervals (1 and 3 sigma of a Gaussian).
  s->median = Percentile(values, 0.5);
  s->lo68 = Percentile(values, 0.158655);
  s->hi68 = Percentile(values, 0.841345);
  s->lo997 = Percentile(values, 0.00135);
  s->hi997 = Percentile(values, 0.99865);
}

// Index of the peak_e entry in DerivedNames().
constexpr size_t kPeakIndex = 10;

}  // namespace

const std::vector<std::string>& DerivedNames() {
  static const std::vector<std::string> names = {
      "fwhm_um",          "fwhm_x_um",        "fwhm_y_um",     "r2_px2",
      "r2_arcsec2",       "ellipticity",      "total_sigma_x_px", "total_sigma_y_px",
      "total_fwhm_um",    "total_ellipticity", "peak_e"};
  return names;
}

std::vector<double> DerivedAt(const FitModel& model, const double* theta) {
  const double pixel_um = model.stamps()[0].info.pixel_um;
  const PsfMetrics ccd = GaussianMetrics(theta[kCcdSigmaXPx], theta[kCcdSigmaYPx], pixel_um);
  // The identified (total) Gaussian widths: defocus and CCD widths in quadrature; a pillbox
  // of radius R contributes its second moment R^2 / 4 per axis.
  const double d = theta[kDefocusPx];
  const double d2 = model.options().model.defocus == model::DefocusKind::kGaussian ? d * d
                                                                                   : d * d / 4;
  const double tx = std::sqrt(theta[kCcdSigmaXPx] * theta[kCcdSigmaXPx] + d2);
  const double ty = std::sqrt(theta[kCcdSigmaYPx] * theta[kCcdSigmaYPx] + d2);
  const PsfMetrics total = GaussianMetrics(tx, ty, pixel_um);
  std::vector<double> out = {ccd.fwhm_um,   ccd.fwhm_x_um,     ccd.fwhm_y_um, ccd.r2_px2,
                             ccd.r2_arcsec2, ccd.ellipticity,  tx,            ty,
                             total.fwhm_um, total.ellipticity, NAN};
  return out;
}

bool RunFit(const FitModel& model, const FitOptions& options, FitResult* result,
            std::string* error) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = FitResult();
  result->names = model.names();
  const int dim = model.dim();
  if (!FindMap(model, options.map, &result->map, error)) return false;
  const std::vector<double>& theta_map = result->map.theta;

  std::unique_ptr<FitEvaluator> evaluator = model.NewEvaluator();
  result->laplace =
      ComputeLaplace(model, theta_map, evaluator->FisherInformation(theta_map.data()));

  // MAP and Laplace for the parameters.
  result->parameters.resize(dim);
  for (int i = 0; i < dim; ++i) {
    result->parameters[i].map = theta_map[i];
    result->parameters[i].laplace_sd = result->laplace.sd[i];
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
  }
  {
    std::vector<double> pixels, jac, grad(dim, 0.0);
    double peak = 0.0;
    for (int k = 0; k < model.num_exposures(); ++k) {
      evaluator->ModelImage(theta_map.data(), k, &pixels, &jac);
      const size_t q = std::max_element(pixels.begin(), pixels.end()) - pixels.begin();
      peak += pixels[q] / model.num_exposures();
      for (int i = 0; i < dim; ++i) grad[i] += jac[q * dim + i] / model.num_exposures();
    }
    result->derived[kPeakIndex].second.map = peak;
    result->derived[kPeakIndex].second.laplace_sd = DerivedSd(result->laplace, grad);
  }

  if (options.run_mcmc) {
    // Sample in the coordinates where the defocus / CCD ridge is straight
    // (sampling_coordinates.h), seeded from the Laplace approximation in those coordinates.
    const SamplingCoordinates coords(model);
    std::vector<double> phi_map(dim);
    coords.ToSampling(theta_map.data(), phi_map.data());
    const std::vector<double> jac = coords.Jacobian(phi_map.data());
    const std::vector<double> fisher = evaluator->FisherInformation(theta_map.data());
    std::vector<double> fisher_phi(static_cast<size_t>(dim) * dim, 0.0);
    for (int a = 0; a < dim; ++a) {
      for (int b = 0; b < dim; ++b) {
        double sum = 0.0;
        for (int i = 0; i < dim; ++i) {
          for (int j = 0; j < dim; ++j) sum += jac[i * dim + a] * fisher[i * dim + j] * jac[j * dim + b];
        }
        fisher_phi[a * dim + b] = sum;
      }
    }
    const LaplaceResult laplace_phi = ComputeLaplace(coords.names(), model.lower(), model.upper(),
                                                     phi_map, fisher_phi, false);
    auto density_for = [&coords, dim](FitEvaluator* ev) {
      return [&coords, ev, dim](const double* phi) -> double {
        thread_local std::vector<double> theta;
        theta.resize(dim);
        if (!coords.FromSampling(phi, theta.data())) return -INFINITY;
        const double lp = ev->LogPosterior(theta.data());
        return std::isfinite(lp) ? lp + coords.LogJacobian(phi) : -INFINITY;
      };
    };
    int walkers = options.num_walkers > 0 ? options.num_walkers : std::max(32, 4 * dim);
    walkers += walkers % 2;
    std::mt19937_64 engine(DeriveSeed(options.mcmc.seed, 0xC0FFEEULL));
    std::vector<double> initial;
    if (!SeedWalkers(laplace_phi, phi_map, walkers, engine, density_for(evaluator.get()),
                     &initial, error)) {
      return false;
    }
    const int threads = std::max(1, options.mcmc.num_threads);
    std::vector<std::unique_ptr<FitEvaluator>> evaluators;
    std::vector<LogDensity> densities;
    for (int t = 0; t < threads; ++t) {
      evaluators.push_back(model.NewEvaluator());
      densities.push_back(density_for(evaluators.back().get()));
    }
    if (!RunEnsembleSampler(densities, dim, initial, options.mcmc, &result->chain, error)) {
      return false;
    }
    // Back to the fit parameters; autocorrelation times and sample sizes are then measured
    // on the quantities reported.
    SamplerResult& chain = result->chain;
    std::vector<double> theta(dim);
    for (size_t s = 0; s < chain.chain.size() / dim; ++s) {
      double* state = &chain.chain[s * dim];
      coords.FromSampling(state, theta.data());
      std::copy(theta.begin(), theta.end(), state);
    }
    const int kept_steps = chain.num_steps - chain.burn_in;
    if (kept_steps >= 2) {
      double min_ess = INFINITY;
      for (int i = 0; i < dim; ++i) {
        const auto t = EnsembleIntegratedAutocorrelationTime(
            chain.chain.data() + static_cast<size_t>(chain.burn_in) * chain.num_walkers * dim + i,
            kept_steps, chain.num_walkers, static_cast<std::ptrdiff_t>(chain.num_walkers) * dim,
            dim);
        chain.tau[i] = t ? t->tau : INFINITY;
        chain.ess[i] = EffectiveSampleSize(chain.num_walkers, kept_steps, chain.tau[i]);
        min_ess = std::min(min_ess, chain.ess[i]);
      }
      if (chain.converged && min_ess < options.mcmc.target_ess) {
        chain.converged = false;
        chain.stop_reason += "; but on the reported parameters the smallest ESS is " +
                             std::to_string(static_cast<long>(min_ess));
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
    std::vector<std::vector<double>> dvals(dnames.size());
    std::vector<double> pixels;
    const size_t peak_every = std::max<size_t>(1, draws / std::max(1, options.peak_draws));
    for (size_t t = 0; t < draws; ++t) {
      const size_t s = t * total / draws;
      const double* theta = &c.chain[(static_cast<size_t>(c.burn_in) * c.num_walkers + s) * dim];
      const std::vector<double> d = DerivedAt(model, theta);
      for (size_t j = 0; j < dnames.size(); ++j) {
        if (j != kPeakIndex) dvals[j].push_back(d[j]);
      }
      if (t % peak_every == 0) {
        double peak = 0.0;
        for (int k = 0; k < model.num_exposures(); ++k) {
          evaluator->ModelImage(theta, k, &pixels, nullptr);
          peak += *std::max_element(pixels.begin(), pixels.end()) / model.num_exposures();
        }
        dvals[kPeakIndex].push_back(peak);
      }
    }
    for (size_t j = 0; j < dnames.size(); ++j) FillPosterior(dvals[j], &result->derived[j].second);
  }
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace ccdpsf::fit
