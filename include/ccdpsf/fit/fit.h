// A complete fit of one exposure or a joint set: MAP (Ceres) -> Laplace approximation with
// identifiability analysis -> ensemble MCMC seeded from it -> posterior summaries of the
// parameters and of the PSF metrics.
#ifndef CCDPSF_FIT_FIT_H_
#define CCDPSF_FIT_FIT_H_

#include <map>
#include <string>
#include <vector>

#include "ccdpsf/fit/data_alone_estimate.h"
#include "ccdpsf/fit/ensemble_sampler.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/laplace.h"
#include "ccdpsf/fit/map_fit.h"
#include "ccdpsf/fit/posterior_target.h"

namespace ccdpsf::fit {

struct FitOptions {
  MapOptions map;
  bool run_mcmc = true;
  // Walkers: 0 picks max(2 x stretch dimension + 2, target_ess / min_tau_multiple), even.
  int num_walkers = 0;
  SamplerOptions mcmc;
  // What the sampler walks (posterior_target.h); both switches off gives the plain ensemble
  // over all parameters in sampling coordinates.
  PosteriorTargetOptions target;
  // Posterior draws (thinned from the chain after burn-in) used for the derived metrics;
  // the peak pixel, which needs a render per draw and exposure, uses at most peak_draws.
  int derived_draws = 4000;
  int peak_draws = 400;
};

// Centre and intervals of one quantity: the MAP value with its Laplace sd (NaN when the
// data do not constrain it), and the posterior median with central 68 % and 99.7 %
// intervals (NaN without MCMC).
struct Summary {
  double map = NAN;
  double laplace_sd = NAN;
  // The misspecification-robust (sandwich) sd at the MAP: C M C with C the Laplace covariance
  // and M the outer products of the pixels' scores (FitEvaluator::ScoreOuterProducts). Equal
  // to laplace_sd in expectation when the model and noise model hold; larger where the
  // residuals exceed the noise model. NaN where laplace_sd is.
  double sandwich_sd = NAN;
  double median = NAN;
  double lo68 = NAN, hi68 = NAN;
  double lo997 = NAN, hi997 = NAN;
};

// The 68 % interval of the Laplace approximation for a quantity with MAP `map` and sd `sd`:
// map -+ sd; for a quantity that cannot be negative (`positive`: a width, FWHM, ellipticity,
// R^2) the interval of its logarithm, map x exp(-+ sd / map), the same to first order in
// sd / map and never below 0. NaN bounds where sd is not finite.
void LaplaceInterval68(double map, double sd, bool positive, double* lo, double* hi);

// The posterior part of *s from draws of one quantity (non-finite draws dropped): median and
// central 68.27 % and 99.73 % intervals, by linear interpolation between order statistics.
// The MAP and Laplace sd are left as they are.
void FillPosterior(std::vector<double> draws, Summary* s);

struct FitResult {
  std::vector<std::string> names;
  MapResult map;
  LaplaceResult laplace;
  // The sandwich covariance (Summary::sandwich_sd), dim x dim like laplace.covariance.
  std::vector<double> sandwich_covariance;
  bool have_mcmc = false;
  SamplerResult chain;
  std::vector<Summary> parameters;                       // in theta order
  std::vector<std::pair<std::string, Summary>> derived;  // fixed order, see fit.cc
  // With a Gaussian prior: what the data alone say of its parameters (data_alone_estimate.h);
  // left not available (and empty) without one.
  DataAloneEstimate data_alone;
  double seconds = 0.0;
};

// Names of the derived quantities, in the order of FitResult::derived, with their units in
// the names (fwhm_um, ..., peak_e).
const std::vector<std::string>& DerivedNames();

// The derived quantities at theta, except peak_e (needs a render): returned in DerivedNames()
// order with peak_e = NaN.
std::vector<double> DerivedAt(const FitModel& model, const double* theta);

// The parameters at which peak_e is measured: theta with every exposure's spot moved to the
// pixel centre nearest its fitted position, and in a through-focus fit the defocus rate set
// to zero, i.e. every exposure at best focus. Why centred: the intensity names a setting
// (flux and PSF), not where its spots happened to land; with the spot 0.1 px off centre the
// brightest pixel of a sharp spot is ~1.5 % lower, which through the intensity relation
// moved the 800 nm FWHM at I0 by +1.5 sd on simulated campaigns (whose nominal peak is the
// centred spot's). A series' peak_e is thereby its spot's at best focus, as its total_*
// metrics are (DerivedAt): the intensity its identified CCD widths belong to.
std::vector<double> PeakTheta(const FitModel& model, const double* theta);

// MAP (FindMap, unless `map` gives one already found for this model), Laplace, MCMC and the
// summaries. With a Gaussian prior (gaussian_prior.h) every step is the posterior's, and
// data_alone is filled.
bool RunFit(const FitModel& model, const FitOptions& options, FitResult* result,
            std::string* error, const MapResult* map = nullptr);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_FIT_H_
