// What the MCMC walks: the sampler's state for a fit, its two blocks, and the way back to the
// fit parameters theta.
//
// State coordinates (in this order):
//   the shared parameters in sampling coordinates (sampling_coordinates.h: the CCD widths
//   replaced by the total widths t_x, t_y), without the defocus when it is integrated out
//   (defocus_marginal.h: `integrated` sampling with a Gaussian defocus, where the data cannot
//   tell the defocus from the CCD widths), then x_px_K, y_px_K per exposure.
//   Through-focus fits (fit_model.h): the shared parameters in theta coordinates (identity
//   sampling coordinates, no marginalisation: the defocus differs per exposure and the CCD
//   widths are identified), then best_focus_um, then the positions.
//   The shared parameters that follow the positions in theta (best_focus_um, the flux
//   ratios of per-exposure fluxes) move to the shared block, before the positions, so that
//   they take the stretch moves (PhiIndex).
// Blocks: the shared parameters take the ensemble's stretch moves. The positions either join
// them, or (positions_by_conditional) are updated exposure by exposure with an independence
// Metropolis-Hastings move: the proposal is the Laplace approximation's conditional
// N(p_k | shared), whose mean follows the shared parameters linearly,
//   mean_k = p_k,map - P_k^-1 C_k (a - a_map),  covariance scale^2 P_k^-1,
// with P_k the 2 x 2 Fisher block of exposure k's position and C_k its coupling to the shared
// block a. Given the shared parameters the exposures are independent, so each move renders
// only its own exposure; the acceptance ratio uses the exact likelihood, so the Gaussian is
// only a proposal and any mismatch costs acceptance, not correctness.
#ifndef CCDPSF_FIT_POSTERIOR_TARGET_H_
#define CCDPSF_FIT_POSTERIOR_TARGET_H_

#include <array>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fit/defocus_marginal.h"
#include "ccdpsf/fit/ensemble_sampler.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/fit/laplace.h"
#include "ccdpsf/fit/sampling_coordinates.h"

namespace ccdpsf::fit {

struct PosteriorTargetOptions {
  // Integrate the defocus out where the model allows it (see above).
  bool marginal_defocus = true;
  // Update the positions by conditional moves instead of stretch moves (joint fits without
  // defocus_offset, which is tied to every position: PosteriorTarget's constructor).
  bool positions_by_conditional = true;
  // Width of the positions' proposal relative to the Laplace conditional: a little wider
  // than the target keeps the independence sampler robust to tails the Gaussian misses.
  double proposal_scale = 1.2;
  // Positions are updated on every n-th step only (BlockedTarget::conditional_every). With
  // the Laplace proposal their autocorrelation time is ~1.3 steps when updated every step and
  // ~2.6 every second step, far below the shared block's 40-150, so every second step costs
  // nothing in mixing and saves a quarter of the renders (measured on a 12-exposure
  // pixel_centre group: 60 s against 71-89 s of MCMC to the same ESS).
  int position_update_every = 2;
  // The sampler's Laplace-informed independence move (ensemble_sampler.h) on the stretch
  // block: the probability that a walker update takes it (SamplerOptions::
  // independence_fraction; 0 switches it off), and the proposal's scale relative to the
  // Laplace marginal of the stretch block (its scale matrix is laplace_move_scale^2 times
  // that covariance). The move is off where that covariance is not available (LaplaceProposal).
  // Measured (bench/fit_benchmark.cc, seed 1; issue 18): the stretch move alone has tau ~88
  // steps on the single fit and ~42 on the five-exposure joint fit (5000 and 2500 steps of 20
  // walkers to ESS 1000); with the move the independence acceptance is ~0.74 / 0.80 and tau
  // 2.5-5, and both fits converge at 200-300 steps for any fraction in 0.5-0.8 (the
  // convergence checks come every 100 steps, so a smaller tau gains nothing more). 0.6
  // reaches 200 steps on both; and where the Laplace approximation is poor, the stretch moves
  // still take 40 % of the updates, so a run is at most 1 / 0.4 = 2.5 times the stretch-only
  // one's length (the move accepted never) - 0.8 would allow 5 times. Scale 1: the t_5's
  // tails already cover a posterior a little wider than the Laplace one; 1.2 lowered the
  // acceptance (0.61 against 0.74 on the single fit) without lowering tau.
  double laplace_move_fraction = 0.6;
  double laplace_move_scale = 1.0;
};

class PosteriorTarget {
 public:
  // theta_map and the posterior's information at it (theta coordinates, dim x dim): the
  // likelihood's Fisher information with a Gaussian prior's precision added
  // (FitModel::PosteriorInformation), so that the Laplace seeds and proposals are the
  // posterior's.
  PosteriorTarget(const FitModel& model, const std::vector<double>& theta_map,
                  const std::vector<double>& fisher, const PosteriorTargetOptions& options);

  int dim() const { return static_cast<int>(names_.size()); }
  int stretch_dim() const { return stretch_dim_; }
  bool marginal_defocus() const { return marginal_; }
  bool positions_by_conditional() const { return stretch_dim_ < dim(); }
  const std::vector<std::string>& names() const { return names_; }
  const std::vector<double>& state_map() const { return state_map_; }
  // The Laplace approximation in state coordinates, to seed the walkers.
  const LaplaceResult& laplace() const { return laplace_; }

  // The independence move's proposal: the Laplace approximation's marginal on the stretch
  // block [0, stretch_dim()), centred at the MAP state, as a mean and the lower Cholesky
  // factor (row-major, stretch_dim() x stretch_dim()) of scale^2 times its covariance, where
  // along each direction the data constrain less than the prior does the covariance holds
  // the spread of a uniform across the prior (1 / sqrt(12) of its widths). False (outputs
  // untouched) when that covariance is not positive definite or has a non-finite entry.
  bool LaplaceProposal(double scale, std::vector<double>* mean,
                       std::vector<double>* cholesky) const;
  // The box the stretch block's support lies in, for the independence move's draws
  // (SamplerOptions::independence_lower / _upper): the prior's bounds on every coordinate that
  // is a model parameter itself, -inf / +inf on the transformed widths (whose support is not
  // a box). Measured on a reference-sensor intensity series with boundary_shift (a_11 and the
  // anisotropy near their bounds, half the proposals outside): the move's acceptance and the
  // steps to convergence in docs/trust.md.
  void ProposalBox(std::vector<double>* lower, std::vector<double>* upper) const;

  // theta of a state; with the defocus integrated out, u in [0, 1] is the quantile of the
  // defocus drawn from its exact conditional. False when the state is outside the support.
  bool ToTheta(const double* state, double u, double* theta) const;

  // log posterior density of a state up to a constant (-infinity outside the support): the
  // log-likelihood, the Gaussian prior's log density (FitModel::LogPrior) and the coordinates'
  // log Jacobian or defocus weight; writes each exposure's log-likelihood to aux
  // (num_exposures values) unless aux is nullptr.
  double LogDensity(FitEvaluator* evaluator, const double* state, double* aux) const;

  // The sampler's target, thread t using evaluators[t] (which must outlive the run).
  BlockedTarget Make(const std::vector<FitEvaluator*>& evaluators) const;

 private:
  // theta for a state with the lowest allowed defocus (the likelihood does not depend on
  // it in marginal mode); false outside the support. *log_weight: log W or log Jacobian.
  bool LikelihoodTheta(const double* state, double* theta, double* log_weight) const;
  double ConditionalUpdate(FitEvaluator* evaluator, double* state, double* aux, double* log_prob,
                           std::mt19937_64& engine) const;
  int PhiIndex(int state_index) const;

  const FitModel& model_;
  SamplingCoordinates coords_;
  WidthBounds bounds_;
  bool marginal_ = false;
  int num_shared_ = 0;  // shared parameters in the state
  int stretch_dim_ = 0;
  double proposal_scale_ = 1.0;
  int position_update_every_ = 1;
  std::vector<std::string> names_;
  std::vector<double> state_map_;
  LaplaceResult laplace_;
  // Per exposure: the conditional proposal's mean offset matrix B_k (2 x num_shared_,
  // row-major), the Cholesky factor L_k of P_k^-1 (lower, row-major 2 x 2) and its inverse.
  std::vector<std::vector<double>> coupling_;
  std::vector<std::array<double, 4>> chol_, chol_inverse_;
};

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_POSTERIOR_TARGET_H_
