#include "ccdpsf/model/renderer.h"

#include <string>
#include <vector>

#include "glog/logging.h"
#include "internal/integrated_renderer.h"
#include "internal/pixel_centre_renderer.h"

namespace ccdpsf::model {

namespace {

// What the boundary and corner densities need (renderer.h): checked, as Render checks its own.
void CheckDensityRender(const ModelOptions& options, const SpotParams& params) {
  CHECK(options.sampling == Sampling::kIntegrated)
      << "boundary and corner densities need integrated sampling";
  CHECK_EQ(options.pixel_response_width, 1.0)
      << "boundary and corner densities need the whole pixel";
  std::string error;
  CHECK(ValidSpotParams(options, params, &error)) << error;
}

}  // namespace

struct SpotRenderer::Workspace {
  internal::IntegratedWorkspace integrated;
};

SpotRenderer::SpotRenderer(const ModelOptions& options)
    : options_(options), workspace_(std::make_unique<Workspace>()) {
  CHECK(options_.sampling == Sampling::kIntegrated ||
        options_.defocus == DefocusKind::kGaussian)
      << "pixel_centre sampling has only the Gaussian defocus of the 2015 code";
  CHECK_GT(options_.relative_tolerance, 0.0);
}

SpotRenderer::~SpotRenderer() = default;

void SpotRenderer::Render(const SpotParams& params, const PixelGrid& grid, double* model,
                          double* jacobian) const {
  std::string error;
  CHECK(ValidSpotParams(options_, params, &error)) << error;
  CHECK_GT(grid.nx, 0);
  CHECK_GT(grid.ny, 0);
  if (options_.sampling == Sampling::kPixelCentre) {
    internal::RenderPixelCentre(params, grid, model, jacobian);
  } else {
    internal::RenderIntegrated(options_, params, grid, model, jacobian, &workspace_->integrated);
  }
}

void SpotRenderer::RenderWithDefocusOffset(const SpotParams& params, double dx_px, double dy_px,
                                           const PixelGrid& grid, double* model, double* jacobian,
                                           double* offset_jacobian) const {
  if (options_.sampling == Sampling::kPixelCentre) {
    std::string error;
    CHECK(ValidSpotParams(options_, params, &error)) << error;
    CHECK_GT(grid.nx, 0);
    CHECK_GT(grid.ny, 0);
    internal::RenderPixelCentre(params, grid, model, jacobian, dx_px, dy_px, offset_jacobian);
    return;
  }
  SpotParams shifted = params;
  shifted[kCentreX] += dx_px;
  shifted[kCentreY] += dy_px;
  std::vector<double> own;
  if (offset_jacobian != nullptr && jacobian == nullptr) {
    own.resize(static_cast<size_t>(grid.size()) * kNumSpotParams);
    jacobian = own.data();
  }
  Render(shifted, grid, model, jacobian);
  // The offset moves the whole (shifted) spot: its derivatives are the centre's.
  for (int q = 0; offset_jacobian != nullptr && q < grid.size(); ++q) {
    offset_jacobian[2 * q] = jacobian[static_cast<size_t>(q) * kNumSpotParams + kCentreX];
    offset_jacobian[2 * q + 1] = jacobian[static_cast<size_t>(q) * kNumSpotParams + kCentreY];
  }
}

void SpotRenderer::RenderAtEdges(const SpotParams& params, const PixelGrid& grid, bool edge_x,
                                 bool edge_y, double* density, double* jacobian) const {
  CheckDensityRender(options_, params);
  CHECK_GT(grid.nx, 0);
  CHECK_GT(grid.ny, 0);
  using internal::AxisKernel;
  internal::RenderIntegrated(options_, params, grid, density, jacobian, &workspace_->integrated,
                             edge_x ? AxisKernel::kUpperEdge : AxisKernel::kPixel,
                             edge_y ? AxisKernel::kUpperEdge : AxisKernel::kPixel);
}

void SpotRenderer::RenderWithDensities(const SpotParams& params, const PixelGrid& grid,
                                       double* model, double* jacobian, const DensityImage& x,
                                       const DensityImage& y, const DensityImage& corner) const {
  CheckDensityRender(options_, params);
  using internal::AxisKernel;
  const internal::IntegratedOutput outputs[4] = {
      {grid, AxisKernel::kPixel, AxisKernel::kPixel, model, jacobian},
      {x.grid, AxisKernel::kUpperEdge, AxisKernel::kPixel, x.values, x.jacobian},
      {y.grid, AxisKernel::kPixel, AxisKernel::kUpperEdge, y.values, y.jacobian},
      {corner.grid, AxisKernel::kUpperEdge, AxisKernel::kUpperEdge, corner.values,
       corner.jacobian}};
  internal::RenderIntegrated(options_, params, outputs, 4, &workspace_->integrated);
}

void SpotRenderer::RenderBoundaryDensity(const SpotParams& params, const PixelGrid& grid, int axis,
                                         double* density, double* jacobian) const {
  CHECK(axis == 0 || axis == 1) << axis;
  RenderAtEdges(params, grid, axis == 0, axis == 1, density, jacobian);
}

void SpotRenderer::RenderCornerDensity(const SpotParams& params, const PixelGrid& grid,
                                       double* density, double* jacobian) const {
  RenderAtEdges(params, grid, true, true, density, jacobian);
}

}  // namespace ccdpsf::model
