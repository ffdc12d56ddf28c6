// The MCMC's coordinates (sampling_coordinates.h) against finite differences: the map and
// its inverse agree, and the log-Jacobian is the log-determinant of d theta / d phi.
#include "ccdpsf/fit/sampling_coordinates.h"

#include <cmath>
#include <vector>

#include "Eigen/Dense"
#include "gtest/gtest.h"
#include "support/fit_helpers.h"
#include "support/simulated_stamps.h"

namespace ccdpsf::fit {
namespace {

using testing_support::MustCreate;
using testing_support::PaperConfig;
using testing_support::SimulateStamps;

void CheckCoordinates(model::Sampling sampling) {
  FitModelOptions options;
  options.model.sampling = sampling;
  auto model = MustCreate(SimulateStamps(PaperConfig(sampling, 2, 3), 4), options);
  const SamplingCoordinates coords(*model);
  const int n = model->dim();
  // CCD widths from the plateau (0.08 px) to well resolved (0.45 px).
  for (double sx : {0.08, 0.21, 0.3, 0.45}) {
    for (double sy : {0.12, 0.33}) {
      std::vector<double> theta = {1e5, 0.47, 0.41, sx, sy, 10.0, 10.1, 9.9, 10.0};
      std::vector<double> phi(n), back(n);
      coords.ToSampling(theta.data(), phi.data());
      ASSERT_TRUE(coords.FromSampling(phi.data(), back.data()));
      for (int i = 0; i < n; ++i) EXPECT_NEAR(back[i], theta[i], 1e-12) << i;
      // d theta / d phi by central differences of FromSampling; steps relative to each
      // coordinate (1e-6), so truncation (~1e-12 relative) and rounding (~1e-10) are far
      // below the 1e-6 tolerance on the log-determinant.
      Eigen::MatrixXd jac(n, n);
      for (int j = 0; j < n; ++j) {
        const double h = 1e-6 * std::max(std::abs(phi[j]), 1e-6);
        std::vector<double> up = phi, down = phi, tu(n), td(n);
        up[j] += h;
        down[j] -= h;
        ASSERT_TRUE(coords.FromSampling(up.data(), tu.data()));
        ASSERT_TRUE(coords.FromSampling(down.data(), td.data()));
        for (int i = 0; i < n; ++i) jac(i, j) = (tu[i] - td[i]) / (2 * h);
      }
      const double log_det = std::log(std::abs(jac.determinant()));
      EXPECT_NEAR(coords.LogJacobian(phi.data()), log_det, 1e-6) << sx << " " << sy;
      const std::vector<double> analytic = coords.Jacobian(phi.data());
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          EXPECT_NEAR(analytic[i * n + j], jac(i, j), 1e-6 * (1 + std::abs(jac(i, j))))
              << i << "," << j;
        }
      }
    }
  }
}

TEST(SamplingCoordinates, TotalWidthsInIntegratedSampling) {
  CheckCoordinates(model::Sampling::kIntegrated);
}

TEST(SamplingCoordinates, KernelWeightsInPixelCentreSampling) {
  CheckCoordinates(model::Sampling::kPixelCentre);
}

// The pixel_centre map squeezes the flat part of the likelihood (widths below ~0.2 px, where
// the sampled kernel's neighbour weight exp(-1 / (2 s^2)) < 4e-6) into a short interval:
// between 0.05 and 0.2 px the coordinate moves by c x 0.15 plus that weight, with c = 3e-3.
TEST(SamplingCoordinates, PixelCentrePlateauIsShort) {
  FitModelOptions options;
  options.model.sampling = model::Sampling::kPixelCentre;
  auto model =
      MustCreate(SimulateStamps(PaperConfig(model::Sampling::kPixelCentre, 1, 3), 4), options);
  const SamplingCoordinates coords(*model);
  auto u_of = [&](double s) {
    std::vector<double> theta = {1e5, 0.47, 0.41, s, s, 10.0, 10.0}, phi(7);
    coords.ToSampling(theta.data(), phi.data());
    return phi[kCcdSigmaXPx];
  };
  EXPECT_NEAR(u_of(0.2) - u_of(0.05), 3e-3 * 0.15 + std::exp(-0.5 / 0.04), 1e-15);
  EXPECT_EQ(coords.names()[kCcdSigmaXPx], "ccd_kernel_weight_x");
}

}  // namespace
}  // namespace ccdpsf::fit
