// The line densities a boundary-shift test hands to ApplyBoundaryShift: the spot's light per
// unit length along a grid's pixel boundaries, values only, in ApplyBoundaryShift's layout
// (the grid grown by one pixel below on the boundaries' axis).
#ifndef CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_
#define CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_

#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/renderer.h"

namespace ccdpsf::testing_support {

struct BoundaryDensities {
  model::DualImage x;  // along the boundaries x = x0 - 1/2 + b of each row, (nx + 1) x ny
  model::DualImage y;  // along the boundaries y = y0 - 1/2 + b of each column, nx x (ny + 1)
};

BoundaryDensities DrawBoundaryDensities(const model::SpotRenderer& renderer,
                                        const model::SpotParams& spot,
                                        const model::PixelGrid& grid);

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_
