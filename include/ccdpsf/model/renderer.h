// Renders the spot model of spot_model.h onto a pixel grid, with first derivatives.
//
// Usage:
//   SpotRenderer renderer(options);
//   std::vector<double> model(grid.size()), jacobian(grid.size() * kNumSpotParams);
//   renderer.Render(params, grid, model.data(), jacobian.data());
//
// model[j * nx + i] is the expected number of electrons in pixel (i, j); jacobian holds
// d model[p] / d params[k] at jacobian[p * kNumSpotParams + k] (row-major, one row per
// pixel). Pass jacobian = nullptr when derivatives are not needed.
//
// A renderer keeps scratch buffers between calls, so one instance must not be used from two
// threads at once; make one per thread. Parameters must pass ValidSpotParams (checked with
// CHECK: calling with invalid parameters is a bug in the caller).
#ifndef CCDPSF_MODEL_RENDERER_H_
#define CCDPSF_MODEL_RENDERER_H_

#include <memory>

#include "ccdpsf/model/spot_model.h"

namespace ccdpsf::model {

class SpotRenderer {
 public:
  explicit SpotRenderer(const ModelOptions& options);
  ~SpotRenderer();
  SpotRenderer(const SpotRenderer&) = delete;
  SpotRenderer& operator=(const SpotRenderer&) = delete;

  const ModelOptions& options() const { return options_; }

  void Render(const SpotParams& params, const PixelGrid& grid, double* model,
              double* jacobian) const;

  // The same with the defocus kernel centred at (x + dx_px, y + dy_px) instead of the Airy
  // centre (the catalogue's defocus_offset). Integrated sampling: exactly the spot centred at
  // (x + dx_px, y + dy_px) (a convolution with a shifted kernel is the shifted convolution),
  // so the Jacobian's centre columns are the derivatives with respect to the shifted centre.
  // pixel_centre: the 2015 F kernel centred there (pixel_centre_renderer.h). Zero offsets give
  // exactly Render's output. offset_jacobian (may be null) receives d model / d (dx_px, dy_px),
  // pixels x 2 row-major (integrated: the centre's columns).
  void RenderWithDefocusOffset(const SpotParams& params, double dx_px, double dy_px,
                               const PixelGrid& grid, double* model, double* jacobian,
                               double* offset_jacobian = nullptr) const;

  // The line integral of the spot's continuous image [e- / px] along each pixel's upper
  // boundary on one axis: for axis 0, out[j * nx + i] is the integral along x = x0 + i + 1/2
  // over y in [y0 + j - 1/2, y0 + j + 1/2] (the boundary between pixels (i, j) and (i + 1, j));
  // for axis 1, along y = y0 + j + 1/2 over the pixel's x extent. What a boundary moved by a
  // small d [px] adds to the pixel beyond it is d times this (model/boundary_shift.h). Same
  // layout and Jacobian as Render. Integrated sampling only, with the whole pixel collecting
  // (ModelOptions::pixel_response_width = 1): the 2015 pixel_centre model samples points and
  // has no pixel boundaries.
  void RenderBoundaryDensity(const SpotParams& params, const PixelGrid& grid, int axis,
                             double* density, double* jacobian) const;
  // The spot's continuous image itself [e- / px^2] at each pixel's upper corner: out[j * nx +
  // i] at (x0 + i + 1/2, y0 + j + 1/2), where four pixels meet. A corner patch of small area A
  // there holds A times this (the second-order term of the boundary shifts). Same layout,
  // Jacobian and restrictions as RenderBoundaryDensity.
  void RenderCornerDensity(const SpotParams& params, const PixelGrid& grid, double* density,
                           double* jacobian) const;

  // Render and, in the same passes, the three densities above on their own grids (usually
  // the boundaries and corners of a window of the image): x = RenderBoundaryDensity's axis 0,
  // y = its axis 1, corner = RenderCornerDensity's. The renders that integrate alike along y
  // (the pixels and x; y and corner) share that integral, the larger part of a render's cost.
  // The same numbers as the four separate calls up to rounding; the same restrictions as
  // RenderBoundaryDensity, and every grid must lie whole pixels from `grid` along y. Jacobians
  // all null or none.
  struct DensityImage {
    PixelGrid grid;
    double* values = nullptr;
    double* jacobian = nullptr;
  };
  void RenderWithDensities(const SpotParams& params, const PixelGrid& grid, double* model,
                           double* jacobian, const DensityImage& x, const DensityImage& y,
                           const DensityImage& corner) const;

 private:
  // The integrated render with the pixel box replaced by its upper edge on the axes asked
  // (both: the point at the pixel's upper corner): the densities above.
  void RenderAtEdges(const SpotParams& params, const PixelGrid& grid, bool edge_x, bool edge_y,
                     double* density, double* jacobian) const;
  struct Workspace;
  ModelOptions options_;
  std::unique_ptr<Workspace> workspace_;
};

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_RENDERER_H_
