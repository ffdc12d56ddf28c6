#include "support/boundary_densities.h"

#include <vector>

namespace ccdpsf::testing_support {

model::BoundaryDensities DrawBoundaryDensities(const model::SpotRenderer& renderer,
                                               const model::SpotParams& spot,
                                               const model::PixelGrid& grid) {
  const model::PixelGrid gx{grid.nx + 1, grid.ny, grid.x0 - 1.0, grid.y0};
  const model::PixelGrid gy{grid.nx, grid.ny + 1, grid.x0, grid.y0 - 1.0};
  const model::PixelGrid gc{grid.nx + 1, grid.ny + 1, grid.x0 - 1.0, grid.y0 - 1.0};
  model::BoundaryDensities d{{gx.nx, gx.ny, 0, std::vector<double>(gx.size())},
                             {gy.nx, gy.ny, 0, std::vector<double>(gy.size())},
                             {gc.nx, gc.ny, 0, std::vector<double>(gc.size())}};
  renderer.RenderBoundaryDensity(spot, gx, 0, d.x.data.data(), nullptr);
  renderer.RenderBoundaryDensity(spot, gy, 1, d.y.data.data(), nullptr);
  renderer.RenderCornerDensity(spot, gc, d.corner.data.data(), nullptr);
  return d;
}

}  // namespace ccdpsf::testing_support
