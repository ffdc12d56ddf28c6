// `pixel_centre` sampling: the discretisation of the authors' 2015 Python code, exactly
// (docs/conventions.md, Sampling), so that results can be compared with the paper's.
#ifndef CCDPSF_INTERNAL_PIXEL_CENTRE_RENDERER_H_
#define CCDPSF_INTERNAL_PIXEL_CENTRE_RENDERER_H_

#include "ccdpsf/model/spot_model.h"

namespace ccdpsf::internal {

// Renders on stamp indices (grid.x0 = grid.y0 = 0 required); see renderer.h for the layout.
// params[kFlux] is the peak meta-parameter m; only the Gaussian defocus exists in this mode,
// and params[kDefocus] = 0 leaves the defocus step out. The defocus kernel F is centred at
// (x + defocus_dx_px, y + defocus_dy_px); `jacobian` is with respect to params (F moves
// with x, y), `offset_jacobian` (pixels x 2, row-major; may be null) with respect to
// (defocus_dx_px, defocus_dy_px), F's centre alone.
void RenderPixelCentre(const model::SpotParams& params, const model::PixelGrid& grid, double* model,
                       double* jacobian, double defocus_dx_px = 0.0, double defocus_dy_px = 0.0,
                       double* offset_jacobian = nullptr);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_PIXEL_CENTRE_RENDERER_H_
