// Affine-invariant ensemble MCMC: the stretch move of J. Goodman and J. Weare, "Ensemble
// samplers with affine invariance", Comm. App. Math. Comp. Sci. 5 (2010) 65-80, with the
// parallel half-ensemble scheme of Foreman-Mackey et al. (emcee, PASP 125 (2013) 306).
//
// The walkers are split into two halves, the first and the second num_walkers / 2 of them.
// One step updates the first half, then the second. A walker x_k of the half being updated
// picks a partner x_j uniformly from the other half (whose positions do not change during
// this half-step), draws z from g(z) ~ 1 / sqrt(z) on [1/a, a], proposes
//
//   y = x_j + z (x_k - x_j)
//
// and accepts it with probability min(1, z^(dim - 1) p(y) / p(x_k)). Because the walkers of
// a half do not read each other, a half's walkers are updated in parallel. The move is
// unchanged by any affine map of the parameters, so badly scaled or strongly correlated
// parameters cost nothing extra; but the ensemble never leaves the affine hull of its
// initial positions, which must therefore span all dim directions (checked).
//
// Determinism: walker k draws all its random numbers (exactly three per update, accepted or
// not) from its own std::mt19937_64 seeded with DeriveSeed(seed, k), and each walker is
// updated by exactly one thread, so the chain is bit-identical for any num_threads.
//
// Convergence (checked every check_interval steps, less often in long runs: see
// check_fraction; sooner where a check's tau predicts the criteria met before the next one,
// at that step, at least a quarter of the spacing later; and at max_steps):
//   burn-in   burn_in = min(ceil(burn_in_taus * max tau of the previous check), steps / 2),
//             and steps / 2 at the first check. A transient still inside the kept steps
//             inflates the tau measured on them, which lengthens the next burn-in and delays
//             convergence rather than hiding it.
//   tau, ess  per parameter on steps [burn_in, steps): the ensemble tau of
//             autocorrelation.h, ess = walkers * (steps - burn_in) / tau.
//   converged (steps - burn_in) > min_tau_multiple * max(tau) and min(ess) >= target_ess
//             (and tau was estimable for every parameter), over the state's coordinates and,
//             when SamplerOptions::reported is set, the reported quantities too.
//
// Laplace-informed independence move (optional, off by default: independence_fraction = 0).
// Each walker update takes, with probability independence_fraction, an independence
// Metropolis-Hastings move instead of the stretch move: a proposal y drawn from a
// multivariate Student-t q with nu degrees of freedom, centre m and scale matrix L L^T (the
// caller's approximation of the posterior, e.g. its Laplace approximation, possibly
// widened), accepted with probability
//
//   min(1, p(y) q(x_k) / (p(x_k) q(y))),   log q(v) = -(nu + d) / 2 log(1 + |L^-1 (v - m)|^2 / nu).
//
// Why: where the approximation is good the move is accepted most of the time and draws
// almost independent states, so the autocorrelation time falls from the stretch move's
// tens of steps to a few; the heavier-than-Gaussian tails keep p / q bounded when the
// posterior's tails are a little heavier than the approximation's. Why it stays correct
// where the approximation is poor (a bound, a curved ridge): each kernel of the mixture
// leaves the target invariant by itself (the stretch move given the other half, the
// independence move given nothing else), the choice between them does not depend on the
// state, so the mixture leaves it invariant too; a poor proposal only lowers the
// independence move's acceptance, and the stretch moves still mix the chain as before. The
// move reads no other walker, so the half-ensemble scheme and its parallelism are untouched.
// For a blocked target the move acts on the stretch block [0, stretch_dim) only (m, L of that
// block's marginal), keeping the walker's other coordinates: an MH update of the first block
// given the walker's own rest, accepted with p(y, rest) q(x) / (p(x, rest) q(y)).
// Bounds (optional: independence_lower, independence_upper): where the target is 0 outside a
// box (a prior's bounds), a proposal outside it is a move wasted, and with a posterior
// piled against a bound (a coefficient near 0) half the proposals can fall there. The move
// then draws y again, up to kMaxIndependenceDraws times, until it lies inside the box. The
// proposal is then q restricted to the box times a constant (the probability of ending
// inside within that many draws, over q's mass inside), which cancels in the ratio above: the
// acceptance probability is the one above, unchanged, and the move stays exact; a last draw
// still outside is proposed and rejected as before. The box must contain the target's
// support.
// Random numbers: with independence_fraction > 0 every update first draws one uniform (the
// choice), then the stretch move's three numbers or the independence move's d + nu standard
// normals (repeated while outside the box) and one uniform, always in that order; with
// independence_fraction = 0 nothing extra is drawn and the chain is exactly that of the
// stretch-only sampler.
//
// It is easy to misuse an MCMC sampler's output: use only chain steps >= burn_in, and treat
// converged = false as "the error bars are not to be trusted".
#ifndef CCDPSF_FIT_ENSEMBLE_SAMPLER_H_
#define CCDPSF_FIT_ENSEMBLE_SAMPLER_H_

#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

namespace ccdpsf::fit {

struct SamplerOptions {
  // Stop after this many steps (one step moves every walker once) even if not converged.
  int max_steps = 20000;
  // Convergence checks happen at multiples of check_interval steps (or where the previous
  // check predicts convergence, see the top), ...
  int check_interval = 100;
  // ... but at least check_fraction * (steps so far) apart. A check costs
  // O(walkers * dim * steps * log(steps)) (~1 ms of CPU per walker and parameter at 20000
  // steps), so at a fixed spacing a long run would spend more time checking than sampling;
  // growing the spacing bounds that share, at the price of running up to this fraction of
  // extra steps after convergence is reached. 0: exactly every check_interval steps.
  double check_fraction = 0.05;
  // Convergence needs the smallest per-parameter effective sample size to reach this.
  double target_ess = 1000;
  // ... and the post-burn-in chain to be longer than this many times the largest tau [steps]
  // (emcee's advice: below ~50 tau the tau estimate itself is unreliable).
  double min_tau_multiple = 50;
  // Burn-in length in units of the previous check's tau (see above). 5: cheap next to the
  // 50 tau the chain must run anyway (10 %), and a transient from a tight initial ball has
  // decayed by then in the Gaussian tests; a longer one is caught by the tau it inflates.
  double burn_in_taus = 5;
  // Stretch-move scale a > 1 (Goodman & Weare's a = 2). Acceptance falls as a or the
  // dimension grows: with a = 2 it is ~0.7 on the 2-D and ~0.55 on the 5-D Gaussian of the
  // tests.
  double stretch_a = 2.0;
  // Laplace-informed independence move (see above): the probability that a walker update
  // uses it instead of the stretch move, in [0, 1]; 0 (the default) switches it off. When > 0,
  // independence_mean (stretch_dim values, the proposal's centre) and independence_cholesky
  // (stretch_dim x stretch_dim, row-major, the lower-triangular factor L of the proposal's
  // scale matrix L L^T; entries above the diagonal are ignored; diagonal > 0) must be set,
  // in the target's coordinates.
  double independence_fraction = 0.0;
  std::vector<double> independence_mean;
  std::vector<double> independence_cholesky;
  // The box the proposal is drawn in (see above): stretch_dim values each, -inf / +inf for an
  // open side; both empty (the default) for no box.
  std::vector<double> independence_lower;
  std::vector<double> independence_upper;
  // Degrees of freedom of the Student-t proposal, an integer >= 1 so that its chi-square
  // variate is a sum of nu squared normals (a fixed number of draws). 5: tails heavy enough
  // that p / q stays bounded for a posterior a little heavier-tailed than Gaussian, while
  // the proposal's core is still close to the Gaussian (95 % of the t_5's mass lies within
  // 2.6 scale units against 2.0 for the normal, so little is wasted in the tails).
  int independence_nu = 5;
  // The quantities the caller reports, when they are not the state's own coordinates (a
  // transformed or augmented state): reported(index, state, out) writes reported_dim values
  // for the stored state `index` (= step * walkers + walker). When set, convergence also needs
  // them to pass (their tau enters max tau, their ESS min ESS), so that a chain is never
  // called converged on coordinates nobody reads. It must be a pure function of its arguments
  // (safe to call from several threads), which lets the caller recompute exactly the values
  // that were judged.
  std::function<void(size_t index, const double* state, double* out)> reported;
  int reported_dim = 0;
  // Threads used: min(num_threads, number of log-densities given, walkers / 2).
  int num_threads = 2;
  // Walker k's random stream is DeriveSeed(seed, k).
  uint64_t seed = 0;
  // A progress line on stderr, rewritten in place with '\r', shown only once the run has
  // lasted more than 1 s.
  bool progress = true;
  // Prefix of the progress line (e.g. which fit this is).
  std::string progress_label;
  // Checkpointing (sampler_checkpoint.h). When set, the run's state is written to this file
  // at a convergence check once at least checkpoint_seconds have passed since the last
  // write (0: at every check); and a run that finds there a checkpoint of itself (the same
  // options, seed, dimensions and initial positions) continues from it, ending with exactly
  // the chain of an uninterrupted run. A checkpoint of another run is ignored (and
  // replaced). The file is left in place at the end: the caller removes it.
  std::string checkpoint_path;
  double checkpoint_seconds = 30;

  // False, with a one-line reason, when a field is out of range.
  bool IsValid(std::string* error) const;
};

// log p(theta) up to a constant, theta[0..dim-1]. Must return -infinity outside the support
// (anything not finite is treated as outside the support and rejected) and must never throw.
// One function per thread: thread t only ever calls log_density_per_thread[t], so each may
// own scratch space (e.g. a SpotRenderer) without locking.
using LogDensity = std::function<double(const double* theta)>;

// A target whose coordinates split in two blocks (Metropolis-within-Gibbs around the
// ensemble): coordinates [0, stretch_dim) take the stretch move above; after each of its
// stretch updates, a walker's remaining coordinates [stretch_dim, dim) are updated by
// `conditional`, a Markov kernel that must leave p(rest | first block) invariant. Each
// half-step then still leaves the product of the walkers' densities invariant: the stretch
// move is a valid Metropolis-Hastings update of walker k's first block for ANY target given
// the other half's positions (here p(first block | walker k's own rest)).
// Why: in a joint fit the per-exposure positions are nearly independent of each other given
// the shared PSF parameters; sampling them by exact conditional moves keeps the ensemble's
// dimension that of the shared block, and the stretch move's autocorrelation time grows with
// that dimension.
// aux: aux_dim numbers per walker that the density computes for a state and the conditional
// update reads and keeps current (e.g. the log-likelihood of each exposure), so that a
// conditional move need not recompute what it does not change.
struct BlockedTarget {
  int stretch_dim = 0;
  int aux_dim = 0;
  // log p(state) up to a constant; writes aux_dim values to aux (which may be nullptr when
  // aux_dim == 0). Rules as for LogDensity. One per thread.
  using Density = std::function<double(const double* state, double* aux)>;
  // Updates state[stretch_dim..dim), *aux and *log_prob (the density of the new state) in
  // place, drawing only from `engine`; returns the fraction of its sub-moves accepted. One
  // per thread; empty when stretch_dim == dim.
  using Conditional =
      std::function<double(double* state, double* aux, double* log_prob, std::mt19937_64& engine)>;
  std::vector<Density> log_density;
  std::vector<Conditional> conditional;
  // The conditional update follows the stretch update on steps 0, every, 2 every, ... only:
  // when the second block mixes much faster than the first (e.g. positions drawn from a good
  // proposal), updating it less often saves its cost and leaves the slow block's mixing as
  // it was.
  int conditional_every = 1;
};

struct SamplerResult {
  int num_walkers = 0;
  int dim = 0;
  int num_steps = 0;  // steps taken; the chain holds one entry per step (not the initial state)
  int burn_in = 0;    // steps to discard [steps]
  int num_threads_used = 0;
  // Positions after each step: chain[(step * num_walkers + walker) * dim + k]. The whole run
  // is kept: 8 * num_steps * num_walkers * dim bytes (20000 x 32 x 7: 36 MB).
  std::vector<double> chain;
  // log p of those positions: log_prob[step * num_walkers + walker].
  std::vector<double> log_prob;
  // With SamplerOptions::reported: the reported quantities of every stored state,
  // reported[(step * num_walkers + walker) * reported_dim + j] (the values the convergence
  // checks judged, each computed once); else empty.
  std::vector<double> reported;
  // Accepted stretch moves / stretch moves proposed (= steps when the independence move is
  // off), per walker (NaN for a walker that never proposed one); and its mean over walkers.
  std::vector<double> acceptance_fraction;
  double mean_acceptance = 0.0;
  // Accepted / proposed independence moves over all walkers and steps, and the number
  // proposed (NaN and 0 when the move is off).
  double independence_acceptance = NAN;
  int64_t independence_proposed = 0;
  // Blocked targets only: mean acceptance of the conditional updates (NaN otherwise).
  double conditional_acceptance = NAN;
  // Per parameter, on steps [burn_in, num_steps): integrated autocorrelation time [steps]
  // (+inf where it could not be estimated) and effective sample size
  // walkers * (num_steps - burn_in) / tau (0 there).
  std::vector<double> tau;
  std::vector<double> ess;
  bool converged = false;
  // Why the run stopped: which criteria were met, or which failed at max_steps.
  std::string stop_reason;
  double seconds = 0.0;  // wall-clock duration of the run [s]
  int resumed_from_step = 0;  // the checkpoint's step when the run resumed from one, else 0
  // Why a checkpoint that was there was not resumed (damaged: its checksum fails), else "".
  std::string checkpoint_discarded;

  // The chain's states after burn-in, evenly thinned to at most max_states (>= 1): state
  // indices s (positions at chain[s * dim]), s = burn_in x walkers + t x kept / n for
  // t < n = min(kept, max_states), kept = (num_steps - burn_in) x walkers.
  std::vector<size_t> ThinnedStates(int max_states) const;
};

// Runs the sampler. initial holds num_walkers x dim starting positions, row-major, with
// num_walkers = initial.size() / dim. Returns false, with a one-line message in *error and
// *result untouched, when: the options are invalid; dim < 1; log_density_per_thread is empty
// or holds an empty function; initial.size() is not a positive multiple of dim; num_walkers
// is odd or < 2 * dim + 2 (each half must be able to span the dim directions); an initial
// walker has a non-finite log-density; or the initial walkers lie in a lower-dimensional
// affine subspace; or the independence move is on (independence_fraction > 0) with a mean or
// Cholesky factor of the wrong size or a Cholesky diagonal not finite and > 0. Otherwise
// returns true (converged or not: see result->converged).
bool RunEnsembleSampler(const std::vector<LogDensity>& log_density_per_thread, int dim,
                        const std::vector<double>& initial, const SamplerOptions& options,
                        SamplerResult* result, std::string* error);

// The same for a blocked target: walkers must number >= 2 * stretch_dim + 2 and span the
// stretch block's directions; acceptance_fraction counts the stretch moves.
bool RunEnsembleSampler(const BlockedTarget& target, int dim, const std::vector<double>& initial,
                        const SamplerOptions& options, SamplerResult* result, std::string* error);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_ENSEMBLE_SAMPLER_H_
