// The light a boundary-shift test hands to ApplyBoundaryShift: the spot's light per unit
// length along a grid's pixel boundaries and per unit area at their corners, values only, in
// ApplyBoundaryShift's layout (the grid grown by one pixel below on the boundaries' axes).
#ifndef CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_
#define CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_

#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/renderer.h"

namespace ccdpsf::testing_support {

model::BoundaryDensities DrawBoundaryDensities(const model::SpotRenderer& renderer,
                                        const model::SpotParams& spot,
                                        const model::PixelGrid& grid);

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_BOUNDARY_DENSITIES_H_
