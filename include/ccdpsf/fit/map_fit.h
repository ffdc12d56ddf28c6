// Maximum a posteriori point with Ceres (flat priors: the maximum-likelihood point inside
// the prior box).
//
// One residual block per exposure; its parameter blocks are the shared PSF block (flux,
// Airy radius, defocus, CCD sigma_x, sigma_y) - the same pointer for every exposure, which
// is what makes the fit joint - and the exposure's own (x, y) block. For each valid pixel the
// block returns two residuals,
//
//   r1 = (D - m) / sigma,   r2 = sqrt(log(var / var0) + 1),   var = sigma^2 = m + s^2,
//
// with var0 = s^2 the read-noise-plus-rounding floor, so 1/2 sum (r1^2 + r2^2) equals
// -log L + constant for the Gaussian likelihood with model-dependent variance: the -sum log
// sigma term is kept (r2 >= 1, so its derivative is bounded). r1 is the whitened residual.
// Bounds are the prior box, set with SetParameterLower/UpperBound.
//
// Through-focus fits (fit_model.h) add a third parameter block, best_focus_um [1], shared by
// every exposure like the PSF block (whose index 2 is then the defocus rate); each block's
// defocus is rate |z_k - z0|, and its Jacobian follows by the chain rule.
#ifndef CCDPSF_FIT_MAP_FIT_H_
#define CCDPSF_FIT_MAP_FIT_H_

#include <map>
#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"

namespace ceres {
class CostFunction;
}

namespace ccdpsf::fit {

struct MapOptions {
  // Starting points: every combination of these Airy radii [px] and shares of the Gaussian
  // width given to the defocus (moment starts, FitModel::MomentStart). Several starts make
  // the answer independent of the luck of one. A joint fit without screening runs this
  // search on its first exposure and seeds the joint solve with the result.
  std::vector<double> start_airy_radii_px = {0.35, 0.6, 0.9};
  std::vector<double> start_defocus_shares = {0.25, 0.75};
  // Generous: at low signal (~7 ke- peaks) the rugged pixel_centre joint problem needs several
  // hundred iterations; converging fits stop long before.
  int max_iterations = 1000;
  // Threads of the pixel_centre screening's grid scores, position refinements and local
  // solves; the MAP is the same for any number. --threads (FIT.json mcmc.threads) sets it
  // with the MCMC's.
  int num_threads = 2;
  // Threads of Ceres' residual evaluation in the final solves (one block per exposure). Fixed,
  // not --threads: Ceres sums the cost over its threads, so the MAP's last bits depend on
  // their number (seen under the sanitizers' codegen).
  int solver_threads = 2;
  // Grid screening before the local solves: the log-likelihood is evaluated on a coarse grid
  // of (Airy radius, defocus, sigma_x, sigma_y) with the flux set by least squares, and the
  // best `screen_keep` grid points, with the best point of every Airy radius, become extra
  // starts. The pixel_centre likelihood is
  // strongly multimodal (its unit-peak kernels sampled at integer offsets make it rugged:
  // measured, 20 moment starts on the paper's simulation reach chi^2/dof from 1.05 to 300),
  // so kAuto screens there and not for integrated sampling, whose starts all agree.
  enum class Screen { kAuto, kAlways, kNever };
  Screen screen = Screen::kAuto;
  std::vector<double> screen_airy_radii_px = {0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55,
                                              0.6, 0.65, 0.7, 0.75, 0.85};
  std::vector<double> screen_defocus_px = {0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.65};
  std::vector<double> screen_ccd_sigma_px = {0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5};
  int screen_keep = 10;
  // Joint fits with screening (map_fit.cc, JointScreenStarts): the grid is scored on the
  // first three exposures, the best screen_keep shapes are rescored on all of them, and this
  // many become starts of the joint solve.
  int joint_screen_solves = 3;
  // Through-focus fits. A single exposure cannot separate defocus from the CCD kernel, so
  // the joint fit is not seeded from one as above. Instead: a normal single-exposure fit of
  // the exposure with the smallest moment width (the one nearest best focus) gives the Airy
  // radius, the flux and the total widths there; every exposure's moment variance, pinned to
  // that fit, is then fitted by sigma_ccd^2 + rate^2 (z_k - z0)^2 (linear least squares in
  // sigma_ccd^2 and rate^2 on a grid of z0). Starts: the best such z0 with the CCD variance
  // scaled by each of start_ccd_variance_scales (rate refitted), and z0 at each of these
  // fractions of the scanned range. Every start is solved; the best wins.
  std::vector<double> start_ccd_variance_scales = {1.0, 0.5};
  std::vector<double> start_best_focus_fractions = {0.2, 0.5, 0.8};
};

struct MapResult {
  std::vector<double> theta;
  double log_likelihood = 0.0;  // of the model's likelihood kind, at theta
  double log_prior = 0.0;       // FitModel::LogPrior at theta (0 when every prior is flat)
  double chi2 = 0.0;            // sum of squared whitened residuals
  int num_pixels = 0;
  int dof = 0;                  // pixels - parameters
  int num_starts = 0;
  int num_usable_starts = 0;
  std::vector<double> start_costs;  // final Ceres cost of each start, in order
  int iterations = 0;               // of the best start
  std::string termination;          // Ceres' message for the best start
  double seconds = 0.0;
};

// Returns false with a one-line reason when no start reaches a usable solution.
bool FindMap(const FitModel& model, const MapOptions& options, MapResult* result,
             std::string* error);

// One local solve from `start` (clamped into the prior), e.g. after a few pixels were masked
// near an earlier optimum; fills *result as FindMap does. False with a reason if it fails.
bool RefineMap(const FitModel& model, std::vector<double> start, const MapOptions& options,
               MapResult* result, std::string* error);

// Where exposure k's residual block reads its parameters: its parameter blocks (each a
// slice x[first, first + size) of the solver's vector x) and where each theta index the
// exposure depends on sits in them (block, offset). Theta indices not placed are held at 0
// and their derivatives go nowhere. The fit's x is theta; diagnose's is theta less the
// defocus of a baseline without it, which is held at 0.
struct ExposureCostLayout {
  struct Block {
    int first, size;
  };
  struct Place {
    int block, offset;
  };
  std::vector<Block> blocks;
  std::map<int, Place> place;
};

// The fit's layout: shared[5], position[2], then (when present) best_focus[1], the
// exposure's flux ratio[1] and the effects' parameters (one block, in theta order).
ExposureCostLayout FitExposureCostLayout(const FitModel& model, int k);

// The residual block of exposure k: the one residual of every fit and of diagnose, against
// `data_e` (stamp-sized; null: the stamp's own data). The caller owns the result (or hands it
// to a ceres::Problem).
ceres::CostFunction* NewExposureCost(const FitModel& model, int k, ExposureCostLayout layout,
                                     const Image* data_e = nullptr);
// In the fit's layout, against the stamp.
ceres::CostFunction* NewExposureCost(const FitModel& model, int k);

// The Gaussian prior's residual block (gaussian_prior.h): its layout, the blocks of
// `layouts` that hold the parameters the model's prior names (empty without a prior), and the
// block itself, whose 1/2 sum r^2 is minus the log prior up to a constant. SolveResidualBlocks
// adds it whenever the model's prior is active.
ExposureCostLayout GaussianPriorLayout(const FitModel& model,
                                       const std::vector<ExposureCostLayout>& layouts);
ceres::CostFunction* NewGaussianPriorCost(const FitModel& model, ExposureCostLayout layout);

// Ceres' stopping rules for a solve (dense QR, silent).
struct SolveSettings {
  int max_iterations = 200;
  double function_tolerance = 1e-12;
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  int threads = 1;
};

struct SolveOutcome {
  double cost = 0.0;       // half the sum of squared residuals at the end
  bool usable = false;     // a finite point Ceres calls usable
  bool converged = false;  // and it did not stop at the iteration limit
  int iterations = 0;
  std::string message;
};

// The one least-squares solve of fit and diagnose: the residual blocks of all exposures
// (layouts[k], against (*data_e)[k] or the stamps), and the Gaussian prior's block when the
// model has one, minimised over *x within [lower, upper]; *x holds the start and receives the
// end point.
SolveOutcome SolveResidualBlocks(const FitModel& model,
                                 const std::vector<ExposureCostLayout>& layouts,
                                 const std::vector<double>& lower, const std::vector<double>& upper,
                                 const SolveSettings& settings, const std::vector<Image>* data_e,
                                 std::vector<double>* x);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_MAP_FIT_H_
