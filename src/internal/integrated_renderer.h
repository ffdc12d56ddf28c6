// `integrated` sampling: the exact pixel integral of [Airy (*) defocus] (*) G_ccd.
#ifndef CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_
#define CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_

#include <vector>

#include <Eigen/Core>

#include "ccdpsf/model/spot_model.h"

namespace ccdpsf::internal {

// Scratch space reused between renders (sizes change with the parameters).
struct IntegratedWorkspace {
  Eigen::MatrixXd radial;     // radially symmetric image S at the quadrature nodes, unit flux
  Eigen::MatrixXd radial_dr;  // dS / d(airy radius)
  Eigen::MatrixXd radial_dR;  // dS / d(pillbox radius) (pillbox only)
  Eigen::MatrixXd quadrant, quadrant_dr, quadrant_dR;
  std::vector<double> row;  // first pass: the right-hand sides of one output row, by |i|
  std::vector<double> bt;   // first pass output, [(rhs * n|i| + |i|) * ny + b]
  std::vector<double> acc;  // second pass accumulators, [quantity * ny + b]
};

// Renders with unit flux semantics handled inside; see renderer.h for the output layout.
void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& params,
                      const model::PixelGrid& grid, double* model, double* jacobian,
                      IntegratedWorkspace* workspace);

// The quadrature node spacing [px] used along an axis whose total Gaussian width is s [px],
// for an Airy pattern of cut-off frequency rho_c = Rz / r [cycles/px]. Exposed for tests.
double QuadratureStep(double rho_c, double s, double tolerance);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_
