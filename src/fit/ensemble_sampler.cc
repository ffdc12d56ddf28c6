#include "ccdpsf/fit/ensemble_sampler.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <condition_variable>
#include <cstdio>
#include <limits>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <system_error>
#include <thread>

#include "Eigen/Core"
#include "Eigen/SVD"
#include "ccdpsf/fit/autocorrelation.h"
#include "ccdpsf/fit/sampler_checkpoint.h"
#include "ccdpsf/random.h"
#include "glog/logging.h"

namespace ccdpsf::fit {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// The independence move's draws per update while outside its box (ensemble_sampler.h): with
// a box holding a fraction f of the proposal, a last draw still outside (and so rejected)
// has probability (1 - f)^100, below 1e-4 for f >= 0.09. The bound keeps an update's cost
// finite where the box holds almost nothing.
constexpr int kMaxIndependenceDraws = 100;

// A fixed team of threads that runs one task at a time: Run(task) calls task(t) once for
// every t in [0, size()), t = 0 on the calling thread, and returns when all have finished.
// The workers persist for the whole run, so a half-step costs one hand-over rather than
// thread creation. Both sides of a hand-over first spin for a while (kSpinRounds) before
// blocking: the sampler's half-steps follow each other within microseconds, and a blocked
// thread's wake-up through the kernel took ~0.15 ms a half-step on this machine (a third of
// a joint fit's half-step).
class ThreadTeam {
 public:
  // Starts up to num_threads - 1 workers; if the system refuses a thread, the team is
  // smaller (size() says how large), which changes nothing but speed.
  explicit ThreadTeam(int num_threads) {
    // More threads than cores: a spinning thread would hold a core that a working one needs.
    const unsigned cores = std::thread::hardware_concurrency();
    spin_rounds_ = (cores == 0 || static_cast<unsigned>(num_threads) <= cores) ? kSpinRounds : 0;
    for (int t = 1; t < num_threads; ++t) {
      try {
        workers_.emplace_back(&ThreadTeam::WorkerLoop, this, t);
      } catch (const std::system_error&) {
        break;
      }
    }
  }

  ~ThreadTeam() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_.store(true, std::memory_order_release);
    }
    start_.notify_all();
    for (std::thread& worker : workers_) worker.join();
  }

  ThreadTeam(const ThreadTeam&) = delete;
  ThreadTeam& operator=(const ThreadTeam&) = delete;

  int size() const { return static_cast<int>(workers_.size()) + 1; }

  void Run(const std::function<void(int)>& task) {
    if (workers_.empty()) {
      task(0);
      return;
    }
    task_ = &task;
    pending_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
    {
      // Under the mutex, so that a worker about to block sees the new generation.
      std::lock_guard<std::mutex> lock(mutex_);
      generation_.fetch_add(1, std::memory_order_release);
    }
    start_.notify_all();
    task(0);
    if (!SpinUntil([this] { return pending_.load(std::memory_order_acquire) == 0; })) {
      std::unique_lock<std::mutex> lock(mutex_);
      done_.wait(lock, [this] { return pending_.load(std::memory_order_acquire) == 0; });
    }
    task_ = nullptr;
  }

 private:
  // ~0.1 ms of pause instructions at most (a pause is ~40-140 cycles on recent x86).
  static constexpr int kSpinRounds = 2000;

  // Whether `ready` became true within spin_rounds_ checks.
  template <typename Ready>
  bool SpinUntil(const Ready& ready) const {
    for (int i = 0; i < spin_rounds_; ++i) {
      if (ready()) return true;
#if defined(__x86_64__) || defined(__i386__)
      __builtin_ia32_pause();
#endif
    }
    return ready();
  }

  void WorkerLoop(int index) {
    uint64_t seen = 0;
    const auto started = [&] {
      return stop_.load(std::memory_order_acquire) ||
             generation_.load(std::memory_order_acquire) != seen;
    };
    while (true) {
      if (!SpinUntil(started)) {
        std::unique_lock<std::mutex> lock(mutex_);
        start_.wait(lock, started);
      }
      if (stop_.load(std::memory_order_acquire)) return;
      seen = generation_.load(std::memory_order_acquire);
      (*task_)(index);
      if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
        // Under the mutex, so that a caller about to block sees pending_ at zero.
        std::lock_guard<std::mutex> lock(mutex_);
        done_.notify_one();
      }
    }
  }

  std::mutex mutex_;
  std::condition_variable start_;
  std::condition_variable done_;
  // Set before generation_ moves on (release), read after it is seen (acquire).
  const std::function<void(int)>* task_ = nullptr;
  std::atomic<uint64_t> generation_{0};
  std::atomic<int> pending_{0};
  std::atomic<bool> stop_{false};
  int spin_rounds_ = 0;
  std::vector<std::thread> workers_;
};

// [begin, end) of thread t's share when `count` items are split into `parts` contiguous
// blocks whose sizes differ by at most one.
void StaticBlock(int count, int parts, int t, int* begin, int* end) {
  *begin = static_cast<int>(static_cast<int64_t>(count) * t / parts);
  *end = static_cast<int>(static_cast<int64_t>(count) * (t + 1) / parts);
}

// Checks that the initial walkers span all dim directions: the stretch move only forms
// affine combinations of walkers, so a deficient ensemble could never leave its subspace.
// Columns are scaled to unit RMS first, so parameters of very different units (a flux in
// electrons beside a width in pixels) do not make the test scale-dependent.
// Only the first span_dim of each walker's `stride` coordinates are checked.
bool SpansAllDirections(const std::vector<double>& initial, int num_walkers, int stride,
                        int span_dim, std::string* error) {
  const int dim = span_dim;
  Eigen::MatrixXd centred(num_walkers, dim);
  for (int w = 0; w < num_walkers; ++w) {
    for (int k = 0; k < dim; ++k) centred(w, k) = initial[static_cast<size_t>(w) * stride + k];
  }
  for (int k = 0; k < dim; ++k) {
    centred.col(k).array() -= centred.col(k).mean();
    const double rms = centred.col(k).norm();
    if (!(rms > 0.0)) {
      *error = "ensemble sampler: parameter " + std::to_string(k) +
               " has the same value in every initial walker";
      return false;
    }
    centred.col(k) /= rms;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(centred);
  const Eigen::VectorXd& singular = svd.singularValues();
  // Relative threshold well above rounding (~1e-16) but far below any deliberately spread
  // ensemble, whose columns are unit vectors in general position.
  if (singular(dim - 1) < 1e-9 * singular(0)) {
    *error =
        "ensemble sampler: the initial walkers lie in a lower-dimensional affine "
        "subspace (smallest/largest singular value " +
        std::to_string(singular(dim - 1) / singular(0)) + ")";
    return false;
  }
  return true;
}

// For messages: whole numbers as such (2000, not 2e+03), others to `precision` significant
// digits, but never in exponent form below 1e7.
std::string FormatNumber(double value, int precision = 3) {
  std::ostringstream out;
  if (std::isfinite(value) && std::fabs(value) < 1e7 &&
      (value == std::round(value) || std::fabs(value) >= std::pow(10.0, precision))) {
    out << std::fixed;
    out.precision(0);
  } else {
    out.precision(precision);
  }
  out << value;
  return out.str();
}

// The sampler's state and its two operations (a step, a convergence check).
class EnsembleSampler {
 public:
  EnsembleSampler(const BlockedTarget& target, int dim, int num_walkers,
                  const SamplerOptions& options, ThreadTeam* team)
      : target_(target),
        dim_(dim),
        stretch_dim_(target.stretch_dim),
        aux_dim_(target.aux_dim),
        num_walkers_(num_walkers),
        half_(num_walkers / 2),
        options_(options),
        team_(team),
        positions_(static_cast<size_t>(num_walkers) * dim),
        log_prob_(num_walkers),
        accepted_(num_walkers, 0),
        independence_proposed_(num_walkers, 0),
        independence_accepted_(num_walkers, 0),
        conditional_acceptance_(num_walkers, 0.0),
        aux_(static_cast<size_t>(num_walkers) * target.aux_dim),
        // Each thread's scratch starts on its own 64-byte cache line (8 doubles), so that
        // threads writing proposals do not invalidate each other's caches.
        proposal_stride_((dim + 7) / 8 * 8),
        proposal_(static_cast<size_t>(team->size()) * proposal_stride_),
        whitened_(static_cast<size_t>(team->size()) * proposal_stride_),
        aux_stride_((target.aux_dim + 7) / 8 * 8),
        proposal_aux_(static_cast<size_t>(team->size()) * aux_stride_) {
    engines_.reserve(num_walkers);
    for (int w = 0; w < num_walkers; ++w) {
      engines_.emplace_back(DeriveSeed(options.seed, static_cast<uint64_t>(w)));
    }
  }

  // Sets the positions and evaluates their log-densities; false, with a message, when one
  // of them is not finite.
  bool Initialise(const std::vector<double>& initial, std::string* error) {
    positions_ = initial;
    const int threads = team_->size();
    team_->Run([&](int t) {
      int begin, end;
      StaticBlock(num_walkers_, threads, t, &begin, &end);
      for (int w = begin; w < end; ++w) {
        log_prob_[w] = target_.log_density[t](&positions_[static_cast<size_t>(w) * dim_], AuxOf(w));
      }
    });
    for (int w = 0; w < num_walkers_; ++w) {
      if (!std::isfinite(log_prob_[w])) {
        *error = "ensemble sampler: initial walker " + std::to_string(w) + " has log-density " +
                 FormatNumber(log_prob_[w]) + " (every walker must start inside the support)";
        return false;
      }
    }
    return true;
  }

  // One step: the first half, then the second; appends the new state to the chain.
  void Step(std::vector<double>* chain, std::vector<double>* log_prob) {
    for (int half = 0; half < 2; ++half) {
      team_->Run([this, half](int t) { UpdateHalf(half, t); });
    }
    ++step_;
    chain->insert(chain->end(), positions_.begin(), positions_.end());
    log_prob->insert(log_prob->end(), log_prob_.begin(), log_prob_.end());
  }

  // The walkers' state into / from a checkpoint. Import is false if the checkpoint's sizes
  // do not match this sampler or an engine's text does not parse.
  void Export(SamplerCheckpoint* c) const {
    c->positions = positions_;
    c->log_prob = log_prob_;
    c->accepted = accepted_;
    c->independence_proposed = independence_proposed_;
    c->independence_accepted = independence_accepted_;
    c->conditional_acceptance = conditional_acceptance_;
    c->aux = aux_;
    c->engines.clear();
    for (const std::mt19937_64& e : engines_) {
      std::ostringstream text;
      text << e;
      c->engines.push_back(text.str());
    }
  }
  bool Import(const SamplerCheckpoint& c, int64_t steps) {
    if (c.positions.size() != positions_.size() || c.log_prob.size() != log_prob_.size() ||
        c.accepted.size() != accepted_.size() || c.aux.size() != aux_.size() ||
        c.independence_proposed.size() != independence_proposed_.size() ||
        c.independence_accepted.size() != independence_accepted_.size() ||
        c.conditional_acceptance.size() != conditional_acceptance_.size() ||
        c.engines.size() != engines_.size()) {
      return false;
    }
    std::vector<std::mt19937_64> engines(engines_.size());
    for (size_t w = 0; w < engines.size(); ++w) {
      std::istringstream text(c.engines[w]);
      text >> engines[w];
      if (text.fail()) return false;
    }
    positions_ = c.positions;
    log_prob_ = c.log_prob;
    accepted_ = c.accepted;
    independence_proposed_ = c.independence_proposed;
    independence_accepted_ = c.independence_accepted;
    conditional_acceptance_ = c.conditional_acceptance;
    aux_ = c.aux;
    engines_ = std::move(engines);
    step_ = steps;
    return true;
  }

  // Per walker: accepted stretch moves; independence moves proposed and accepted.
  const std::vector<int64_t>& accepted() const { return accepted_; }
  const std::vector<int64_t>& independence_proposed() const { return independence_proposed_; }
  const std::vector<int64_t>& independence_accepted() const { return independence_accepted_; }
  // Sum over steps of each walker's conditional-update acceptance fraction.
  const std::vector<double>& conditional_acceptance() const { return conditional_acceptance_; }

 private:
  double* AuxOf(int walker) {
    return aux_dim_ == 0 ? nullptr : &aux_[static_cast<size_t>(walker) * aux_dim_];
  }

  // log q(x) of the independence proposal up to a constant (the constant cancels in the
  // acceptance ratio): -(nu + d) / 2 log(1 + r^2 / nu), r = L^-1 (x - m) by forward
  // substitution over the stretch block.
  double IndependenceLogDensity(const double* x, double* scratch) const {
    const std::vector<double>& m = options_.independence_mean;
    const std::vector<double>& l = options_.independence_cholesky;
    double r2 = 0.0;
    for (int i = 0; i < stretch_dim_; ++i) {
      double v = x[i] - m[i];
      for (int j = 0; j < i; ++j) v -= l[static_cast<size_t>(i) * stretch_dim_ + j] * scratch[j];
      scratch[i] = v / l[static_cast<size_t>(i) * stretch_dim_ + i];
      r2 += scratch[i] * scratch[i];
    }
    const double nu = options_.independence_nu;
    return -0.5 * (nu + stretch_dim_) * std::log1p(r2 / nu);
  }

  // Whether the stretch block of y lies inside the independence move's box (true without one).
  bool InsideBox(const double* y) const {
    const std::vector<double>& lo = options_.independence_lower;
    const std::vector<double>& hi = options_.independence_upper;
    if (lo.empty()) return true;
    for (int d = 0; d < stretch_dim_; ++d) {
      if (!(y[d] >= lo[d] && y[d] <= hi[d])) return false;
    }
    return true;
  }

  // Thread t's share of the walkers of half `half`.
  void UpdateHalf(int half, int t) {
    const double a = options_.stretch_a;
    const int other_begin = (1 - half) * half_;
    const double fraction = options_.independence_fraction;
    int begin, end;
    StaticBlock(half_, team_->size(), t, &begin, &end);
    double* y = &proposal_[static_cast<size_t>(t) * proposal_stride_];
    double* y_aux = aux_dim_ == 0 ? nullptr : &proposal_aux_[static_cast<size_t>(t) * aux_stride_];
    for (int i = begin; i < end; ++i) {
      const int k = half * half_ + i;
      std::mt19937_64& engine = engines_[k];
      const double* xk = &positions_[static_cast<size_t>(k) * dim_];
      // No choice is drawn when the move is off, so the stream (and the chain) is then
      // exactly the stretch-only sampler's.
      const bool independence = fraction > 0.0 && Uniform01(engine) < fraction;
      // log of the factor that multiplies p(y) / p(x_k) in the acceptance probability.
      double log_factor = 0.0;
      double u_accept = 0.0;
      if (independence) {
        // d + nu normals per draw (repeated while outside the box), then one uniform.
        // y = m + L z sqrt(nu / chi2): z ~ N(0, I_d) and chi2 a chi-square variate with nu
        // degrees of freedom give a multivariate t.
        const std::vector<double>& m = options_.independence_mean;
        const std::vector<double>& l = options_.independence_cholesky;
        const double nu = options_.independence_nu;
        double log_q_y = 0.0;
        for (int draw = 0; draw < kMaxIndependenceDraws; ++draw) {
          for (int d = 0; d < stretch_dim_; ++d) y[d] = StandardNormal(engine);
          double chi2 = 0.0;
          for (int n = 0; n < options_.independence_nu; ++n) {
            const double g = StandardNormal(engine);
            chi2 += g * g;
          }
          const double scale = std::sqrt(nu / chi2);
          double z2 = 0.0;
          for (int d = 0; d < stretch_dim_; ++d) z2 += y[d] * y[d];
          // y = m + scale L z in place, last row first: row d reads z[0..d], not yet
          // overwritten.
          for (int d = stretch_dim_ - 1; d >= 0; --d) {
            double v = 0.0;
            for (int j = 0; j <= d; ++j) v += l[static_cast<size_t>(d) * stretch_dim_ + j] * y[j];
            y[d] = m[d] + scale * v;
          }
          // L^-1 (y - m) = scale z, so q(y) needs no solve.
          log_q_y = -0.5 * (nu + stretch_dim_) * std::log1p(scale * scale * z2 / nu);
          if (InsideBox(y)) break;
        }
        u_accept = Uniform01(engine);
        double* scratch = &whitened_[static_cast<size_t>(t) * proposal_stride_];
        log_factor = IndependenceLogDensity(xk, scratch) - log_q_y;
        ++independence_proposed_[k];
      } else {
        // Always three draws, in this order, so a walker's stream never depends on outcomes.
        const double u_partner = Uniform01(engine);
        const double u_stretch = Uniform01(engine);
        u_accept = Uniform01(engine);
        const int j = other_begin + std::min(half_ - 1, static_cast<int>(u_partner * half_));
        // Inverse CDF of g(z) ~ 1/sqrt(z) on [1/a, a]: z = ((a - 1) u + 1)^2 / a.
        const double root = (a - 1.0) * u_stretch + 1.0;
        const double z = root * root / a;
        const double* xj = &positions_[static_cast<size_t>(j) * dim_];
        for (int d = 0; d < stretch_dim_; ++d) y[d] = xj[d] + z * (xk[d] - xj[d]);
        log_factor = (stretch_dim_ - 1) * std::log(z);
      }
      std::copy(xk + stretch_dim_, xk + dim_, y + stretch_dim_);
      const double log_prob_y = target_.log_density[t](y, y_aux);
      if (std::isfinite(log_prob_y)) {
        const double log_ratio = log_factor + log_prob_y - log_prob_[k];
        if (std::log(u_accept) < log_ratio) {
          std::copy(y, y + dim_, &positions_[static_cast<size_t>(k) * dim_]);
          if (aux_dim_ > 0) std::copy(y_aux, y_aux + aux_dim_, AuxOf(k));
          log_prob_[k] = log_prob_y;
          ++(independence ? independence_accepted_ : accepted_)[k];
        }
      }
      if (stretch_dim_ < dim_ && step_ % target_.conditional_every == 0) {
        conditional_acceptance_[k] += target_.conditional[t](
            &positions_[static_cast<size_t>(k) * dim_], AuxOf(k), &log_prob_[k], engine);
      }
    }
  }

  const BlockedTarget& target_;
  const int dim_;
  const int stretch_dim_;
  const int aux_dim_;
  const int num_walkers_;
  const int half_;
  const SamplerOptions& options_;
  ThreadTeam* team_;
  std::vector<double> positions_;               // [walker * dim + k]
  std::vector<double> log_prob_;                // [walker]
  std::vector<int64_t> accepted_;               // [walker], stretch moves
  std::vector<int64_t> independence_proposed_;  // [walker]
  std::vector<int64_t> independence_accepted_;  // [walker]
  int64_t step_ = 0;                            // steps completed
  std::vector<double> conditional_acceptance_;  // [walker]
  std::vector<double> aux_;                     // [walker * aux_dim + i]
  const int proposal_stride_;
  std::vector<double> proposal_;  // [thread * proposal_stride_ + k], per-thread scratch
  std::vector<double> whitened_;  // [thread * proposal_stride_ + k], L^-1 (x - m) scratch
  const int aux_stride_;
  std::vector<double> proposal_aux_;  // [thread * aux_stride_ + i], per-thread scratch
  std::vector<std::mt19937_64> engines_;
};

struct Diagnostics {
  int burn_in = 0;
  std::vector<double> tau;
  std::vector<double> ess;
  double max_tau = kInf;  // inf if any tau is missing
  bool converged = false;
  std::string reason;
};

// tau of every parameter on chain steps [first, last); the default (tau = inf, no window)
// where there is no estimate. Parameters are dealt out among the team's threads, each
// writing only its own entries, so the result does not depend on the team size.
std::vector<AutocorrelationTime> TauPerParameter(const std::vector<double>& chain, int num_walkers,
                                                 int dim, int first, int last, ThreadTeam* team) {
  std::vector<AutocorrelationTime> tau(dim);
  const int threads = team->size();
  const std::ptrdiff_t step_stride = static_cast<std::ptrdiff_t>(num_walkers) * dim;
  team->Run([&](int t) {
    for (int k = t; k < dim; k += threads) {
      const std::optional<AutocorrelationTime> estimate = EnsembleIntegratedAutocorrelationTime(
          chain.data() + first * step_stride + k, last - first, num_walkers, step_stride, dim);
      if (estimate) tau[k] = *estimate;  // else the default: tau = inf, no window
    }
  });
  return tau;
}

// The reported quantities (SamplerOptions::reported) of every stored state, computed once:
// reported_dim values per state, and per step whether its states are done. A pure function
// of (index, state) gives the same values whenever it is called, so each check reuses the
// earlier ones and the caller gets the whole chain's (SamplerResult::reported).
struct ReportedValues {
  std::vector<double> values;
  std::vector<char> done;

  // Computes the states of steps [first, steps) not done yet, on the team's threads (each
  // step written by one thread).
  void Fill(const std::vector<double>& chain, int num_walkers, int dim, int first, int steps,
            const SamplerOptions& options, ThreadTeam* team) {
    const int rdim = options.reported_dim;
    values.resize(static_cast<size_t>(steps) * num_walkers * rdim);
    done.resize(steps, 0);
    const int threads = team->size();
    team->Run([&](int t) {
      for (int step = first + t; step < steps; step += threads) {
        if (done[step]) continue;
        for (int w = 0; w < num_walkers; ++w) {
          const size_t index = static_cast<size_t>(step) * num_walkers + w;
          options.reported(index, chain.data() + index * dim, values.data() + index * rdim);
        }
        done[step] = 1;
      }
    });
  }
};

// previous_max_tau: the largest tau of the previous check (+inf if none or not estimated).
Diagnostics Check(const std::vector<double>& chain, int num_walkers, int dim, int steps,
                  double previous_max_tau, const SamplerOptions& options, ThreadTeam* team,
                  ReportedValues* reported) {
  Diagnostics diag;
  const int half = steps / 2;
  const double wanted = std::ceil(options.burn_in_taus * previous_max_tau);
  // (NaN from 0 * inf also fails the comparison and gives half.)
  diag.burn_in = wanted < half ? static_cast<int>(wanted) : half;

  const int kept = steps - diag.burn_in;
  double max_tau = 0.0;
  double min_ess = kInf;
  int min_ess_parameter = 0;
  int no_window_parameter = -1;
  // Appends the taus of one set of quantities to diag and folds them into the criteria.
  auto add = [&](const std::vector<AutocorrelationTime>& taus) {
    for (const AutocorrelationTime& t : taus) {
      const int k = static_cast<int>(diag.tau.size());
      diag.tau.push_back(t.tau);
      diag.ess.push_back(EffectiveSampleSize(num_walkers, kept, t.tau));
      if (!t.window_found && no_window_parameter < 0) no_window_parameter = k;
      max_tau = std::max(max_tau, t.window_found ? t.tau : kInf);
      if (diag.ess.back() < min_ess) {
        min_ess = diag.ess.back();
        min_ess_parameter = k;
      }
    }
  };
  add(TauPerParameter(chain, num_walkers, dim, diag.burn_in, steps, team));
  // The reported quantities, computed from the kept states (ensemble_sampler.h).
  int reported_from = -1;  // index in diag.tau where they start (-1: none)
  if (options.reported && options.reported_dim > 0 && kept > 0) {
    reported->Fill(chain, num_walkers, dim, diag.burn_in, steps, options, team);
    reported_from = static_cast<int>(diag.tau.size());
    add(TauPerParameter(reported->values, num_walkers, options.reported_dim, diag.burn_in, steps,
                        team));
  }
  // Names "parameter k" for state coordinates and "reported quantity k" past them.
  auto name = [reported_from](int k) {
    return reported_from >= 0 && k >= reported_from
               ? "reported quantity " + std::to_string(k - reported_from)
               : "parameter " + std::to_string(k);
  };
  const double needed = options.min_tau_multiple * max_tau;
  const bool long_enough = kept > needed;
  const bool enough_ess = min_ess >= options.target_ess;
  diag.converged = long_enough && enough_ess && no_window_parameter < 0;
  diag.max_tau = max_tau;

  std::ostringstream reason;
  reason << kept << " post-burn-in steps " << (long_enough ? ">" : "<=") << " "
         << FormatNumber(options.min_tau_multiple) << " x max tau (" << FormatNumber(max_tau)
         << ") = " << FormatNumber(needed) << "; min ESS " << FormatNumber(min_ess) << " ("
         << name(min_ess_parameter) << ") " << (enough_ess ? ">=" : "<") << " target "
         << FormatNumber(options.target_ess);
  if (no_window_parameter >= 0) {
    reason << "; no tau estimate for " << name(no_window_parameter)
           << " (chain too short, or a walker never moved)";
  }
  diag.reason = reason.str();
  return diag;
}

// The progress line: rewritten in place on stderr, first shown after 1 s, then at most
// every 0.25 s so that it costs nothing next to the sampling.
class ProgressLine {
 public:
  ProgressLine(const SamplerOptions& options, std::chrono::steady_clock::time_point start)
      : options_(options), start_(start), last_(start) {}

  ~ProgressLine() {
    if (shown_ && terminal_) std::fputc('\n', stderr);
  }

  // last: the final update, drawn (if the line is shown at all) whatever the time since the
  // previous one, so that the line left on screen is the final state.
  void Update(int steps, const Diagnostics* last_check, double acceptance, bool last) {
    if (!options_.progress) return;
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    if (elapsed <= 1.0) return;
    // On a terminal the line is rewritten 4 times a second; into a log file or pipe (CI,
    // scripts) a new line is written only every 10 s, so logs stay readable.
    const double every = terminal_ ? 0.25 : 10.0;
    if (!last && std::chrono::duration<double>(now - last_).count() < every) return;
    last_ = now;
    shown_ = true;
    std::ostringstream line;
    if (!options_.progress_label.empty()) line << options_.progress_label << ": ";
    line << "step " << steps << "/" << options_.max_steps << "  acceptance "
         << FormatNumber(acceptance, 2);
    if (last_check != nullptr && !last_check->tau.empty()) {
      line << "  max tau "
           << FormatNumber(*std::max_element(last_check->tau.begin(), last_check->tau.end()))
           << "  min ESS "
           << FormatNumber(*std::min_element(last_check->ess.begin(), last_check->ess.end())) << "/"
           << FormatNumber(options_.target_ess);
    }
    line << "  " << FormatNumber(elapsed) << " s";
    // Trailing spaces clear what a longer previous line left behind.
    if (terminal_) {
      std::fprintf(stderr, "\r%s     ", line.str().c_str());
    } else {
      std::fprintf(stderr, "%s\n", line.str().c_str());
    }
    std::fflush(stderr);
  }

 private:
  const SamplerOptions& options_;
  const std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_;
  bool shown_ = false;
  const bool terminal_ = ::isatty(STDERR_FILENO) != 0;
};

// The step of the check after one at `steps` (whose diagnostics are `diag`): the first
// multiple of check_interval at least spacing = max(check_interval, check_fraction * steps)
// after the last multiple at or before `steps`, or max_steps if that comes first; sooner where
// `diag` predicts convergence before it: at the step where the next check's burn-in (burn_in_taus x
// max tau) and the kept steps both criteria need at that tau (min_tau_multiple x tau, and
// target_ess x tau / walkers) are reached, but at least spacing / 4 later. A chain that needs 310
// steps then stops at 325, not 400; a tau that keeps growing costs at most four times the checks.
int NextCheck(int steps, const Diagnostics& diag, int num_walkers, const SamplerOptions& options) {
  const int64_t interval = options.check_interval;
  const double spacing = std::max(static_cast<double>(interval), options.check_fraction * steps);
  // From the grid point at or before `steps`: an early check keeps the grid's next one.
  const int64_t grid = steps - steps % interval;
  int64_t next = static_cast<int64_t>(std::ceil((grid + spacing) / interval)) * interval;
  if (std::isfinite(diag.max_tau) && diag.max_tau > 0) {
    const double kept =
        diag.max_tau * std::max(options.min_tau_multiple, options.target_ess / num_walkers);
    const double predicted = std::ceil(options.burn_in_taus * diag.max_tau) + std::floor(kept) + 1;
    if (predicted < static_cast<double>(next)) {
      next = std::max(static_cast<int64_t>(predicted),
                      steps + static_cast<int64_t>(std::ceil(spacing / 4)));
    }
  }
  next = std::max<int64_t>(next, steps + 1);
  return static_cast<int>(std::min<int64_t>(next, options.max_steps));
}

// FNV-1a over what determines a run's chain: the dimensions, the options that steer the
// steps and the checks, the seed and the initial positions (not the threads: the chain does
// not depend on them).
uint64_t RunFingerprint(const BlockedTarget& target, int dim, const std::vector<double>& initial,
                        const SamplerOptions& o) {
  uint64_t h = 1469598103934665603ULL;
  auto mix = [&h](const void* data, size_t n) {
    const unsigned char* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ULL;
    }
  };
  const int64_t ints[] = {dim,
                          target.stretch_dim,
                          target.aux_dim,
                          target.conditional_every,
                          o.max_steps,
                          o.check_interval,
                          static_cast<int64_t>(o.seed),
                          o.reported ? o.reported_dim : -1};
  const double reals[] = {o.check_fraction, o.target_ess, o.min_tau_multiple, o.burn_in_taus,
                          o.stretch_a};
  mix(ints, sizeof(ints));
  mix(reals, sizeof(reals));
  mix(initial.data(), initial.size() * sizeof(double));
  // The independence move: its proposal steers the chain only when the move is on.
  mix(&o.independence_fraction, sizeof(o.independence_fraction));
  if (o.independence_fraction > 0.0) {
    const int64_t nu = o.independence_nu;
    mix(&nu, sizeof(nu));
    mix(o.independence_mean.data(), o.independence_mean.size() * sizeof(double));
    const int d = target.stretch_dim;
    for (int i = 0; i < d; ++i) {
      mix(&o.independence_cholesky[static_cast<size_t>(i) * d], (i + 1) * sizeof(double));
    }
    const int64_t box = o.independence_lower.empty() ? 0 : 1;
    mix(&box, sizeof(box));
    mix(o.independence_lower.data(), o.independence_lower.size() * sizeof(double));
    mix(o.independence_upper.data(), o.independence_upper.size() * sizeof(double));
  }
  return h;
}

}  // namespace

bool SamplerOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    *error = "sampler options: " + message;
    return false;
  };
  if (max_steps < 1) return fail("max_steps must be >= 1");
  if (check_interval < 1) return fail("check_interval must be >= 1");
  if (!(check_fraction >= 0.0) || !(check_fraction <= 1.0)) {
    return fail("check_fraction must be in [0, 1]");
  }
  if (!(target_ess >= 0.0) || !std::isfinite(target_ess)) {
    return fail("target_ess must be finite and >= 0");
  }
  if (!(min_tau_multiple >= 0.0) || !std::isfinite(min_tau_multiple)) {
    return fail("min_tau_multiple must be finite and >= 0");
  }
  if (!(burn_in_taus >= 0.0) || !std::isfinite(burn_in_taus)) {
    return fail("burn_in_taus must be finite and >= 0");
  }
  if (!(stretch_a > 1.0) || !std::isfinite(stretch_a)) {
    return fail("stretch_a must be finite and > 1");
  }
  if (num_threads < 1) return fail("num_threads must be >= 1");
  if (!(independence_fraction >= 0.0) || !(independence_fraction <= 1.0)) {
    return fail("independence_fraction must be in [0, 1]");
  }
  // Above ~30 degrees of freedom the t is a Gaussian in all but the far tails; the cap keeps
  // the per-proposal draws (nu normals) bounded.
  if (independence_nu < 1 || independence_nu > 100) {
    return fail("independence_nu must be in [1, 100]");
  }
  if (reported && reported_dim < 1) return fail("reported_dim must be >= 1 when reported is set");
  return true;
}

bool RunEnsembleSampler(const std::vector<LogDensity>& log_density_per_thread, int dim,
                        const std::vector<double>& initial, const SamplerOptions& options,
                        SamplerResult* result, std::string* error) {
  BlockedTarget target;
  target.stretch_dim = dim;
  for (const LogDensity& f : log_density_per_thread) {
    if (!f) {
      *error = "ensemble sampler: an empty log-density function was given";
      return false;
    }
    target.log_density.push_back([&f](const double* state, double*) { return f(state); });
  }
  return RunEnsembleSampler(target, dim, initial, options, result, error);
}

bool RunEnsembleSampler(const BlockedTarget& target, int dim, const std::vector<double>& initial,
                        const SamplerOptions& options, SamplerResult* result, std::string* error) {
  CHECK(result != nullptr);
  CHECK(error != nullptr);
  const auto start = std::chrono::steady_clock::now();
  if (!options.IsValid(error)) return false;
  if (dim < 1) {
    *error = "ensemble sampler: dim must be >= 1, got " + std::to_string(dim);
    return false;
  }
  const int stretch_dim = target.stretch_dim;
  if (stretch_dim < 1 || stretch_dim > dim || target.aux_dim < 0) {
    *error = "ensemble sampler: stretch block of " + std::to_string(stretch_dim) +
             " coordinates and aux_dim " + std::to_string(target.aux_dim) +
             " do not fit dim = " + std::to_string(dim);
    return false;
  }
  const auto& log_density_per_thread = target.log_density;
  if (log_density_per_thread.empty()) {
    *error = "ensemble sampler: no log-density function given";
    return false;
  }
  for (const BlockedTarget::Density& f : log_density_per_thread) {
    if (!f) {
      *error = "ensemble sampler: an empty log-density function was given";
      return false;
    }
  }
  if (target.conditional_every < 1) {
    *error = "ensemble sampler: conditional_every must be >= 1";
    return false;
  }
  if (stretch_dim < dim) {
    bool ok = target.conditional.size() >= log_density_per_thread.size();
    for (const BlockedTarget::Conditional& f : target.conditional) ok = ok && static_cast<bool>(f);
    if (!ok) {
      *error = "ensemble sampler: a blocked target needs a conditional update per thread";
      return false;
    }
  }
  if (initial.empty() || initial.size() % dim != 0) {
    *error = "ensemble sampler: initial has " + std::to_string(initial.size()) +
             " values, not a positive multiple of dim = " + std::to_string(dim);
    return false;
  }
  const size_t walkers_size = initial.size() / dim;
  if (walkers_size > static_cast<size_t>(std::numeric_limits<int>::max())) {
    *error = "ensemble sampler: too many walkers";
    return false;
  }
  const int num_walkers = static_cast<int>(walkers_size);
  if (num_walkers % 2 != 0 || num_walkers < 2 * stretch_dim + 2) {
    *error = "ensemble sampler: need an even number of walkers >= 2 * dim + 2 = " +
             std::to_string(2 * stretch_dim + 2) + ", got " + std::to_string(num_walkers);
    return false;
  }
  // The chain keeps every step of every walker (a position and a log density): refused
  // before sampling when its largest size would not fit in memory comfortably.
  constexpr double kMaxChainBytes = 4.0 * (1LL << 30);
  const double chain_bytes = static_cast<double>(num_walkers) * options.max_steps * (dim + 1) *
                             sizeof(double);
  if (chain_bytes > kMaxChainBytes) {
    char text[240];
    std::snprintf(text, sizeof(text),
                  "the MCMC chain could reach %.1f GB (%d walkers x %d steps x %d values), above "
                  "the 4 GB limit: lower --max_steps or --walkers",
                  chain_bytes / (1LL << 30), num_walkers, options.max_steps, dim + 1);
    *error = text;
    return false;
  }
  for (double v : initial) {
    if (!std::isfinite(v)) {
      *error = "ensemble sampler: initial positions must be finite";
      return false;
    }
  }
  if (!SpansAllDirections(initial, num_walkers, dim, stretch_dim, error)) return false;
  if (options.independence_fraction > 0.0) {
    const size_t d = static_cast<size_t>(stretch_dim);
    bool ok =
        options.independence_mean.size() == d && options.independence_cholesky.size() == d * d;
    for (size_t i = 0; ok && i < d; ++i) {
      ok = std::isfinite(options.independence_mean[i]) &&
           options.independence_cholesky[i * d + i] > 0.0;
      for (size_t j = 0; ok && j <= i; ++j)
        ok = std::isfinite(options.independence_cholesky[i * d + j]);
    }
    if (!ok) {
      *error = "ensemble sampler: the independence move needs a finite mean of " +
               std::to_string(d) + " values and a " + std::to_string(d) + " x " +
               std::to_string(d) +
               " lower Cholesky factor with finite entries and a positive "
               "diagonal";
      return false;
    }
    const std::vector<double>& lo = options.independence_lower;
    const std::vector<double>& hi = options.independence_upper;
    bool box_ok = lo.size() == hi.size() && (lo.empty() || lo.size() == d);
    for (size_t i = 0; box_ok && i < lo.size(); ++i) {
      box_ok = !std::isnan(lo[i]) && !std::isnan(hi[i]) && lo[i] < hi[i];
    }
    if (!box_ok) {
      *error = "ensemble sampler: the independence move's box needs " + std::to_string(d) +
               " lower and upper bounds, each lower below its upper (or none)";
      return false;
    }
  }

  const int wanted_threads = std::min(
      {options.num_threads, static_cast<int>(log_density_per_thread.size()), num_walkers / 2});
  ThreadTeam team(wanted_threads);
  EnsembleSampler sampler(target, dim, num_walkers, options, &team);
  if (!sampler.Initialise(initial, error)) return false;

  SamplerResult out;
  out.num_walkers = num_walkers;
  out.dim = dim;
  out.num_threads_used = team.size();
  const size_t state_size = static_cast<size_t>(num_walkers) * dim;
  // Room for the first check interval; the vectors grow geometrically after that.
  out.chain.reserve(state_size * std::min(options.max_steps, options.check_interval));
  out.log_prob.reserve(static_cast<size_t>(num_walkers) *
                       std::min(options.max_steps, options.check_interval));

  ProgressLine progress(options, start);
  Diagnostics diag;
  ReportedValues reported;
  bool have_check = false;
  int steps = 0;
  int next_check = std::min(options.check_interval, options.max_steps);
  const uint64_t fingerprint = RunFingerprint(target, dim, initial, options);
  if (!options.checkpoint_path.empty()) {
    SamplerCheckpoint saved;
    std::string unreadable;
    // A checkpoint is taken right after a check: redoing that check (deterministic) restores
    // the diagnostics the loop carries. One that is there but damaged is said, not resumed.
    const bool read = ReadSamplerCheckpoint(options.checkpoint_path, &saved, &unreadable);
    std::error_code ec;
    if (!read && std::filesystem::exists(options.checkpoint_path, ec)) {
      out.checkpoint_discarded = unreadable + ": discarded, the MCMC starts afresh";
    }
    if (read && saved.fingerprint == fingerprint && saved.steps >= 1 &&
        saved.steps < options.max_steps &&
        saved.chain.size() == static_cast<size_t>(saved.steps) * state_size &&
        saved.chain_log_prob.size() == static_cast<size_t>(saved.steps) * num_walkers &&
        sampler.Import(saved, saved.steps)) {
      out.chain = std::move(saved.chain);
      out.log_prob = std::move(saved.chain_log_prob);
      steps = saved.steps;
      next_check = saved.next_check;
      diag = Check(out.chain, num_walkers, dim, steps, saved.previous_max_tau, options, &team,
                   &reported);
      have_check = true;
      out.resumed_from_step = steps;
    }
  }
  auto last_checkpoint = std::chrono::steady_clock::now();
  while (steps < options.max_steps) {
    sampler.Step(&out.chain, &out.log_prob);
    ++steps;
    bool stop = steps == options.max_steps;
    if (steps == next_check) {
      const double previous_max_tau = have_check ? diag.max_tau : kInf;
      diag = Check(out.chain, num_walkers, dim, steps, previous_max_tau, options, &team, &reported);
      have_check = true;
      stop = stop || diag.converged;
      next_check = NextCheck(steps, diag, num_walkers, options);
      const auto now = std::chrono::steady_clock::now();
      if (!stop && !options.checkpoint_path.empty() &&
          std::chrono::duration<double>(now - last_checkpoint).count() >=
              options.checkpoint_seconds) {
        SamplerCheckpoint c;
        c.fingerprint = fingerprint;
        c.steps = steps;
        c.next_check = next_check;
        c.previous_max_tau = previous_max_tau;
        sampler.Export(&c);
        c.chain = out.chain;
        c.chain_log_prob = out.log_prob;
        std::string write_error;
        // A checkpoint that cannot be written costs the resume, not the run.
        if (!WriteSamplerCheckpoint(options.checkpoint_path, c, &write_error)) {
          LOG(WARNING) << write_error;
        }
        last_checkpoint = now;
      }
    }
    if (options.progress) {
      // All moves' acceptance: stretch and independence.
      int64_t total = 0;
      for (int64_t a : sampler.accepted()) total += a;
      for (int64_t a : sampler.independence_accepted()) total += a;
      progress.Update(steps, have_check ? &diag : nullptr,
                      static_cast<double>(total) / (static_cast<double>(steps) * num_walkers),
                      stop);
    }
    if (stop) break;
  }

  out.num_steps = steps;
  out.burn_in = diag.burn_in;
  if (options.reported && options.reported_dim > 0) {
    reported.Fill(out.chain, num_walkers, dim, 0, steps, options, &team);
    out.reported = std::move(reported.values);
  }
  // The state's coordinates only (the reported quantities' are the caller's to measure).
  const size_t state_entries = std::min(diag.tau.size(), static_cast<size_t>(dim));
  out.tau.assign(diag.tau.begin(), diag.tau.begin() + state_entries);
  out.ess.assign(diag.ess.begin(), diag.ess.begin() + state_entries);
  out.converged = diag.converged;
  out.stop_reason =
      (diag.converged ? "converged after " + std::to_string(steps) + " steps: "
                      : "not converged at max_steps = " + std::to_string(steps) + ": ") +
      diag.reason;
  out.acceptance_fraction.resize(num_walkers);
  double sum = 0.0;
  int walkers_with_stretch = 0;
  int64_t independence_accepted = 0;
  for (int w = 0; w < num_walkers; ++w) {
    const int64_t stretch_proposed = steps - sampler.independence_proposed()[w];
    out.acceptance_fraction[w] =
        stretch_proposed > 0 ? static_cast<double>(sampler.accepted()[w]) / stretch_proposed : NAN;
    if (stretch_proposed > 0) {
      sum += out.acceptance_fraction[w];
      ++walkers_with_stretch;
    }
    out.independence_proposed += sampler.independence_proposed()[w];
    independence_accepted += sampler.independence_accepted()[w];
  }
  out.mean_acceptance = walkers_with_stretch > 0 ? sum / walkers_with_stretch : NAN;
  if (out.independence_proposed > 0) {
    out.independence_acceptance =
        static_cast<double>(independence_accepted) / out.independence_proposed;
  }
  if (stretch_dim < dim) {
    double c = 0.0;
    for (double a : sampler.conditional_acceptance()) c += a;
    const int64_t updates = (steps + target.conditional_every - 1) / target.conditional_every;
    out.conditional_acceptance = c / (static_cast<double>(updates) * num_walkers);
  }
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  *result = std::move(out);
  return true;
}

std::vector<size_t> SamplerResult::ThinnedStates(int max_states) const {
  const size_t first = static_cast<size_t>(burn_in) * num_walkers;
  const size_t kept = static_cast<size_t>(num_steps - burn_in) * num_walkers;
  const size_t n = std::min<size_t>(kept, static_cast<size_t>(std::max(1, max_states)));
  std::vector<size_t> out(n);
  for (size_t t = 0; t < n; ++t) out[t] = first + t * kept / n;
  return out;
}

}  // namespace ccdpsf::fit
