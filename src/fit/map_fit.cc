#include "ccdpsf/fit/map_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "ceres/ceres.h"
#include "glog/logging.h"

namespace ccdpsf::fit {
namespace {

// Shared-block index of each renderer parameter (-1: position block).
constexpr int kSharedIndexOfSpot[model::kNumSpotParams] = {
    kFluxE, -1, -1, kAiryRadiusPx, kDefocusPx, kCcdSigmaXPx, kCcdSigmaYPx};

class ExposureCost : public ceres::CostFunction {
 public:
  ExposureCost(const FitModel& model, int k)
      : model_(model), k_(k), renderer_(model.options().model) {
    const Stamp& s = model.stamps()[k];
    for (size_t q = 0; q < s.valid.size(); ++q) {
      if (s.valid[q]) pixels_.push_back(static_cast<int>(q));
    }
    noise_.gain_e_per_adu = s.gain_e_per_adu;
    noise_.read_noise_e = s.read_noise_e;
    mutable_parameter_block_sizes()->push_back(kNumShared);
    mutable_parameter_block_sizes()->push_back(2);
    set_num_residuals(2 * static_cast<int>(pixels_.size()));
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    std::vector<double> theta(model_.dim(), 0.0);
    for (int i = 0; i < kNumShared; ++i) theta[i] = parameters[0][i];
    theta[FitModel::XIndex(k_)] = parameters[1][0];
    theta[FitModel::YIndex(k_)] = parameters[1][1];
    model::SpotParams p = model_.SpotFor(theta.data(), k_);
    std::string why;
    // Ceres may probe outside the bounds during a line search; an invalid point is reported
    // as a failed evaluation, never a crash.
    if (!model::ValidSpotParams(renderer_.options(), p, &why)) return false;
    const model::PixelGrid grid = model_.GridFor(k_);
    model_pixels_.resize(grid.size());
    const bool want_jacobian = jacobians != nullptr;
    if (want_jacobian) spot_jacobian_.resize(grid.size() * model::kNumSpotParams);
    renderer_.Render(p, grid, model_pixels_.data(),
                     want_jacobian ? spot_jacobian_.data() : nullptr);
    const Stamp& s = model_.stamps()[k_];
    const double var0 = noise_.VarianceE2(0.0);
    const int n = static_cast<int>(pixels_.size());
    for (int i = 0; i < n; ++i) {
      const int q = pixels_[i];
      const double m = model_pixels_[q];
      const double var = noise_.VarianceE2(m);
      const double sigma = std::sqrt(var);
      const double d = s.electrons.data[q];
      const double r1 = (d - m) / sigma;
      const double r2 = std::sqrt(std::log(var / var0) + 1.0);
      residuals[i] = r1;
      residuals[n + i] = r2;
      if (!want_jacobian) continue;
      const double* g = &spot_jacobian_[static_cast<size_t>(q) * model::kNumSpotParams];
      const double dvar_dm = m > 0 ? 1.0 : 0.0;
      // dr1/dm = -1/sigma - (d - m) / (2 sigma^3) dvar/dm;  dr2/dm = dvar/dm / (2 var r2).
      const double dr1 = -1.0 / sigma - (d - m) / (2.0 * var * sigma) * dvar_dm;
      const double dr2 = dvar_dm / (2.0 * var * r2);
      if (jacobians[0] != nullptr) {
        for (int sp = 0; sp < model::kNumSpotParams; ++sp) {
          const int j = kSharedIndexOfSpot[sp];
          if (j < 0) continue;
          jacobians[0][i * kNumShared + j] = dr1 * g[sp];
          jacobians[0][(n + i) * kNumShared + j] = dr2 * g[sp];
        }
      }
      if (jacobians[1] != nullptr) {
        jacobians[1][i * 2 + 0] = dr1 * g[model::kCentreX];
        jacobians[1][i * 2 + 1] = dr1 * g[model::kCentreY];
        jacobians[1][(n + i) * 2 + 0] = dr2 * g[model::kCentreX];
        jacobians[1][(n + i) * 2 + 1] = dr2 * g[model::kCentreY];
      }
    }
    return true;
  }

 private:
  const FitModel& model_;
  const int k_;
  model::SpotRenderer renderer_;
  CcdNoise noise_;
  std::vector<int> pixels_;  // valid pixel indices
  mutable std::vector<double> model_pixels_, spot_jacobian_;
};

struct StartOutcome {
  std::vector<double> theta;
  double cost = std::numeric_limits<double>::infinity();
  bool usable = false;
  int iterations = 0;
  std::string message;
};

StartOutcome Solve(const FitModel& model, std::vector<double> theta, const MapOptions& options) {
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  double* shared = theta.data();
  for (int k = 0; k < model.num_exposures(); ++k) {
    double* position = theta.data() + FitModel::XIndex(k);
    problem.AddResidualBlock(NewExposureCost(model, k), nullptr, shared, position);
  }
  for (int i = 0; i < kNumShared; ++i) {
    problem.SetParameterLowerBound(shared, i, model.lower()[i]);
    problem.SetParameterUpperBound(shared, i, model.upper()[i]);
  }
  for (int k = 0; k < model.num_exposures(); ++k) {
    double* position = theta.data() + FitModel::XIndex(k);
    for (int j = 0; j < 2; ++j) {
      problem.SetParameterLowerBound(position, j, model.lower()[FitModel::XIndex(k) + j]);
      problem.SetParameterUpperBound(position, j, model.upper()[FitModel::XIndex(k) + j]);
    }
  }
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = options.max_iterations;
  solver.function_tolerance = 1e-12;
  solver.gradient_tolerance = 1e-12;
  solver.parameter_tolerance = 1e-10;
  solver.num_threads = options.num_threads;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  StartOutcome out;
  out.theta = theta;
  out.cost = summary.final_cost;
  // Ceres calls a run that hit the iteration limit "usable"; it has not converged, so it
  // does not count as a MAP point.
  out.usable = summary.IsSolutionUsable() && summary.termination_type != ceres::NO_CONVERGENCE &&
               std::isfinite(summary.final_cost);
  out.iterations = static_cast<int>(summary.iterations.size());
  out.message = summary.message;
  return out;
}

// Least-squares flux for the shape in *theta (set in place), then the log-posterior.
double ScoreWithBestFlux(const FitModel& model, FitEvaluator* ev, std::vector<double>* theta) {
  const double flux = ev->LeastSquaresFlux(theta->data());
  if (!std::isfinite(flux)) return -INFINITY;
  (*theta)[kFluxE] = std::clamp(flux, model.lower()[kFluxE], model.upper()[kFluxE]);
  return ev->LogPosterior(theta->data());
}

// Positions by grid search, for pixel_centre sampling: there the moment centroid is not the
// model's centre (its kernels shift the image; measured, the centroid sits about halfway
// between the spot and the stamp centre) and the likelihood is sharp in position. +-0.3 px in
// 0.025 px steps, one exposure at a time (the others stay put), with the shape in *theta.
void RefinePositions(const FitModel& model, FitEvaluator* ev, std::vector<double>* theta) {
  for (int k = 0; k < model.num_exposures(); ++k) {
    const int ix = FitModel::XIndex(k), iy = FitModel::YIndex(k);
    const double cx = (*theta)[ix], cy = (*theta)[iy];
    double best = -INFINITY, bx = cx, by = cy;
    for (int i = -12; i <= 12; ++i) {
      for (int j = -12; j <= 12; ++j) {
        std::vector<double> t = *theta;
        t[ix] = cx + 0.025 * i;
        t[iy] = cy + 0.025 * j;
        const double ll = ScoreWithBestFlux(model, ev, &t);
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
  ScoreWithBestFlux(model, ev, theta);
}

// Grid points ranked by log-likelihood (flux by least squares, positions refined once for a
// mid-range shape); returns the best `keep` as starting vectors.
std::vector<std::vector<double>> ScreenStarts(const FitModel& model, const MapOptions& options) {
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  std::vector<double> base = model.MomentStart(0.5, 0.5);
  base[kDefocusPx] = 0.4;
  base[kCcdSigmaXPx] = base[kCcdSigmaYPx] = 0.3;
  RefinePositions(model, ev.get(), &base);
  std::vector<std::pair<double, std::vector<double>>> scored;
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
          if (!inside) continue;
          const double ll = ScoreWithBestFlux(model, ev.get(), &theta);
          if (std::isfinite(ll)) scored.push_back({ll, theta});
        }
      }
    }
  }
  std::sort(scored.begin(), scored.end(),
            [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<std::vector<double>> starts;
  for (size_t i = 0; i < scored.size() && static_cast<int>(i) < options.screen_keep; ++i) {
    starts.push_back(scored[i].second);
  }
  return starts;
}

}  // namespace

ceres::CostFunction* NewExposureCost(const FitModel& model, int k) {
  return new ExposureCost(model, k);
}

bool FindMap(const FitModel& model, const MapOptions& options, MapResult* result,
             std::string* error) {
  const auto t0 = std::chrono::steady_clock::now();
  *result = MapResult();
  std::vector<std::vector<double>> starts;
  if (model.num_exposures() > 1) {
    // Joint fit: the multi-start search runs on the first exposure alone (12x cheaper for
    // 12 exposures), and its PSF seeds the joint solve; positions start at the centroids.
    // The moment start with the single fit's radius is kept as a fallback seed.
    std::string single_error;
    auto single = FitModel::Create({model.stamps()[0]}, model.options(), &single_error);
    MapResult single_map;
    if (single && FindMap(*single, options, &single_map, &single_error)) {
      const double r = single_map.theta[kAiryRadiusPx];
      std::vector<double> seeded = model.MomentStart(r, 0.5);
      for (int i = 0; i < kNumShared; ++i) {
        seeded[i] = std::clamp(single_map.theta[i], model.lower()[i], model.upper()[i]);
      }
      if (model.options().model.sampling == model::Sampling::kPixelCentre) {
        std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
        RefinePositions(model, ev.get(), &seeded);
      }
      seeded[FitModel::XIndex(0)] = single_map.theta[FitModel::XIndex(0)];
      seeded[FitModel::YIndex(0)] = single_map.theta[FitModel::YIndex(0)];
      starts.push_back(seeded);
      starts.push_back(model.MomentStart(r, 0.5));
    }
  }
  if (starts.empty()) {
    for (double r : options.start_airy_radii_px) {
      for (double share : options.start_defocus_shares) {
        starts.push_back(model.MomentStart(r, share));
      }
    }
  }
  const bool screen =
      options.screen == MapOptions::Screen::kAlways ||
      (options.screen == MapOptions::Screen::kAuto &&
       model.options().model.sampling == model::Sampling::kPixelCentre);
  if (screen && model.num_exposures() == 1) {
    for (auto& s : ScreenStarts(model, options)) starts.push_back(std::move(s));
  }
  // A joint fit's starts are a seeded start and a fallback: the fallback runs only if the
  // seeded solve fails (the multi-start search already ran on the single exposure).
  const bool fallback_only = model.num_exposures() > 1 && starts.size() == 2;
  StartOutcome best;
  for (const std::vector<double>& start : starts) {
    if (fallback_only && best.usable) break;
    const StartOutcome o = Solve(model, start, options);
    ++result->num_starts;
    result->start_costs.push_back(o.cost);
    if (!o.usable) continue;
    ++result->num_usable_starts;
    if (o.cost < best.cost) best = o;
  }
  if (!best.usable) {
    *error = "the fit did not converge from any of " + std::to_string(result->num_starts) +
             " starting points (" + best.message + ")";
    return false;
  }
  result->theta = best.theta;
  result->iterations = best.iterations;
  result->termination = best.message;
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  result->log_likelihood = ev->LogLikelihood(best.theta.data());
  result->chi2 = ev->ChiSquare(best.theta.data());
  result->num_pixels = model.NumValidPixels();
  result->dof = result->num_pixels - model.dim();
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace ccdpsf::fit
