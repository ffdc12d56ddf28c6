// `integrated` sampling: the exact pixel integral of [Airy (*) defocus] (*) G_ccd.
#ifndef CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_
#define CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_

#include <vector>

#include <Eigen/Core>

#include "ccdpsf/model/spot_model.h"

namespace ccdpsf::internal {

// Scratch space reused between renders (sizes change with the parameters).
struct IntegratedWorkspace {
  // The radially symmetric image S (unit flux) at the nodes (|i|, |j|) of one quadrant, and
  // its derivatives by the Airy radius and (pillbox only) the pillbox radius.
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
