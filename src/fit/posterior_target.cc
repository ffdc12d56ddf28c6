#include "ccdpsf/fit/posterior_target.h"

#include <algorithm>
#include <cmath>

#include "Eigen/Cholesky"
#include "Eigen/Core"
#include "ccdpsf/random.h"

namespace ccdpsf::fit {

PosteriorTarget::PosteriorTarget(const FitModel& model, const std::vector<double>& theta_map,
                                 const std::vector<double>& fisher,
                                 const PosteriorTargetOptions& options)
    : model_(model),
      coords_(model),
      proposal_scale_(options.proposal_scale),
      position_update_every_(std::max(1, options.position_update_every)) {
  const int theta_dim = model.dim();
  const std::vector<double>& lo = model.lower();
  const std::vector<double>& hi = model.upper();
  bounds_ = {lo[kDefocusPx],   hi[kDefocusPx],   lo[kCcdSigmaXPx],
             hi[kCcdSigmaXPx], lo[kCcdSigmaYPx], hi[kCcdSigmaYPx]};
  // The split is integrated out only where the model depends on the totals alone, and only
  // with CCD widths bounded away from zero (else W(t) diverges when t_x = t_y). The
  // brighter-fatter growth adds to the CCD widths alone (not to the totals), so with it the
  // split is sampled.
  marginal_ = options.marginal_defocus &&
              model.options().model.sampling == model::Sampling::kIntegrated &&
              model.options().model.defocus == model::DefocusKind::kGaussian &&
              !model.through_focus() && bounds_.sigma_x_lower > 0 && bounds_.sigma_y_lower > 0 &&
              !model.options().HasEffect(model::EffectKind::kBrighterFatter);
  num_shared_ = model.NumSharedParams() - (marginal_ ? 1 : 0);
  const int dim = theta_dim - (marginal_ ? 1 : 0);

  std::vector<double> phi_map(theta_dim);
  coords_.ToSampling(theta_map.data(), phi_map.data());
  const std::vector<double> jac = coords_.Jacobian(phi_map.data());
  std::vector<double> lower(dim), upper(dim);
  for (int i = 0; i < dim; ++i) {
    const int p = PhiIndex(i);
    names_.push_back(coords_.names()[p]);
    state_map_.push_back(phi_map[p]);
    lower[i] = lo[p];
    upper[i] = hi[p];
  }
  // Fisher information in state coordinates: J^T F J restricted to the state's coordinates.
  std::vector<double> f_state(static_cast<size_t>(dim) * dim, 0.0);
  for (int a = 0; a < dim; ++a) {
    for (int b = 0; b < dim; ++b) {
      const int pa = PhiIndex(a), pb = PhiIndex(b);
      double sum = 0.0;
      for (int i = 0; i < theta_dim; ++i) {
        const double ja = jac[i * theta_dim + pa];
        if (ja == 0.0) continue;
        for (int j = 0; j < theta_dim; ++j) {
          sum += ja * fisher[i * theta_dim + j] * jac[j * theta_dim + pb];
        }
      }
      f_state[a * dim + b] = sum;
    }
  }
  laplace_ = ComputeLaplace(names_, lower, upper, state_map_, f_state,
                            !marginal_ && !model.through_focus());

  stretch_dim_ = dim;
  // With one exposure a conditional move costs a second render per step for only two
  // coordinates; the ensemble over all six is cheaper there (measured on the demo exposure:
  // 6.6 s against 8.0 s of CPU to the same ESS).
  // Nor with defocus_offset (pixel_centre): it moves the image like every exposure's position,
  // so shared stretch moves with the positions held (and conditional position moves with the
  // offset held) both take tiny steps (measured, five exposures: tau ~770, not converged at
  // 20 000 steps in 38 s; all in the ensemble: converged in 2.9 s).
  const int n = model.num_exposures();
  if (!options.positions_by_conditional || n < 2 ||
      model.options().HasEffect(model::EffectKind::kDefocusOffset)) {
    return;
  }
  coupling_.assign(n, std::vector<double>(2 * num_shared_));
  chol_.resize(n);
  chol_inverse_.resize(n);
  for (int k = 0; k < n; ++k) {
    const int px = num_shared_ + 2 * k, py = px + 1;
    const double p00 = f_state[px * dim + px], p01 = f_state[px * dim + py],
                 p11 = f_state[py * dim + py];
    const double det = p00 * p11 - p01 * p01;
    if (!(p00 > 0 && det > 0 && std::isfinite(det))) return;  // keep positions in the ensemble
    // Sigma = P^-1.
    const double s00 = p11 / det, s01 = -p01 / det, s11 = p00 / det;
    for (int a = 0; a < num_shared_; ++a) {
      const double cx = f_state[px * dim + a], cy = f_state[py * dim + a];
      coupling_[k][a] = -(s00 * cx + s01 * cy);
      coupling_[k][num_shared_ + a] = -(s01 * cx + s11 * cy);
    }
    const double l00 = std::sqrt(s00), l10 = s01 / l00, l11 = std::sqrt(s11 - l10 * l10);
    if (!(l11 > 0)) return;
    chol_[k] = {l00, 0.0, l10, l11};
    chol_inverse_[k] = {1.0 / l00, 0.0, -l10 / (l00 * l11), 1.0 / l11};
  }
  stretch_dim_ = num_shared_;
}

bool PosteriorTarget::LaplaceProposal(double scale, std::vector<double>* mean,
                                      std::vector<double>* cholesky) const {
  const int d = stretch_dim_;
  const int n = laplace_.dim;
  if (!(scale > 0.0) || !std::isfinite(scale) || d > n ||
      laplace_.covariance.size() != static_cast<size_t>(n) * n ||
      laplace_.eigenvectors.size() != static_cast<size_t>(n) * n ||
      laplace_.eigen_sd.size() != static_cast<size_t>(n) || laplace_.scales.size() !=
      static_cast<size_t>(n)) {
    return false;
  }
  // The covariance of the constrained subspace, and along each direction the data constrain
  // less than the prior does (an eigenvector of the prior-scaled information with sd above
  // 1 / sqrt(12) of the prior's widths) the sd of a uniform spread across the prior: the
  // posterior there is the prior's, cut by its bounds, which the move's box then applies.
  // (Without it the move would be off and the stretch moves alone would have to cross the
  // prior: on bench/fit_benchmark.cc's catalogue series with boundary_shift, not converged in
  // 20 000 steps.)
  Eigen::MatrixXd full(n, n);
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) full(a, b) = laplace_.covariance[static_cast<size_t>(a) * n + b];
  }
  for (int j = 0; j < n; ++j) {
    if (!(laplace_.eigen_sd[j] > kUnconstrainedSdFraction)) continue;
    Eigen::VectorXd v(n);
    for (int i = 0; i < n; ++i) {
      v[i] = laplace_.eigenvectors[static_cast<size_t>(i) * n + j] * laplace_.scales[i];
    }
    full += kUnconstrainedSdFraction * kUnconstrainedSdFraction * v * v.transpose();
  }
  // The marginal of a Gaussian on a block is the block of its covariance.
  const Eigen::MatrixXd block = scale * scale * full.topLeftCorner(d, d);
  if (!block.allFinite()) return false;
  const Eigen::LLT<Eigen::MatrixXd> llt(block);
  if (llt.info() != Eigen::Success) return false;
  const Eigen::MatrixXd l = llt.matrixL();
  if (!l.allFinite() || !(l.diagonal().minCoeff() > 0.0)) return false;
  mean->assign(state_map_.begin(), state_map_.begin() + d);
  cholesky->assign(static_cast<size_t>(d) * d, 0.0);
  for (int a = 0; a < d; ++a) {
    for (int b = 0; b <= a; ++b) (*cholesky)[static_cast<size_t>(a) * d + b] = l(a, b);
  }
  return true;
}

void PosteriorTarget::ProposalBox(std::vector<double>* lower, std::vector<double>* upper) const {
  lower->assign(stretch_dim_, -INFINITY);
  upper->assign(stretch_dim_, INFINITY);
  for (int i = 0; i < stretch_dim_; ++i) {
    const int p = PhiIndex(i);
    if (!coords_.IsIdentity(p)) continue;
    (*lower)[i] = model_.lower()[p];
    (*upper)[i] = model_.upper()[p];
  }
}

int PosteriorTarget::PhiIndex(int i) const {
  // State [core shared (5, or 4 without the integrated-out defocus) | trailing shared
  // (best_focus_um, flux ratios) | positions]; theta [shared (5) | positions | trailing].
  const int core = marginal_ ? kNumShared - 1 : kNumShared;
  const int trailing = model_.NumTrailing();
  if (i < core) return marginal_ && i >= kDefocusPx ? i + 1 : i;
  if (i < core + trailing) return kNumShared + 2 * model_.num_exposures() + (i - core);
  return kNumShared + (i - core - trailing);
}

bool PosteriorTarget::LikelihoodTheta(const double* state, double* theta,
                                      double* log_weight) const {
  thread_local std::vector<double> phi;
  phi.resize(model_.dim());
  for (int i = 0; i < dim(); ++i) phi[PhiIndex(i)] = state[i];
  if (marginal_) {
    double lo, hi;
    if (!AllowedDefocus(phi[kCcdSigmaXPx], phi[kCcdSigmaYPx], bounds_, &lo, &hi)) return false;
    phi[kDefocusPx] = lo;
    const double w = DefocusMarginalWeight(phi[kCcdSigmaXPx], phi[kCcdSigmaYPx], lo, hi);
    if (!(w > 0)) return false;
    *log_weight = std::log(w);
    if (!coords_.FromSampling(phi.data(), theta)) return false;
  } else {
    if (!coords_.FromSampling(phi.data(), theta)) return false;
    *log_weight = coords_.LogJacobian(phi.data());
  }
  return model_.InsidePrior(theta);
}

bool PosteriorTarget::ToTheta(const double* state, double u, double* theta) const {
  std::vector<double> phi(model_.dim());
  for (int i = 0; i < dim(); ++i) phi[PhiIndex(i)] = state[i];
  if (marginal_) {
    double lo, hi;
    if (!AllowedDefocus(phi[kCcdSigmaXPx], phi[kCcdSigmaYPx], bounds_, &lo, &hi)) return false;
    phi[kDefocusPx] = DefocusQuantile(phi[kCcdSigmaXPx], phi[kCcdSigmaYPx], lo, hi, u);
  }
  return coords_.FromSampling(phi.data(), theta);
}

double PosteriorTarget::LogDensity(FitEvaluator* evaluator, const double* state,
                                   double* aux) const {
  thread_local std::vector<double> theta;
  theta.resize(model_.dim());
  double log_weight = 0.0;
  if (!LikelihoodTheta(state, theta.data(), &log_weight) || !std::isfinite(log_weight)) {
    return -INFINITY;
  }
  // The Gaussian prior's log density (gaussian_prior.h; 0 without one). It names no defocus,
  // so it stays outside the defocus integral of marginal mode; and no position, so the
  // positions' conditional moves (ConditionalUpdate), which change one exposure's
  // log-likelihood at a time, leave it as it is. aux holds the log-likelihoods alone.
  double total = log_weight + model_.LogPrior(theta.data());
  for (int k = 0; k < model_.num_exposures(); ++k) {
    const double l = evaluator->ExposureLogLikelihood(theta.data(), k);
    if (!std::isfinite(l)) return -INFINITY;
    if (aux != nullptr) aux[k] = l;
    total += l;
  }
  return total;
}

double PosteriorTarget::ConditionalUpdate(FitEvaluator* evaluator, double* state, double* aux,
                                          double* log_prob, std::mt19937_64& engine) const {
  thread_local std::vector<double> theta;
  theta.resize(model_.dim());
  double log_weight = 0.0;
  if (!LikelihoodTheta(state, theta.data(), &log_weight)) return 0.0;
  const int n = model_.num_exposures();
  int accepted = 0;
  for (int k = 0; k < n; ++k) {
    // Always three draws per exposure, in this order.
    const double z0 = StandardNormal(engine), z1 = StandardNormal(engine);
    const double u = Uniform01(engine);
    const int sx = num_shared_ + 2 * k;
    double mean[2] = {state_map_[sx], state_map_[sx + 1]};
    for (int a = 0; a < num_shared_; ++a) {
      const double delta = state[a] - state_map_[a];
      mean[0] += coupling_[k][a] * delta;
      mean[1] += coupling_[k][num_shared_ + a] * delta;
    }
    const std::array<double, 4>& l = chol_[k];
    const std::array<double, 4>& li = chol_inverse_[k];
    const double s = proposal_scale_;
    const double new_x = mean[0] + s * l[0] * z0;
    const double new_y = mean[1] + s * (l[2] * z0 + l[3] * z1);
    const int ix = FitModel::XIndex(k), iy = FitModel::YIndex(k);
    if (!(new_x >= model_.lower()[ix] && new_x <= model_.upper()[ix] &&
          new_y >= model_.lower()[iy] && new_y <= model_.upper()[iy])) {
      continue;
    }
    const double dx = state[sx] - mean[0], dy = state[sx + 1] - mean[1];
    const double r0 = li[0] * dx / s, r1 = (li[2] * dx + li[3] * dy) / s;
    const double log_q_current = -0.5 * (r0 * r0 + r1 * r1);
    const double log_q_new = -0.5 * (z0 * z0 + z1 * z1);
    theta[ix] = new_x;
    theta[iy] = new_y;
    const double l_new = evaluator->ExposureLogLikelihood(theta.data(), k);
    if (std::isfinite(l_new) && std::log(u) < l_new - aux[k] + log_q_current - log_q_new) {
      state[sx] = new_x;
      state[sx + 1] = new_y;
      *log_prob += l_new - aux[k];
      aux[k] = l_new;
      ++accepted;
    } else {
      theta[ix] = state[sx];
      theta[iy] = state[sx + 1];
    }
  }
  return static_cast<double>(accepted) / n;
}

BlockedTarget PosteriorTarget::Make(const std::vector<FitEvaluator*>& evaluators) const {
  BlockedTarget target;
  target.stretch_dim = stretch_dim_;
  target.aux_dim = model_.num_exposures();
  target.conditional_every = position_update_every_;
  for (FitEvaluator* ev : evaluators) {
    target.log_density.push_back(
        [this, ev](const double* state, double* aux) { return LogDensity(ev, state, aux); });
    if (positions_by_conditional()) {
      target.conditional.push_back(
          [this, ev](double* state, double* aux, double* log_prob, std::mt19937_64& engine) {
            return ConditionalUpdate(ev, state, aux, log_prob, engine);
          });
    }
  }
  return target;
}

}  // namespace ccdpsf::fit
