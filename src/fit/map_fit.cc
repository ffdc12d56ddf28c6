#include "ccdpsf/fit/map_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <optional>

#include "ceres/ceres.h"
#include "glog/logging.h"
#include "internal/parallel_for.h"

namespace ccdpsf::fit {
namespace {

// The options of the one-exposure search that seeds a joint fit's PSF: one exposure's options
// (SingleExposureOptions) without boundary_shift. One exposure does not measure the boundary
// shifts (they need a series of intensities), the seed passes on only the PSF and the first
// position, and the effect makes each of the search's starts several times dearer
// (bench/fit_benchmark.cc, BM_Series12MapBoundaryShift); the joint solve starts the effect
// at its start values (FitModel::SetEffectStart).
FitModelOptions JointSeedOptions(const FitModelOptions& options) {
  FitModelOptions seed = SingleExposureOptions(options);
  seed.effects.erase(std::remove_if(seed.effects.begin(), seed.effects.end(),
                                    [](const FitEffect& e) {
                                      return e.kind == model::EffectKind::kBoundaryShift;
                                    }),
                     seed.effects.end());
  return seed;
}

// The residuals of exposure k (pixel_likelihood.h: two per valid pixel) against the parameter
// blocks of a layout (ExposureCostLayout). The model image and its derivatives come from
// FitEvaluator::ModelImageColumns, the one place a model is drawn.
class ExposureCost : public ceres::CostFunction {
 public:
  ExposureCost(const FitModel& model, int k, ExposureCostLayout layout, const Image* data_e)
      : model_(model), k_(k), layout_(std::move(layout)), evaluator_(model.NewEvaluator()) {
    const Stamp& s = model.stamps()[k];
    data_ = data_e != nullptr ? data_e->data.data() : s.electrons.data.data();
    for (size_t q = 0; q < s.valid.size(); ++q) {
      if (s.valid[q]) pixels_.push_back(static_cast<int>(q));
    }
    noise_ = StampNoise(s);
    for (const auto& block : layout_.blocks) mutable_parameter_block_sizes()->push_back(block.size);
    set_num_residuals(2 * static_cast<int>(pixels_.size()));
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    std::vector<double>& theta = theta_;
    theta.assign(model_.dim(), 0.0);
    for (const auto& [index, where] : layout_.place) {
      theta[index] = parameters[where.block][where.offset];
    }
    const bool want_jacobian = jacobians != nullptr;
    // Ceres may probe outside the bounds during a line search; a point the renderer cannot
    // draw is reported as a failed evaluation, never a crash.
    model::SpotParams p = model_.SpotFor(theta.data(), k_);
    std::string why;
    if (!model::ValidSpotParams(evaluator_->renderer_options(), p, &why)) return false;
    if (!evaluator_->ModelImageColumns(theta.data(), k_, &model_pixels_,
                                       want_jacobian ? &jacobian_ : nullptr, &columns_)) {
      return false;
    }
    const Stamp& s = model_.stamps()[k_];
    const int n = static_cast<int>(pixels_.size());
    const int nc = static_cast<int>(columns_.size());
    if (want_jacobian) {
      for (size_t b = 0; b < parameter_block_sizes().size(); ++b) {
        if (jacobians[b] != nullptr) {
          std::fill_n(jacobians[b], 2 * n * parameter_block_sizes()[b], 0.0);
        }
      }
    }
    // Each column's place (block -1: a theta index held fixed, whose derivative goes nowhere).
    std::vector<ExposureCostLayout::Place> column_place(nc, {-1, 0});
    for (int c = 0; c < nc; ++c) {
      const auto it = layout_.place.find(columns_[c]);
      if (it != layout_.place.end()) column_place[c] = it->second;
    }
    // The pedestal has no shot noise (pixel_likelihood.h, EvaluatePixelWithPedestal): its
    // column is -dr/dd, the others dr/dm times the derivative of the charge (the model less
    // the pedestal, which depends on no other parameter).
    const int pedestal_index = model_.EffectIndex(model::EffectKind::kBackground);
    const double pedestal = model_.PedestalAt(theta.data());
    PixelValue v;
    for (int i = 0; i < n; ++i) {
      const int q = pixels_[i];
      EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, data_[q], s.CensorAt(q),
                                model_pixels_[q], pedestal, noise_, true, &v);
      residuals[i] = v.r[0];
      residuals[n + i] = v.r[1];
      if (!want_jacobian) continue;
      const double* g = &jacobian_[static_cast<size_t>(q) * nc];
      for (int c = 0; c < nc; ++c) {
        const ExposureCostLayout::Place& where = column_place[c];
        if (where.block < 0 || jacobians[where.block] == nullptr) continue;
        double* block = jacobians[where.block];
        const int size = layout_.blocks[where.block].size;
        const bool is_pedestal = columns_[c] == pedestal_index;
        block[i * size + where.offset] = v.ResidualDerivative(0, g[c], is_pedestal);
        block[(n + i) * size + where.offset] = v.ResidualDerivative(1, g[c], is_pedestal);
      }
    }
    return true;
  }

 private:
  const FitModel& model_;
  const int k_;
  ExposureCostLayout layout_;
  std::unique_ptr<FitEvaluator> evaluator_;
  const double* data_;
  PixelNoise noise_;
  std::vector<int> pixels_;  // valid pixel indices
  mutable std::vector<double> theta_, model_pixels_, jacobian_;
  mutable std::vector<int> columns_;
};

// The Gaussian prior's whitened residuals (gaussian_prior.h) against the parameter blocks of
// a layout that places every parameter it names (GaussianPriorLayout): 1/2 sum r^2 is minus
// the log prior up to a constant, so a solve with this block minimises minus the log
// posterior. A named parameter the layout does not place is held at 0, as the exposures'
// blocks hold it.
class GaussianPriorCost : public ceres::CostFunction {
 public:
  GaussianPriorCost(const GaussianPriorTerm& term, ExposureCostLayout layout)
      : term_(term), layout_(std::move(layout)) {
    for (const auto& block : layout_.blocks) mutable_parameter_block_sizes()->push_back(block.size);
    set_num_residuals(term.size());
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const int n = term_.size();
    // The named parameters in a theta-shaped scratch vector (only their slots are read).
    const std::vector<int>& indices = term_.indices();
    const int span = *std::max_element(indices.begin(), indices.end()) + 1;
    std::vector<double> theta(span, 0.0);
    for (int i : indices) {
      const auto it = layout_.place.find(i);
      if (it != layout_.place.end()) {
        theta[i] = parameters[it->second.block][it->second.offset];
      }
    }
    term_.WhitenedResiduals(theta.data(), residuals);
    if (jacobians == nullptr) return true;
    for (size_t b = 0; b < layout_.blocks.size(); ++b) {
      if (jacobians[b] != nullptr) std::fill_n(jacobians[b], n * layout_.blocks[b].size, 0.0);
    }
    const std::vector<double>& w = term_.whitening();
    for (int j = 0; j < n; ++j) {
      const auto it = layout_.place.find(indices[j]);
      if (it == layout_.place.end() || jacobians[it->second.block] == nullptr) continue;
      const int size = layout_.blocks[it->second.block].size;
      for (int r = 0; r < n; ++r) {
        jacobians[it->second.block][r * size + it->second.offset] = w[r * n + j];
      }
    }
    return true;
  }

 private:
  const GaussianPriorTerm& term_;
  ExposureCostLayout layout_;
};

struct StartOutcome {
  std::vector<double> theta;
  double cost = std::numeric_limits<double>::infinity();
  bool usable = false;
  int iterations = 0;
  std::string message;
};

StartOutcome Solve(const FitModel& model, std::vector<double> theta, const MapOptions& options) {
  std::vector<ExposureCostLayout> layouts;
  for (int k = 0; k < model.num_exposures(); ++k)
    layouts.push_back(FitExposureCostLayout(model, k));
  SolveSettings settings;
  settings.max_iterations = options.max_iterations;
  settings.threads = options.solver_threads;
  const SolveOutcome o =
      SolveResidualBlocks(model, layouts, model.lower(), model.upper(), settings, nullptr, &theta);
  StartOutcome out;
  out.theta = theta;
  out.cost = o.cost;
  // A run that hit the iteration limit has not converged: it does not count as a MAP point.
  out.usable = o.usable && o.converged;
  out.iterations = o.iterations;
  out.message = o.message;
  return out;
}

// Least-squares flux for the shape in *theta (set in place), then the log-posterior: with
// a Gaussian prior its log density is added, since JointScreenStarts ranks local optima whose
// prior-bearing parameters differ. (The grid of ScreenStarts and RefinePositions move
// parameters no Gaussian prior names today, so there it adds the same to every score.)
double ScoreWithBestFlux(const FitModel& model, FitEvaluator* ev, std::vector<double>* theta) {
  const double ll = ev->BestFluxLogLikelihood(theta->data(), 0, model.num_exposures());
  return model.InsidePrior(theta->data()) ? ll + model.LogPrior(theta->data()) : -INFINITY;
}

// Positions by grid search, for pixel_centre sampling: there the moment centroid is not the
// model's centre (its kernels shift the image; measured, the centroid sits about halfway
// between the spot and the stamp centre) and the likelihood is sharp in position. One
// exposure at a time (the others stay put), with the shape in *theta, scored alone with the
// flux that best fits it: a position moves only its own exposure's likelihood, so a joint
// model need not render the others. The grid is +-0.3 px in 0.025 px steps; with
// `coarse_to_fine`, +-0.3 px in 0.05 px steps and then +-0.05 px in 0.0125 px steps around
// the best (250 renders instead of 625; the position sd is >= 0.02 px even at 7 ke-, so the
// fine step still resolves the peak).
void RefinePositions(const FitModel& model, FitEvaluator* ev, std::vector<double>* theta,
                     bool coarse_to_fine = false, int first_exposure = 0) {
  struct Pass {
    int half;
    double step;
  };
  const std::vector<Pass> passes = coarse_to_fine ? std::vector<Pass>{{6, 0.05}, {4, 0.0125}}
                                                  : std::vector<Pass>{{12, 0.025}};
  for (int k = first_exposure; k < model.num_exposures(); ++k) {
    const int ix = FitModel::XIndex(k), iy = FitModel::YIndex(k);
    for (const Pass& pass : passes) {
      const double cx = (*theta)[ix], cy = (*theta)[iy];
      double best = -INFINITY, bx = cx, by = cy;
      std::vector<double> t = *theta;
      for (int i = -pass.half; i <= pass.half; ++i) {
        for (int j = -pass.half; j <= pass.half; ++j) {
          t[ix] = cx + pass.step * i;
          t[iy] = cy + pass.step * j;
          if (!model.InsidePrior(t.data())) continue;
          const double ll = ev->BestFluxLogLikelihood(t.data(), k, k + 1);
          if (ll > best) {
            best = ll;
            bx = t[ix];
            by = t[iy];
          }
        }
      }
      (*theta)[ix] = bx;
      (*theta)[iy] = by;
    }
  }
  ScoreWithBestFlux(model, ev, theta);
}

// Calls task(i, evaluator) for i = 0..n-1 on up to `threads` threads, each with its own
// evaluator of `model`. Tasks must write only their own index's results: the outcome is then
// the same for any number of threads (the screening's starts, and so the fit, do not depend
// on --threads).
void ForEachIndex(const FitModel& model, int n, int threads,
                  const std::function<void(int, FitEvaluator*)>& task) {
  std::vector<std::unique_ptr<FitEvaluator>> evaluators(std::max(1, threads));
  internal::ParallelFor(n, threads, [&](int i, int worker) {
    if (!evaluators[worker]) evaluators[worker] = model.NewEvaluator();
    task(i, evaluators[worker].get());
  });
}

// Grid points ranked by log-likelihood (flux by least squares, positions refined once for a
// mid-range shape); returns the best `keep` as starting vectors. The grid's scores and the
// kept points' position refinements (most of a pixel_centre MAP's time) run on
// options.num_threads threads.
std::vector<std::vector<double>> ScreenStarts(const FitModel& model, const MapOptions& options) {
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  std::vector<double> base = model.MomentStart(0.5, 0.5);
  base[kDefocusPx] = 0.4;
  base[kCcdSigmaXPx] = base[kCcdSigmaYPx] = 0.3;
  RefinePositions(model, ev.get(), &base);
  std::vector<std::vector<double>> grid;
  for (double r : options.screen_airy_radii_px) {
    for (double f : options.screen_defocus_px) {
      for (double sx : options.screen_ccd_sigma_px) {
        for (double sy : options.screen_ccd_sigma_px) {
          std::vector<double> theta = base;
          theta[kAiryRadiusPx] = r;
          theta[kDefocusPx] = f;
          theta[kCcdSigmaXPx] = sx;
          theta[kCcdSigmaYPx] = sy;
          bool inside = true;
          for (int i = 1; i < kNumShared; ++i) {
            inside &= theta[i] >= model.lower()[i] && theta[i] <= model.upper()[i];
          }
          if (inside) grid.push_back(std::move(theta));
        }
      }
    }
  }
  std::vector<double> grid_ll(grid.size());
  ForEachIndex(model, static_cast<int>(grid.size()), options.num_threads,
               [&](int i, FitEvaluator* e) { grid_ll[i] = ScoreWithBestFlux(model, e, &grid[i]); });
  std::vector<std::pair<double, std::vector<double>>> scored;
  for (size_t i = 0; i < grid.size(); ++i) {
    if (std::isfinite(grid_ll[i])) scored.push_back({grid_ll[i], std::move(grid[i])});
  }
  std::stable_sort(scored.begin(), scored.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  // Kept: the best screen_keep points, and the best point of every Airy radius. The basins
  // differ mainly in the Airy radius, and the top of the ranking can lie in one wrong basin
  // (measured: a 700 nm Table-1 group, truth r = 0.411 px, whose ten best grid points all
  // led to r = 0.362 at chi^2/dof 1.63 against 1.01 at the truth).
  std::vector<bool> keep(scored.size(), false);
  std::vector<double> radii_seen;
  for (size_t i = 0; i < scored.size(); ++i) {
    const double r = scored[i].second[kAiryRadiusPx];
    const bool first_of_radius =
        std::find(radii_seen.begin(), radii_seen.end(), r) == radii_seen.end();
    if (first_of_radius) radii_seen.push_back(r);
    keep[i] = static_cast<int>(i) < options.screen_keep || first_of_radius;
  }
  std::vector<std::vector<double>> starts;
  // The positions were refined for one mid-range shape only; the likelihood is so sharp in
  // position that each kept shape gets its own refinement before the local solve (measured:
  // without it a 600 nm spot (r = 0.35 px) ended at chi^2/dof 1.3-1.8 against 1.05 near the
  // truth).
  for (size_t i = 0; i < scored.size(); ++i) {
    if (keep[i]) starts.push_back(std::move(scored[i].second));
  }
  ForEachIndex(model, static_cast<int>(starts.size()), options.num_threads,
               [&](int i, FitEvaluator* e) { RefinePositions(model, e, &starts[i]); });
  return starts;
}

// Joint pixel_centre fits: the starts come from the joint data, not from one exposure. One
// exposure cannot tell the rugged posterior's basins apart at low signal (measured on a
// simulated 7.1 ke- group: a single exposure's best point, defocus 0.17 px and CCD widths
// 0.42 px, fits it better than the truth does, but seeded from it the 10-exposure joint fit
// ended at chi^2/dof 1.28 against 0.97 at the truth). So the single-exposure search (grid
// screening, then a local solve from each kept point) runs on the first min(K, 3)
// exposures, which already separate those basins by hundreds in chi^2 at a quarter of the
// cost of twelve; every local optimum it reaches then gets the other exposures' positions
// refined, is scored on all K, and the best joint_screen_solves become the joint solve's
// starts. Local optima, not grid points, are compared: at high signal a grid point's
// distance from the nearest optimum costs more chi^2 than a wrong basin does.
std::vector<std::vector<double>> JointScreenStarts(const FitModel& model,
                                                   const MapOptions& options) {
  const int num_sub = std::min(model.num_exposures(), 3);
  std::vector<Stamp> sub_stamps(model.stamps().begin(), model.stamps().begin() + num_sub);
  std::string error;
  auto sub = FitModel::Create(sub_stamps, model.options(), &error);
  if (!sub) return {};
  // Each kept grid point's local solve and scoring is independent of the others': they run
  // on options.num_threads threads, each solve on one Ceres thread whatever that number.
  const std::vector<std::vector<double>> screened = ScreenStarts(*sub, options);
  MapOptions one_thread = options;
  one_thread.solver_threads = 1;
  std::vector<std::pair<double, std::vector<double>>> outcomes(screened.size(), {-INFINITY, {}});
  ForEachIndex(model, static_cast<int>(screened.size()), options.num_threads,
               [&](int s, FitEvaluator* ev) {
                 const StartOutcome local = Solve(*sub, screened[s], one_thread);
                 if (!local.usable) return;
                 std::vector<double> theta = model.MomentStart(local.theta[kAiryRadiusPx], 0.5);
                 // Shared and position parameters keep their indices; the sub-model's trailing
                 // ones (flux ratios) move to the full model's.
                 for (int i = 0; i < kNumShared + 2 * num_sub; ++i) theta[i] = local.theta[i];
                 for (int k = 1; k < num_sub; ++k) {
                   if (sub->RatioIndex(k) >= 0) {
                     theta[model.RatioIndex(k)] = local.theta[sub->RatioIndex(k)];
                   }
                 }
                 // Refine exposures num_sub.. only.
                 if (model.num_exposures() > num_sub) {
                   RefinePositions(model, ev, &theta, /*coarse_to_fine=*/true, num_sub);
                 }
                 outcomes[s] = {ScoreWithBestFlux(model, ev, &theta), std::move(theta)};
               });
  std::vector<std::pair<double, std::vector<double>>> scored;
  for (auto& o : outcomes) {
    if (std::isfinite(o.first)) scored.push_back(std::move(o));
  }
  std::sort(scored.begin(), scored.end(),
            [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<std::vector<double>> starts;
  for (size_t i = 0; i < scored.size(); ++i) {
    if (static_cast<int>(starts.size()) >= options.joint_screen_solves) break;
    // Local optima that agree (same basin) give one start.
    bool duplicate = false;
    for (const auto& s : starts) {
      double d = 0.0;
      for (int j = kAiryRadiusPx; j < kNumShared; ++j) d = std::max(d, std::abs(s[j] - scored[i].second[j]));
      duplicate |= d < 1e-3;
    }
    if (!duplicate) starts.push_back(std::move(scored[i].second));
  }
  return starts;
}

// Focus mode: sigma_ccd^2 = a and rate^2 = c fitted to the Gaussian variances v_k at
// distances dz_k from a trial best focus, v_k ~ a + c dz_k^2 (least squares, a >= a_min,
// c >= 0). With fixed_a >= 0, a is held there and only c is fitted. Returns the residual
// sum of squares.
double FitVarianceLaw(const std::vector<double>& v, const std::vector<double>& dz2, double a_min,
                      double fixed_a, double* a, double* c) {
  const size_t n = v.size();
  auto rss = [&](double aa, double cc) {
    double sum = 0.0;
    for (size_t k = 0; k < n; ++k) sum += std::pow(v[k] - aa - cc * dz2[k], 2);
    return sum;
  };
  auto c_given_a = [&](double aa) {
    double num = 0.0, den = 0.0;
    for (size_t k = 0; k < n; ++k) {
      num += (v[k] - aa) * dz2[k];
      den += dz2[k] * dz2[k];
    }
    return den > 0 ? std::max(0.0, num / den) : 0.0;
  };
  if (fixed_a >= 0) {
    *a = fixed_a;
    *c = c_given_a(fixed_a);
    return rss(*a, *c);
  }
  double s1 = 0, sx = 0, sxx = 0, sy = 0, sxy = 0;
  for (size_t k = 0; k < n; ++k) {
    s1 += 1;
    sx += dz2[k];
    sxx += dz2[k] * dz2[k];
    sy += v[k];
    sxy += v[k] * dz2[k];
  }
  const double det = s1 * sxx - sx * sx;
  double aa = det > 0 ? (sxx * sy - sx * sxy) / det : sy / s1;
  double cc = det > 0 ? (s1 * sxy - sx * sy) / det : 0.0;
  if (cc < 0) {  // the widths do not grow away from z0: no defocus
    cc = 0.0;
    aa = sy / s1;
  }
  if (aa < a_min) {
    aa = a_min;
    cc = c_given_a(aa);
  }
  *a = aa;
  *c = cc;
  return rss(aa, cc);
}

// The starting points of a through-focus fit (MapOptions).
std::vector<std::vector<double>> FocusStarts(const FitModel& model, const MapOptions& options) {
  const int n = model.num_exposures();
  const int f = model.FocusIndex();
  const double z_min = model.lower()[f], z_max = model.upper()[f];
  // The exposure nearest best focus: the smallest moment width.
  std::vector<double> v = model.MomentGaussianVariances(0.5);
  const int best = static_cast<int>(std::min_element(v.begin(), v.end()) - v.begin());
  // Its normal (single-focus) fit: Airy radius, flux, total widths and position there.
  double radius = 0.5, tx2 = NAN, ty2 = NAN;
  std::vector<double> single_theta;
  {
    FitModelOptions single_options = JointSeedOptions(model.options());
    single_options.through_focus = false;
    single_options.flux = FluxMode::kShared;
    std::string error;
    auto single = FitModel::Create({model.stamps()[best]}, single_options, &error);
    MapResult single_map;
    if (single && FindMap(*single, options, &single_map, &error)) {
      single_theta = single_map.theta;
      radius = single_theta[kAiryRadiusPx];
      const double d2 = single_theta[kDefocusPx] * single_theta[kDefocusPx];
      tx2 = single_theta[kCcdSigmaXPx] * single_theta[kCcdSigmaXPx] + d2;
      ty2 = single_theta[kCcdSigmaYPx] * single_theta[kCcdSigmaYPx] + d2;
    }
  }
  // Moment variances for that radius, pinned to the fitted total variance at `best` (the
  // moments in a 5 x 5 box are biased; the offset removes most of it).
  v = model.MomentGaussianVariances(radius);
  double half_ellipticity = 0.0;  // (t_x^2 - t_y^2) / 2, carried into the CCD widths
  if (std::isfinite(tx2) && std::isfinite(ty2)) {
    const double offset = 0.5 * (tx2 + ty2) - v[best];
    for (double& x : v) x += offset;
    half_ellipticity = 0.5 * (tx2 - ty2);
  }
  const double a_min = 0.06 * 0.06;
  auto dz2_for = [&](double z0) {
    std::vector<double> dz2(n);
    for (int k = 0; k < n; ++k) dz2[k] = std::pow(model.FocusPositionUm(k) - z0, 2);
    return dz2;
  };
  // Best focus that best explains the widths: a grid over the scanned range.
  // (81 points: a step of 1/80 of the range, well inside the solve's reach.)
  double z_best = 0.5 * (z_min + z_max), rss_best = INFINITY;
  for (int i = 0; i <= 80; ++i) {
    const double z0 = z_min + (z_max - z_min) * i / 80.0;
    double a, c;
    const double rss = FitVarianceLaw(v, dz2_for(z0), a_min, -1.0, &a, &c);
    if (rss < rss_best) {
      rss_best = rss;
      z_best = z0;
    }
  }
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  auto make = [&](double z0, double ccd_scale) {
    // sigma_ccd^2 and rate^2 for this best focus; with ccd_scale < 1 the CCD variance is
    // scaled down (more of each width given to the defocus) and the rate refitted.
    const std::vector<double> dz2 = dz2_for(z0);
    double a, c;
    FitVarianceLaw(v, dz2, a_min, -1.0, &a, &c);
    if (ccd_scale != 1.0) FitVarianceLaw(v, dz2, a_min, std::max(a_min, ccd_scale * a), &a, &c);
    std::vector<double> theta(model.dim());
    theta[kFluxE] = single_theta.empty() ? 0.0 : single_theta[kFluxE];
    theta[kAiryRadiusPx] = radius;
    // A rate of zero would leave z0 without a gradient: start with some defocus.
    theta[kDefocusPx] = std::max(std::sqrt(c), 0.05 * model.upper()[kDefocusPx]);
    theta[kCcdSigmaXPx] = std::sqrt(std::max(a_min, a + half_ellipticity));
    theta[kCcdSigmaYPx] = std::sqrt(std::max(a_min, a - half_ellipticity));
    theta[f] = z0;
    for (int k = 0; k < n; ++k) {
      theta[FitModel::XIndex(k)] = model.CentroidX(k);
      theta[FitModel::YIndex(k)] = model.CentroidY(k);
    }
    if (!single_theta.empty()) {
      theta[FitModel::XIndex(best)] = single_theta[FitModel::XIndex(0)];
      theta[FitModel::YIndex(best)] = single_theta[FitModel::YIndex(0)];
    }
    for (int k = 1; k < n; ++k) {
      if (model.RatioIndex(k) >= 0) theta[model.RatioIndex(k)] = model.StartFluxRatio(k);
    }
    model.SetEffectStart(theta.data());
    for (int i = 0; i < model.dim(); ++i) {
      theta[i] = std::clamp(theta[i], model.lower()[i], model.upper()[i]);
    }
    // The flux: least squares for this shape, clamped into the prior (the single fit's flux
    // is the fallback).
    ev->BestFluxLogLikelihood(theta.data(), 0, n);
    return theta;
  };
  std::vector<std::vector<double>> starts;
  for (double scale : options.start_ccd_variance_scales) starts.push_back(make(z_best, scale));
  for (double fraction : options.start_best_focus_fractions) {
    starts.push_back(make(z_min + std::clamp(fraction, 0.0, 1.0) * (z_max - z_min), 1.0));
  }
  return starts;
}

void FillResult(const FitModel& model, const StartOutcome& best, MapResult* result) {
  result->theta = best.theta;
  result->iterations = best.iterations;
  result->termination = best.message;
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  result->log_likelihood = ev->LogLikelihood(best.theta.data());
  result->log_prior = model.LogPrior(best.theta.data());
  result->chi2 = ev->ChiSquare(best.theta.data());
  // Censored pixels are bounds, not measurements: no chi^2, no degree of freedom.
  result->num_pixels = model.NumMeasuredPixels();
  result->dof = result->num_pixels - model.dim();
}

}  // namespace

bool RefineMap(const FitModel& model, std::vector<double> start, const MapOptions& options,
               MapResult* result, std::string* error) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = MapResult();
  if (static_cast<int>(start.size()) != model.dim()) {
    *error = "RefineMap: the start has " + std::to_string(start.size()) + " values, the model " +
             std::to_string(model.dim());
    return false;
  }
  for (int i = 0; i < model.dim(); ++i) {
    start[i] = std::clamp(start[i], model.lower()[i], model.upper()[i]);
  }
  const StartOutcome o = Solve(model, start, options);
  result->num_starts = 1;
  result->start_costs.push_back(o.cost);
  if (!o.usable) {
    *error = "the refit did not converge (" + o.message + " after " +
             std::to_string(o.iterations) + " iterations)";
    return false;
  }
  result->num_usable_starts = 1;
  FillResult(model, o, result);
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

ExposureCostLayout FitExposureCostLayout(const FitModel& model, int k) {
  ExposureCostLayout layout;
  auto add_block = [&](int first, int size) {
    const int block = static_cast<int>(layout.blocks.size());
    layout.blocks.push_back({first, size});
    for (int i = 0; i < size; ++i) layout.place[first + i] = {block, i};
  };
  add_block(0, kNumShared);
  add_block(FitModel::XIndex(k), 2);
  if (model.through_focus()) add_block(model.FocusIndex(), 1);
  if (model.RatioIndex(k) >= 0) add_block(model.RatioIndex(k), 1);
  const int effects = model.EffectsFirstIndex();
  if (effects >= 0) add_block(effects, model.dim() - effects);
  return layout;
}

ceres::CostFunction* NewExposureCost(const FitModel& model, int k, ExposureCostLayout layout,
                                     const Image* data_e) {
  return new ExposureCost(model, k, std::move(layout), data_e);
}

ceres::CostFunction* NewExposureCost(const FitModel& model, int k) {
  return NewExposureCost(model, k, FitExposureCostLayout(model, k));
}

ExposureCostLayout GaussianPriorLayout(const FitModel& model,
                                       const std::vector<ExposureCostLayout>& layouts) {
  ExposureCostLayout out;
  std::map<int, int> block_of_first;  // a block's first x index -> its number in `out`
  for (int index : model.gaussian_prior().indices()) {
    for (const ExposureCostLayout& layout : layouts) {
      const auto it = layout.place.find(index);
      if (it == layout.place.end()) continue;
      const ExposureCostLayout::Block& block = layout.blocks[it->second.block];
      auto [where, added] =
          block_of_first.emplace(block.first, static_cast<int>(out.blocks.size()));
      if (added) out.blocks.push_back(block);
      out.place[index] = {where->second, it->second.offset};
      break;
    }
  }
  return out;
}

ceres::CostFunction* NewGaussianPriorCost(const FitModel& model, ExposureCostLayout layout) {
  return new GaussianPriorCost(model.gaussian_prior(), std::move(layout));
}

SolveOutcome SolveResidualBlocks(const FitModel& model,
                                 const std::vector<ExposureCostLayout>& layouts,
                                 const std::vector<double>& lower, const std::vector<double>& upper,
                                 const SolveSettings& settings, const std::vector<Image>* data_e,
                                 std::vector<double>* x) {
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  for (int k = 0; k < model.num_exposures(); ++k) {
    std::vector<double*> blocks;
    for (const auto& block : layouts[k].blocks) blocks.push_back(x->data() + block.first);
    problem.AddResidualBlock(
        NewExposureCost(model, k, layouts[k], data_e != nullptr ? &(*data_e)[k] : nullptr), nullptr,
        blocks);
    for (const auto& block : layouts[k].blocks) {
      for (int j = 0; j < block.size; ++j) {
        problem.SetParameterLowerBound(x->data() + block.first, j, lower[block.first + j]);
        problem.SetParameterUpperBound(x->data() + block.first, j, upper[block.first + j]);
      }
    }
  }
  if (model.gaussian_prior().active()) {
    // The prior's block reads the parameter blocks the exposures' blocks already hold (and
    // bound): one more residual block, so the cost is minus the log posterior.
    ExposureCostLayout layout = GaussianPriorLayout(model, layouts);
    std::vector<double*> blocks;
    for (const auto& block : layout.blocks) blocks.push_back(x->data() + block.first);
    if (!blocks.empty()) {
      problem.AddResidualBlock(NewGaussianPriorCost(model, std::move(layout)), nullptr, blocks);
    }
  }
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = settings.max_iterations;
  solver.function_tolerance = settings.function_tolerance;
  solver.gradient_tolerance = settings.gradient_tolerance;
  solver.parameter_tolerance = settings.parameter_tolerance;
  solver.num_threads = settings.threads;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  SolveOutcome out;
  out.cost = summary.final_cost;
  out.usable = summary.IsSolutionUsable() && std::isfinite(summary.final_cost);
  out.converged = summary.termination_type != ceres::NO_CONVERGENCE;
  out.iterations = static_cast<int>(summary.iterations.size());
  out.message = summary.message;
  return out;
}

bool FindMap(const FitModel& model, const MapOptions& options, MapResult* result,
             std::string* error) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = MapResult();
  const bool screen =
      options.screen == MapOptions::Screen::kAlways ||
      (options.screen == MapOptions::Screen::kAuto &&
       model.options().model.sampling == model::Sampling::kPixelCentre);
  std::vector<std::vector<double>> starts;
  // Starts from this index on are fallbacks: solved only while no earlier one has succeeded.
  size_t first_fallback = std::numeric_limits<size_t>::max();
  if (model.through_focus()) {
    starts = FocusStarts(model, options);
  } else if (model.num_exposures() > 1 && screen) {
    starts = JointScreenStarts(model, options);
    first_fallback = starts.size();
    starts.push_back(model.MomentStart(0.5, 0.5));
  } else if (model.num_exposures() > 1) {
    // Joint fit: the multi-start search runs on the first exposure alone (12x cheaper for
    // 12 exposures), and its PSF seeds the joint solve; positions start at the centroids.
    // The moment start with the single fit's radius is kept as a fallback seed.
    std::string single_error;
    auto single = FitModel::Create({model.stamps()[0]}, JointSeedOptions(model.options()),
                                   &single_error);
    MapResult single_map;
    if (single && FindMap(*single, options, &single_map, &single_error)) {
      const double r = single_map.theta[kAiryRadiusPx];
      std::vector<double> seeded = model.MomentStart(r, 0.5);
      for (int i = 0; i < kNumShared; ++i) {
        seeded[i] = std::clamp(single_map.theta[i], model.lower()[i], model.upper()[i]);
      }
      seeded[FitModel::XIndex(0)] = single_map.theta[FitModel::XIndex(0)];
      seeded[FitModel::YIndex(0)] = single_map.theta[FitModel::YIndex(0)];
      starts.push_back(seeded);
      first_fallback = starts.size();
      starts.push_back(model.MomentStart(r, 0.5));
    }
  }
  if (starts.empty() && !model.through_focus()) {
    for (double r : options.start_airy_radii_px) {
      for (double share : options.start_defocus_shares) {
        starts.push_back(model.MomentStart(r, share));
      }
    }
  }
  if (screen && model.num_exposures() == 1) {
    for (auto& s : ScreenStarts(model, options)) starts.push_back(std::move(s));
  }
  if (screen && model.HasEffects()) {
    // The 2015 model's posterior is rugged: with effects free from the start the search can
    // settle in a wrong basin (measured: a five-exposure set with a 0.1 px defocus_offset
    // ended at r = 0.24 px, chi^2/dof 1.33, against 0.47 px and 0.98). The fit without the
    // effects, with them added at "no effect" (theta holds them at its end), is a start
    // inside the right basin, as diagnose reaches them.
    FitModelOptions plain_options = model.options();
    // (A Gaussian prior on effect parameters binds inactive there: gaussian_prior.h.)
    plain_options.effects.clear();
    std::string plain_error;
    auto plain = FitModel::Create(model.stamps(), plain_options, &plain_error);
    MapResult plain_map;
    if (plain && FindMap(*plain, options, &plain_map, &plain_error)) {
      std::vector<double> staged = plain_map.theta;
      staged.resize(model.dim());
      model.SetEffectStart(staged.data());
      starts.insert(starts.begin(), std::move(staged));
      if (first_fallback != std::numeric_limits<size_t>::max()) ++first_fallback;
    }
  }
  // A joint fit's last start is a fallback, solved only if the others fail (the multi-start
  // search already ran on one exposure, or on the screened joint data).
  StartOutcome best;
  std::string last_failure;
  // A single exposure's starts are independent solves of one residual block: they run on
  // options.num_threads threads, each solve on one Ceres thread (with one block, Ceres' thread
  // count changes no bit), and are taken in order below, so the MAP does not depend on the
  // threads. (Joint fits keep their starts serial: a joint solve's last bits depend on its
  // Ceres threads, MapOptions::solver_threads.)
  std::vector<std::optional<StartOutcome>> solved(starts.size());
  if (model.num_exposures() == 1 && options.num_threads > 1) {
    MapOptions one_thread = options;
    one_thread.solver_threads = 1;
    const int parallel = static_cast<int>(std::min(starts.size(), first_fallback));
    ForEachIndex(model, parallel, options.num_threads,
                 [&](int i, FitEvaluator*) { solved[i] = Solve(model, starts[i], one_thread); });
  }
  for (size_t i = 0; i < starts.size(); ++i) {
    if (i >= first_fallback && best.usable) break;
    const StartOutcome o = solved[i] ? *solved[i] : Solve(model, starts[i], options);
    ++result->num_starts;
    result->start_costs.push_back(o.cost);
    if (!o.usable) {
      last_failure = o.message + " after " + std::to_string(o.iterations) + " iterations";
      continue;
    }
    ++result->num_usable_starts;
    if (o.cost < best.cost) best = o;
  }
  if (!best.usable) {
    *error = "the fit did not converge from any of " + std::to_string(result->num_starts) +
             " starting points (last: " + last_failure + ")";
    return false;
  }
  FillResult(model, best, result);
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace ccdpsf::fit
