// `integrated` sampling: the exact pixel integral of [Airy (*) defocus] (*) G_ccd.
#ifndef CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_
#define CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "ccdpsf/model/spot_model.h"
#include "internal/airy_disc_average.h"

namespace ccdpsf::internal {

// Doubles starting on a 64-byte boundary (a cache line): the passes load four doubles at a
// time, and a load straddling two cache lines costs two.
class AlignedDoubles {
 public:
  void resize(size_t n) {
    storage_.resize(n + 7);
    const size_t misalignment = reinterpret_cast<uintptr_t>(storage_.data()) % 64;
    data_ = storage_.data() + (misalignment == 0 ? 0 : (64 - misalignment) / sizeof(double));
  }
  double* data() { return data_; }
  const double* data() const { return data_; }
  double& operator[](size_t i) { return data_[i]; }

 private:
  std::vector<double> storage_;
  double* data_ = nullptr;
};

// A column-major image on quadrature nodes; with rows a multiple of 4 every column starts on
// a 32-byte boundary, so that no four-double load straddles a cache line.
struct NodeImage {
  int rows = 0, cols = 0;
  AlignedDoubles values;
  void Resize(int r, int c) {
    rows = r;
    cols = c;
    values.resize(static_cast<size_t>(r) * c);
  }
  double& operator()(int i, int j) { return values[static_cast<size_t>(j) * rows + i]; }
  double* data() { return values.data(); }
};

// What the radially symmetric image S on the quadrant depends on. S does not depend on the
// centre or the grid's place: renders that share these (the exposures of a joint fit, which
// share the Airy radius and the widths) reuse it.
struct QuadrantKey {
  double k = 0.0;                // Airy wavenumber pi Rz / r [1/px]
  double hx = 0.0, hy = 0.0;     // node spacings [px]
  double pillbox_radius = -1.0;  // [px]; -1: the Gaussian-defocus model (S is the Airy pattern)
  int rows = 0, cols = 0;        // quadrant size [nodes]
  bool derivs = false;           // quadrant_dr (and quadrant_dR) filled too
  // Whether a quadrant made for this key serves a render that needs `wanted`: the same S, at
  // least its rows and columns and, if wanted, derivatives.
  bool Serves(const QuadrantKey& wanted) const {
    return k == wanted.k && hx == wanted.hx && hy == wanted.hy &&
           pillbox_radius == wanted.pillbox_radius && rows >= wanted.rows && cols >= wanted.cols &&
           (derivs || !wanted.derivs);
  }
};

// The distances [px] of a quadrant's nodes (|i| hx, |j| hy) from the origin, laid out as S
// (node (iu, ju) at ju * rows + iu). They depend on the quadrant's shape and spacings only,
// so renders that change only the Airy or pillbox radius (an MCMC's proposals) reuse them.
struct NodeDistances {
  int rows = 0, cols = 0;
  double hx = 0.0, hy = 0.0;
  std::vector<double> d;
  void Update(int rows, int cols, double hx, double hy);
};

// Kernel weights along one axis. With an integer node density Q = 1/h, the nodes seen by
// pixel n + 1 are those seen by pixel n shifted by exactly Q, with the same weights; so one
// window of weights serves every pixel of the axis: pixel n uses nodes first + Q n + m,
// m = 0..size-1, with weights row m.
struct AxisWeights {
  int first = 0;      // first node index seen by pixel 0
  int q = 1;          // node shift per pixel (= 1/h)
  Eigen::MatrixXd w;  // (size x 3): h k, d(h k)/d centre, d(h k)/d width
};

// The most outputs one render fills (the pixels and the three densities of the boundary shifts).
constexpr int kMaxIntegratedOutputs = 4;

// What the integral along one axis collects per pixel: the pixel's extent (times the pixel
// response window, ModelOptions::pixel_response_width), or the line at its upper edge, so
// that a pixel's value is the line integral of the image along that edge [e- / px].
enum class AxisKernel { kPixel, kUpperEdge };

// Scratch space reused between renders (sizes change with the parameters).
struct IntegratedWorkspace {
  // The radially symmetric image S (unit flux) at the nodes (|i|, |j|) of one quadrant, and
  // its derivatives by the Airy radius and (pillbox only) the pillbox radius.
  NodeImage quadrant, quadrant_dr, quadrant_dR;
  QuadrantKey quadrant_key;    // what the quadrant holds now (rows 0: nothing yet)
  AlignedDoubles row;          // first pass: the right-hand sides of one output row, by |i|
  // First pass outputs, one per group of outputs that integrate alike along y (the render of
  // several outputs below), [(|i| * rhs count + rhs) * ny_pad + b].
  std::array<AlignedDoubles, kMaxIntegratedOutputs> bt;
  std::vector<double> acc;  // second pass accumulators, [quantity * ny_pad + b]
  // Kernel weights along x per output, along y per group (kept: their storage is reused).
  std::array<AxisWeights, kMaxIntegratedOutputs> wx, wy;
  std::vector<double> edges;   // kernel weights: the normal's values at the window edges
  std::vector<size_t> offset;  // where each kernel node's input starts, for one output line
  AiryDiscProfile pillbox_profile;  // the pillbox model's S by distance
  std::vector<AiryDiscProfile::Run> pillbox_runs;  // the quadrant's columns, for its Evaluate
  NodeDistances distances;          // of the quadrant's nodes, for the fills
};


// Renders with unit flux semantics handled inside; see renderer.h for the output layout.
// kernel_x = kUpperEdge gives, for pixel (i, j), the line integral along x = x0 + i + 1/2,
// y in [y0 + j - 1/2, y0 + j + 1/2] (SpotRenderer::RenderBoundaryDensity); kernel_y likewise.
void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& params,
                      const model::PixelGrid& grid, double* model, double* jacobian,
                      IntegratedWorkspace* workspace, AxisKernel kernel_x = AxisKernel::kPixel,
                      AxisKernel kernel_y = AxisKernel::kPixel);

// One image a render fills: its grid, what each axis's integral collects, and where the
// values (and, if not null, the Jacobian) go, in RenderIntegrated's layout.
struct IntegratedOutput {
  model::PixelGrid grid;
  AxisKernel kernel_x = AxisKernel::kPixel, kernel_y = AxisKernel::kPixel;
  double* values = nullptr;
  double* jacobian = nullptr;
};

// Several outputs of one spot in one render (at most kMaxIntegratedOutputs; all with a
// Jacobian or none): the quadrant S is filled once, the first pass (along y) runs once per
// y kernel over the union of the rows of the outputs that use it, and each output's second
// pass reads its rows from there. Every output's values are those of its own render up to
// rounding. Outputs that share a y kernel must lie whole pixels apart along y.
void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& params,
                      const IntegratedOutput* outputs, int count, IntegratedWorkspace* workspace);

// The quadrature node spacing [px] used along an axis whose total Gaussian width is s [px],
// for an Airy pattern of cut-off frequency rho_c = Rz / r [cycles/px]. Exposed for tests.
double QuadratureStep(double rho_c, double s, double tolerance);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_INTEGRATED_RENDERER_H_
