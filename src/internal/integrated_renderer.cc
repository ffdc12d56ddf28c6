// Exact pixel integration of the spot model.
//
// Write the model as a radially symmetric image S (the Airy pattern, or the Airy pattern
// convolved with the pillbox) convolved with a separable kernel K = kx(x) ky(y), where kx is
// a Gaussian of total width sX convolved with the pixel's collecting window of width w (1 for
// the whole pixel; less for a narrower pixel response): the fraction of a unit Gaussian of
// width s centred at offset t from a pixel centre that falls in the window,
//   k(t, s) = Phi((t + w/2) / s) - Phi((t - w/2) / s),
//
//   M(a, b) = Integral S(p - c) kx(xa - px) ky(yb - py) dp.
//
// With a Gaussian defocus both Gaussians merge, sX^2 = sigma_f^2 + sigma_x^2 (the origin of
// docs/trust.md, single focus); with a pillbox, sX = sigma_x and S carries the disc.
//
// The integral is evaluated with the uniform (trapezoidal) rule on nodes p = c + (i hX, j hY),
// done as two one-dimensional passes because K is separable:
//   first pass  B(i, b) = hY sum_j S(i, j) ky(yb - cy - j hY)       for every node column i,
//   second pass M(a, b) = hX sum_i kx(xa - cx - i hX) B(i, b).
// Error bound. By Poisson summation the uniform rule's error is the integrand's Fourier
// transform at multiples of 1/h. S is band-limited to the Airy cut-off rho_c = Rz / r (its
// transform is the circular-pupil OTF, zero beyond rho_c), and the kernel's transform is
// exp(-2 pi^2 s^2 f^2) sinc(f). So the error of one pass is at most
//   (8 rho_c^2 / (pi D)) exp(-2 pi^2 s^2 D^2) times the flux,   D = 1/h - rho_c,
// and QuadratureStep picks h so that this is below the tolerance. The rule is exact up to
// that bound for any centre: nodes move with the centre, so S is evaluated at fixed offsets.
// Truncation: a node contributes to pixel a only while |xa - node| <= 1/2 + T sX, with T
// chosen so the Gaussian tail beyond it is below the tolerance. The Airy tail beyond the
// stamp never needs truncating: it reaches the stamp only through the kernel.
//
// Derivatives are those of the quadrature sum itself (the node spacing is piecewise
// constant in the widths: QuadratureStep quantises 1/h), so they are exact for the values
// returned: centre and widths enter only through the kernels, the Airy radius (and pillbox
// radius) only through S.
#include "internal/integrated_renderer.h"

#include <algorithm>
#include <cmath>

#include "ccdpsf/model/airy.h"
#include "glog/logging.h"
#include "internal/airy_disc_average.h"
#include "internal/airy_table_simd.h"
#include "internal/normal_tail.h"
#include "internal/vec4.h"

namespace ccdpsf::internal {

using model::kAiryRadius;
using model::kCcdSigmaX;
using model::kCcdSigmaY;
using model::kCentreX;
using model::kCentreY;
using model::kDefocus;
using model::kFlux;
using model::kNumSpotParams;

namespace {

// Largest number of quadrature nodes allowed in one image: guards against parameters far
// outside anything physical turning into gigabytes (ValidSpotParams keeps us well below).
constexpr double kMaxNodes = 3.0e7;

// Half-width of the Gaussian kernel in units of its sigma beyond which its tail mass is
// below `tolerance` (one-sided normal tail bound exp(-T^2/2) / 2).
double KernelHalfWidthSigmas(double tolerance) {
  return std::sqrt(2.0 * std::log(0.5 / tolerance)) + 0.5;
}

// S for the Gaussian-defocus model, the Airy pattern, on quadrant column ju from row `first`:
// S = norm a(v)^2 at v = k d, d = dist[iu] the node's distance, and dS/dr = dnorm (a^2 + a da v)
// when col_dr is not null. Nodes past the table's end (v >= kAiryTableMax, exact Bessel
// functions) are redone one by one at the end; v grows down the column, so the check is the
// last node's.
void FillAiryColumn(const double* table, double k, double norm, double dnorm, const double* dist,
                    int first, int rows, double* col, double* col_dr) {
  int iu = first;
#if defined(__AVX2__) && defined(__FMA__)
  // Software-pipelined in two stages per group of four nodes: first v, its table piece and
  // the offset in it, then the polynomial. Node by node, the chain (then with a square root) ->
  // piece ->
  // coefficient loads (mostly from L2: the table holds ~50 bytes per 0.05 of v) -> five
  // dependent multiply-adds was too long for the out-of-order window to overlap enough nodes
  // (~9 cycles per node). Here the first stage runs kAhead groups ahead of the second, through
  // a ring of stage buffers, so that the coefficient transposes (the shuffle port's) of
  // different groups proceed side by side.
  constexpr int kAhead = 8;  // groups; a power of two
  alignas(32) int32_t piece[4 * kAhead];
  alignas(32) double offset[4 * kAhead], vs[4 * kAhead];
  const __m256d kv = _mm256_set1_pd(k);
  const __m256d normv = _mm256_set1_pd(norm), dnormv = _mm256_set1_pd(dnorm);
  const int groups = (rows - first) / 4;
  const auto first_stage = [&](int g) {
    const int slot = 4 * (g % kAhead);
    const __m256d v = _mm256_mul_pd(kv, _mm256_loadu_pd(dist + first + 4 * g));
    __m128i p;
    __m256d u;
    TablePieces4(v, &p, &u);
    _mm_store_si128(reinterpret_cast<__m128i*>(piece + slot), p);
    _mm256_store_pd(offset + slot, u);
    _mm256_store_pd(vs + slot, v);
  };
  for (int g = 0; g < std::min(kAhead, groups); ++g) first_stage(g);
  for (int g = 0; g < groups; ++g) {
    const int slot = 4 * (g % kAhead);
    const double* const c[4] = {table + 6 * static_cast<long>(piece[slot]),
                                table + 6 * static_cast<long>(piece[slot + 1]),
                                table + 6 * static_cast<long>(piece[slot + 2]),
                                table + 6 * static_cast<long>(piece[slot + 3])};
    __m256d da;
    const __m256d a =
        PiecePolynomial4(c, _mm256_load_pd(offset + slot), col_dr != nullptr ? &da : nullptr);
    const __m256d a2 = _mm256_mul_pd(a, a);
    const int at = first + 4 * g;
    _mm256_storeu_pd(col + at, _mm256_mul_pd(normv, a2));
    if (col_dr != nullptr) {
      const __m256d v = _mm256_load_pd(vs + slot);
      _mm256_storeu_pd(col_dr + at,
                       _mm256_mul_pd(dnormv, _mm256_fmadd_pd(_mm256_mul_pd(a, da), v, a2)));
    }
    if (g + kAhead < groups) first_stage(g + kAhead);  // into the slot just read
  }
  iu = first + 4 * groups;
#endif
  // The remainder, rounded as the vector lanes are.
  for (; iu < rows; ++iu) {
    const double v = k * dist[iu];
    double a, da;
    TablePolynomial(table, v, &a, col_dr != nullptr ? &da : nullptr);
    const double a2 = a * a;
    col[iu] = norm * a2;
    if (col_dr != nullptr) col_dr[iu] = dnorm * std::fma(a * da, v, a2);
  }
  if (k * dist[rows - 1] < model::kAiryTableMax) return;
  for (iu = first; iu < rows; ++iu) {
    const double v = k * dist[iu];
    if (v < model::kAiryTableMax) continue;
    double a, da;
    model::AiryAmplitudeAndDerivative(v, &a, &da);
    const double a2 = a * a;
    col[iu] = norm * a2;
    if (col_dr != nullptr) col_dr[iu] = dnorm * std::fma(a * da, v, a2);
  }
}

// Copies the lower triangle of the square part of q onto its upper triangle, q(i, j) = q(j, i)
// for i < j: in 4 x 4 blocks, each read as four column pieces and written transposed, so that
// every cache line touched is used whole (element by element, the strided reads took ~10 %
// of a render).
void MirrorLowerTriangle(NodeImage* q) {
  const int n = std::min(q->cols, q->rows);
  const int rows = q->rows;
  double* data = q->data();
  int j0 = 0;
  for (; j0 + 4 <= n; j0 += 4) {
    for (int i0 = 0; i0 < j0; i0 += 4) {  // whole blocks above the diagonal
#if defined(__AVX2__)
      // The transpose in eight shuffles (element by element it took twice as long).
      __m256d src[4];  // src[t] = q(j0..j0+3, i0 + t)
      for (int t = 0; t < 4; ++t) {
        src[t] = _mm256_loadu_pd(data + static_cast<size_t>(i0 + t) * rows + j0);
      }
      const __m256d even01 = _mm256_unpacklo_pd(src[0], src[1]);  // lanes 0, 2 of src 0, 1
      const __m256d odd01 = _mm256_unpackhi_pd(src[0], src[1]);   // lanes 1, 3
      const __m256d even23 = _mm256_unpacklo_pd(src[2], src[3]);
      const __m256d odd23 = _mm256_unpackhi_pd(src[2], src[3]);
      const __m256d column[4] = {
          _mm256_permute2f128_pd(even01, even23, 0x20), _mm256_permute2f128_pd(odd01, odd23, 0x20),
          _mm256_permute2f128_pd(even01, even23, 0x31), _mm256_permute2f128_pd(odd01, odd23, 0x31)};
      for (int t = 0; t < 4; ++t) {  // column[t] = q(i0.., j0 + t)
        _mm256_storeu_pd(data + static_cast<size_t>(j0 + t) * rows + i0, column[t]);
      }
#else
      Vec4 src[4];  // src[t] = q(j0..j0+3, i0 + t)
      for (int t = 0; t < 4; ++t) src[t] = LoadVec4(data + static_cast<size_t>(i0 + t) * rows + j0);
      for (int t = 0; t < 4; ++t) {
        const Vec4 column = {src[0][t], src[1][t], src[2][t], src[3][t]};  // q(i0.., j0 + t)
        StoreVec4(data + static_cast<size_t>(j0 + t) * rows + i0, column);
      }
#endif
    }
    for (int j = j0 + 1; j < j0 + 4; ++j) {  // the diagonal block
      for (int i = j0; i < j; ++i) (*q)(i, j) = (*q)(j, i);
    }
  }
  for (int j = j0; j < n; ++j) {  // columns past the last whole block
    for (int i = 0; i < j; ++i) (*q)(i, j) = (*q)(j, i);
  }
}

// S for the Gaussian-defocus model on the whole quadrant, column by column (FillAiryColumn).
// The values are those of AiryIntensity node by node.
void FillAiryQuadrant(double k, double dk_dr, double hx, double hy, bool derivs, NodeImage* q,
                      NodeImage* q_dr, NodeDistances* distances) {
  // With equal spacings S(|i|, |j|) = S(|j|, |i|): compute the lower triangle, mirror the rest.
  static const double* const table = model::AiryTableCoefficients();
  const bool mirror = hx == hy;
  const int rows = q->rows;
  const double norm = k * k / (4.0 * M_PI);
  const double dnorm = k / (2.0 * M_PI) * dk_dr;  // d(norm a^2)/dr = dnorm (a^2 + a da k d)
  distances->Update(rows, q->cols, hx, hy);
  for (int ju = 0; ju < q->cols; ++ju) {
    // From the diagonal rounded down to whole vectors of four (rows is a multiple of 4): the
    // few nodes above the diagonal computed so are overwritten by the mirror.
    const int first = (mirror && ju < rows) ? ju / 4 * 4 : 0;
    double* col = q->data() + static_cast<size_t>(ju) * rows;
    double* col_dr = derivs ? q_dr->data() + static_cast<size_t>(ju) * rows : nullptr;
    FillAiryColumn(table, k, norm, dnorm, distances->d.data() + static_cast<size_t>(ju) * rows,
                   first, rows, col, col_dr);
  }
  if (!mirror) return;
  MirrorLowerTriangle(q);
  if (derivs) MirrorLowerTriangle(q_dr);
}

// S for the pillbox model: the mean of the Airy intensity over a disc of radius R around
// each node, and when derivs its derivatives by the Airy radius and by R. S depends on the
// node's distance only: AiryDiscProfile tabulates it over the quadrant's distances, node
// values come from its series.
void FillPillboxQuadrant(double k, double dk_dr, double radius, double hx, double hy, bool derivs,
                         NodeImage* q, NodeImage* q_dr, NodeImage* q_dR, AiryDiscProfile* profile,
                         NodeDistances* distances,
                         std::vector<AiryDiscProfile::Run>* runs_scratch) {
  const int rows = q->rows;
  // dS/dr = dS/dk dk/dr, the factor applied to the profile's samples.
  profile->Build(k, radius, std::hypot((rows - 1) * hx, (q->cols - 1) * hy), derivs, dk_dr);
  distances->Update(rows, q->cols, hx, hy);
  // With equal spacings S(|i|, |j|) = S(|j|, |i|): compute the lower triangle, mirror the rest.
  const bool mirror = hx == hy;
  std::vector<AiryDiscProfile::Run>& runs = *runs_scratch;
  runs.resize(q->cols);
  for (int ju = 0; ju < q->cols; ++ju) {
    const int first = (mirror && ju < rows) ? ju : 0;
    runs[ju] = {ju * rows + first, rows - first};
  }
  profile->Evaluate(distances->d.data(), runs.data(), q->cols, q->data(),
                    derivs ? q_dr->data() : nullptr, derivs ? q_dR->data() : nullptr);
  if (!mirror) return;
  MirrorLowerTriangle(q);
  if (!derivs) return;
  MirrorLowerTriangle(q_dr);
  MirrorLowerTriangle(q_dR);
}

}  // namespace

void NodeDistances::Update(int new_rows, int new_cols, double new_hx, double new_hy) {
  if (new_rows == rows && new_cols == cols && new_hx == hx && new_hy == hy) return;
  rows = new_rows;
  cols = new_cols;
  hx = new_hx;
  hy = new_hy;
  d.resize(static_cast<size_t>(rows) * cols);
  for (int ju = 0; ju < cols; ++ju) {
    const double y = ju * hy;
    for (int iu = 0; iu < rows; ++iu) {
      const double x = iu * hx;
      d[static_cast<size_t>(ju) * rows + iu] = std::sqrt(std::fma(x, x, y * y));
    }
  }
}

namespace {

// The upper-edge kernel of ComputeAxisWeights: k(t, s) = phi(z) / s, z = (t + 1/2) / s, at
// every node of the window, with dk/dcentre = z phi(z) / s^2 (t = pixel - centre - node) and
// dk/ds = (z^2 - 1) phi(z) / s^2. Summed against the image it gives the line integral along
// the boundary x = pixel + 1/2 [e- / px] instead of the pixel's integral.
void ComputeUpperEdgeWeights(double pixel0, double centre, double h, int q, double half_width,
                             double s, bool derivs, AxisWeights* aw,
                             std::vector<double>* edge_scratch) {
  aw->q = q;
  aw->first = static_cast<int>(std::ceil((pixel0 - centre - half_width) * q));
  const int last = static_cast<int>(std::floor((pixel0 - centre + half_width) * q));
  const int size = last - aw->first + 1;
  aw->w.resize(size, derivs ? 3 : 1);
  edge_scratch->resize(2 * static_cast<size_t>(size));
  double* z = edge_scratch->data();
  double* density = z + size;
  for (int m = 0; m < size; ++m) z[m] = (pixel0 - centre - (aw->first + m) * h + 0.5) / s;
  NormalDensities(z, size, density);
  for (int m = 0; m < size; ++m) {
    aw->w(m, 0) = h * density[m] / s;
    if (derivs) {
      aw->w(m, 1) = h * z[m] * density[m] / (s * s);
      aw->w(m, 2) = h * (z[m] * z[m] - 1.0) * density[m] / (s * s);
    }
  }
}

// The pixel kernel k(t, s) times h at every node of the window, and when
// derivs its derivatives by the centre and the width. A node's kernel is the normal
// probability between its window's edges t +- w/2; the normal's tail and density are
// evaluated once per edge. With the whole pixel collecting (w = 1 = q node spacings) node m's
// lower edge is node m + q's upper edge, which halves the (erfc, exp) evaluations.
// window <= 0 asks for the upper-edge kernel instead (AxisKernel::kUpperEdge): the normal's
// density at the pixel's upper edge, k(t, s) = phi((t + 1/2) / s) / s, the limit of the
// window's probability over its width as the window shrinks onto that edge.
void ComputeAxisWeights(double pixel0, double centre, double h, int q, double half_width, double s,
                        double window, bool derivs, AxisWeights* aw,
                        std::vector<double>* edge_scratch) {
  if (window <= 0.0) {
    ComputeUpperEdgeWeights(pixel0, centre, h, q, half_width, s, derivs, aw, edge_scratch);
    return;
  }
  aw->q = q;
  aw->first = static_cast<int>(std::ceil((pixel0 - centre - half_width) * q));
  const int last = static_cast<int>(std::floor((pixel0 - centre + half_width) * q));
  const int size = last - aw->first + 1;
  aw->w.resize(size, derivs ? 3 : 1);
  const double half = 0.5 * window;
  const bool shared = window == 1.0;
  // Edges: [0, n_upper) the upper edges of nodes 0, 1, ... (shared: also the lower edges,
  // node m's at m + q); then, not shared, the lower edges of nodes 0..size-1.
  const int n_upper = shared ? size + q : size;
  const int n_edges = shared ? n_upper : 2 * size;
  // Per edge: z = edge / s, the tail 0.5 erfc(|z| / sqrt 2) (one side, so that far from the
  // centre the difference of two tails keeps its relative precision), the density phi(z).
  edge_scratch->resize(3 * static_cast<size_t>(n_edges));
  double* z = edge_scratch->data();
  double* tail = z + n_edges;
  double* density = tail + n_edges;
  for (int e = 0; e < n_edges; ++e) {
    const int node = e < n_upper ? e : e - n_upper;
    const double t = pixel0 - centre - (aw->first + node) * h;
    z[e] = (e < n_upper ? t + half : t - half) / s;
  }
  NormalTailsAndDensities(z, n_edges, tail, derivs ? density : nullptr);
  for (int m = 0; m < size; ++m) {
    const int up = m, lo = shared ? m + q : n_upper + m;
    const double zp = z[up], zm = z[lo];
    double value;
    if (zm >= 0.0) {
      value = tail[lo] - tail[up];  // both edges above the centre
    } else if (zp <= 0.0) {
      value = tail[up] - tail[lo];  // both below
    } else {
      value = 1.0 - tail[up] - tail[lo];  // the window straddles the centre
    }
    aw->w(m, 0) = h * value;
    if (derivs) {
      // dk/dt = (phi(zp) - phi(zm)) / s; t = pixel - centre - node, so d/dcentre = -d/dt.
      aw->w(m, 1) = -h * (density[up] - density[lo]) / s;
      aw->w(m, 2) = -h * (zp * density[up] - zm * density[lo]) / s;  // dk/ds
    }
  }
}

// The inner loop of both passes: for r < R,
//   out[r * out_stride + t] = sum_m w[r * w_stride + m] * base[offset[m] + t],
// for t in [start, start + 4 V). The 4 V sums of each weight row stay in registers through
// the whole sum over nodes m, so each input vector is loaded once for R rows of weights and
// each output is stored once (register blocking: a load per multiply-add for R = 1, a third
// of one for R = 3, against two loads and a store per multiply-add for a plain axpy).
template <int R, int V>
inline void WeightedSumsBlock(int nodes, const double* base, const size_t* offset, const double* w,
                              int w_stride, int start, double* out, int out_stride) {
  Vec4 acc[R][V];
  for (int r = 0; r < R; ++r) {
    for (int v = 0; v < V; ++v) acc[r][v] = Vec4{0.0, 0.0, 0.0, 0.0};
  }
  for (int m = 0; m < nodes; ++m) {
    const double* x = base + offset[m] + start;
    Vec4 in[V];
    for (int v = 0; v < V; ++v) in[v] = LoadVec4(x + 4 * v);
    for (int r = 0; r < R; ++r) {
      const double wr = w[r * w_stride + m];
      for (int v = 0; v < V; ++v) acc[r][v] += wr * in[v];
    }
  }
  for (int r = 0; r < R; ++r) {
    for (int v = 0; v < V; ++v) StoreVec4(out + r * out_stride + start + 4 * v, acc[r][v]);
  }
}

// WeightedSumsBlock over t in [0, length), length a multiple of 4: blocks of 4 V, then one
// block of whatever is left (so that short lengths still have several independent sums in
// flight: one multiply-add's latency is several cycles).
template <int R, int V>
void WeightedSums(int nodes, const double* base, const size_t* offset, const double* w,
                  int w_stride, int length, double* out, int out_stride) {
  int start = 0;
  for (; start + 4 * V <= length; start += 4 * V) {
    WeightedSumsBlock<R, V>(nodes, base, offset, w, w_stride, start, out, out_stride);
  }
  switch ((length - start) / 4) {
#define CCDPSF_REST(n)                                                                   \
  case n:                                                                                \
    if constexpr (n < V) {                                                               \
      WeightedSumsBlock<R, n>(nodes, base, offset, w, w_stride, start, out, out_stride); \
    }                                                                                    \
    break;
    CCDPSF_REST(1)
    CCDPSF_REST(2)
    CCDPSF_REST(3)
    CCDPSF_REST(4)
    CCDPSF_REST(5)
    CCDPSF_REST(6)
    CCDPSF_REST(7)
#undef CCDPSF_REST
    default:
      break;
  }
}
// Block sizes: R x V accumulators plus V inputs fit the 16 vector registers of AVX2.
inline void WeightedSums1(int nodes, const double* base, const size_t* offset, const double* w,
                          int length, double* out) {
  WeightedSums<1, 8>(nodes, base, offset, w, 0, length, out, 0);
}
inline void WeightedSums3(int nodes, const double* base, const size_t* offset, const double* w,
                          int w_stride, int length, double* out, int out_stride) {
  WeightedSums<3, 3>(nodes, base, offset, w, w_stride, length, out, out_stride);
}

// WeightedSums1 for two output lines whose nodes are q apart: line 0 sums nodes m = 0..n-1,
// line 1 nodes m = q..q+n-1 with weight w[m - q], both through offset[]. The nodes the lines
// share (q <= m < n) are loaded once for both: half the loads of two WeightedSums1 calls
// for the same multiply-adds, in the same order (so the same sums, bit for bit). Blocks of
// at most 6 vectors: 2 x 6 sums, an input and two weights fill the 16 AVX2 registers; the
// blocks are of nearly equal sizes, so that none is too short to hide the multiply-add
// latency.
template <int V>
inline void PairSumsBlock(int n, int q, const double* base, const size_t* offset, const double* w,
                          int start, double* out0, double* out1) {
  Vec4 acc0[V], acc1[V];
  for (int v = 0; v < V; ++v) acc0[v] = acc1[v] = Vec4{0.0, 0.0, 0.0, 0.0};
  const int shared_begin = std::min(q, n), shared_end = std::max(q, n);
  for (int m = 0; m < shared_begin; ++m) {  // line 0 only
    const double* x = base + offset[m] + start;
    for (int v = 0; v < V; ++v) acc0[v] += w[m] * LoadVec4(x + 4 * v);
  }
  for (int m = q; m < n; ++m) {  // both lines
    const double* x = base + offset[m] + start;
    const double w0 = w[m], w1 = w[m - q];
    for (int v = 0; v < V; ++v) {
      const Vec4 in = LoadVec4(x + 4 * v);
      acc0[v] += w0 * in;
      acc1[v] += w1 * in;
    }
  }
  for (int m = shared_end; m < n + q; ++m) {  // line 1 only
    const double* x = base + offset[m] + start;
    for (int v = 0; v < V; ++v) acc1[v] += w[m - q] * LoadVec4(x + 4 * v);
  }
  for (int v = 0; v < V; ++v) {
    StoreVec4(out0 + start + 4 * v, acc0[v]);
    StoreVec4(out1 + start + 4 * v, acc1[v]);
  }
}
// PairSumsBlock over t in [0, length), length a multiple of 4.
void PairSums(int n, int q, const double* base, const size_t* offset, const double* w, int length,
              double* out0, double* out1) {
  constexpr int kMaxVectors = 6;
  const int vectors = length / 4;
  const int blocks = (vectors + kMaxVectors - 1) / kMaxVectors;
  int start = 0;
  for (int block = 0; block < blocks; ++block) {
    // The first (vectors % blocks) blocks take one vector more than the others.
    const int size = vectors / blocks + (block < vectors % blocks ? 1 : 0);
    switch (size) {
#define CCDPSF_BLOCK(v)                                         \
  case v:                                                       \
    PairSumsBlock<v>(n, q, base, offset, w, start, out0, out1); \
    break;
      CCDPSF_BLOCK(1)
      CCDPSF_BLOCK(2)
      CCDPSF_BLOCK(3)
      CCDPSF_BLOCK(4)
      CCDPSF_BLOCK(5)
      CCDPSF_BLOCK(6)
#undef CCDPSF_BLOCK
      default:
        break;
    }
    start += 4 * size;
  }
}

// Stores four first-pass output rows (rows[l * row_size + rhs * nh + i], for b = b0 + l) into
// bt[(i * nr + rhs) * ny_pad + b0 + l]: a 4 x 4 transpose per four nodes, so that each store
// writes four b at once (one strided store per value measured ~15 % of a render).
void TransposeStore4(const double* rows, size_t row_size, int nh, int nr, int ny_pad, int b0,
                     double* bt) {
  for (int r = 0; r < nr; ++r) {
    const double* x0 = rows + r * nh;
    const double* x1 = x0 + row_size;
    const double* x2 = x1 + row_size;
    const double* x3 = x2 + row_size;
    for (int i = 0; i < nh; i += 4) {  // nh is a multiple of 4
      const Vec4 a = LoadVec4(x0 + i), b = LoadVec4(x1 + i);
      const Vec4 c = LoadVec4(x2 + i), d = LoadVec4(x3 + i);
      for (int t = 0; t < 4; ++t) {
        const Vec4 column = {a[t], b[t], c[t], d[t]};
        StoreVec4(bt + (static_cast<size_t>(i + t) * nr + r) * ny_pad + b0, column);
      }
    }
  }
}

}  // namespace

double QuadratureStep(double rho_c, double s, double tolerance) {
  // Solve 2 pi^2 s^2 D^2 = log(8 rho_c^2 / (pi D tol)) for D by fixed-point steps D <- g(D).
  // An integer number of nodes per pixel, ceil(rho_c + D), is all that is used: the spacing
  // is piecewise constant in the widths (so the derivatives are those of the sum), and every
  // pixel sees the same kernel weights. g is non-increasing, so two successive steps bracket
  // the fixed point; once both give the same integer, so does the fixed point (usually after
  // two steps: six, with their logarithms, were ~1.5 % of a values-only render).
  const double log_scale = std::log(8.0 * rho_c * rho_c / (M_PI * tolerance));
  const auto g = [&](double delta) {
    const double rhs = std::max(log_scale - std::log(delta), std::log(2.0));
    return std::max(std::sqrt(rhs / (2.0 * M_PI * M_PI * s * s)), 0.25);
  };
  double delta = g(1.0);
  double nodes = std::ceil(rho_c + delta);
  for (int iter = 0; iter < 40; ++iter) {
    delta = g(delta);
    const double next = std::ceil(rho_c + delta);
    if (next == nodes) break;
    nodes = next;
  }
  return 1.0 / nodes;
}

void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& p,
                      const model::PixelGrid& grid, double* model_out, double* jacobian,
                      IntegratedWorkspace* ws, AxisKernel kernel_x, AxisKernel kernel_y) {
  const IntegratedOutput output{grid, kernel_x, kernel_y, model_out, jacobian};
  RenderIntegrated(options, p, &output, 1, ws);
}

void RenderIntegrated(const model::ModelOptions& options, const model::SpotParams& p,
                      const IntegratedOutput* outputs, int count, IntegratedWorkspace* ws) {
  CHECK_GE(count, 1);
  CHECK_LE(count, kMaxIntegratedOutputs);
  const bool pillbox = options.defocus == model::DefocusKind::kPillbox;
  const double cx = p[kCentreX], cy = p[kCentreY];
  const double r = p[kAiryRadius];
  const double defocus = p[kDefocus];
  const double sx = pillbox ? p[kCcdSigmaX] : std::hypot(defocus, p[kCcdSigmaX]);
  const double sy = pillbox ? p[kCcdSigmaY] : std::hypot(defocus, p[kCcdSigmaY]);
  const double rho_c = model::kAiryRz / r;
  const double k = M_PI * model::kAiryRz / r;
  const double dk_dr = -k / r;
  const double tol = options.relative_tolerance;

  // With the pillbox, S is the expensive part and the passes cheap: one spacing for both
  // axes (the finer; a finer spacing only lowers the error bound) makes the quadrant
  // symmetric, S(|i|, |j|) = S(|j|, |i|), which halves the nodes to fill.
  const double step_x = QuadratureStep(rho_c, sx, tol), step_y = QuadratureStep(rho_c, sy, tol);
  const double hx = pillbox ? std::min(step_x, step_y) : step_x;
  const double hy = pillbox ? std::min(step_x, step_y) : step_y;
  const int qx = static_cast<int>(std::lround(1.0 / hx));
  const int qy = static_cast<int>(std::lround(1.0 / hy));
  const double tw = KernelHalfWidthSigmas(tol);
  const bool derivs = outputs[0].jacobian != nullptr;
  for (int o = 1; o < count; ++o) CHECK_EQ(outputs[o].jacobian != nullptr, derivs);

  // A collecting window narrower than the pixel (ModelOptions::pixel_response_width) only
  // shortens the reach of each node; the error bound holds as it is (|sinc(w f)| <= 1). So
  // does the upper-edge kernel (window 0 below): its transform is the Gaussian's times a phase.
  // The edge kernel's nodes reach T s either side of the pixel's upper edge.
  const double window = options.pixel_response_width;
  const auto window_of = [&](AxisKernel kernel) {
    return kernel == AxisKernel::kUpperEdge ? 0.0 : window;
  };
  const auto reach_of = [&](double w, double s) { return 0.5 * (w > 0.0 ? w : 1.0) + tw * s; };

  // The first pass (along y) depends on the outputs' y kernel and rows only: outputs that
  // integrate along y alike share one, over the union of their rows (a group); each output
  // then reads its rows from it. Rows of one group lie a whole number of pixels apart.
  int group_of[kMaxIntegratedOutputs];
  int row_offset[kMaxIntegratedOutputs];  // the output's first row in its group's
  struct Group {
    AxisKernel kernel;
    double y0;
    int ny;      // rows computed
    int ny_pad;  // rows stored (a multiple of 4, >= every member's offset + padded rows)
  };
  Group groups[kMaxIntegratedOutputs];
  int num_groups = 0;
  for (int o = 0; o < count; ++o) {
    const IntegratedOutput& out = outputs[o];
    CHECK_GT(out.grid.nx, 0);
    CHECK_GT(out.grid.ny, 0);
    int g = 0;
    while (g < num_groups && groups[g].kernel != out.kernel_y) ++g;
    if (g == num_groups) groups[num_groups++] = {out.kernel_y, out.grid.y0, out.grid.ny, 0};
    group_of[o] = g;
    Group& group = groups[g];
    const double first = std::min(group.y0, out.grid.y0);
    const double last = std::max(group.y0 + group.ny - 1, out.grid.y0 + out.grid.ny - 1);
    CHECK_LT(std::abs(out.grid.y0 - group.y0 - std::round(out.grid.y0 - group.y0)), 1e-9)
        << "outputs sharing a first pass must lie whole pixels apart";
    group.ny = static_cast<int>(std::lround(last - first)) + 1;
    group.y0 = first;
  }
  for (int o = 0; o < count; ++o) {
    Group& group = groups[group_of[o]];
    row_offset[o] = static_cast<int>(std::lround(outputs[o].grid.y0 - group.y0));
    const int ny_pad = (outputs[o].grid.ny + 3) / 4 * 4;
    group.ny_pad = std::max({group.ny_pad, (group.ny + 3) / 4 * 4, row_offset[o] + ny_pad});
  }

  // Kernel weights: along x per output, along y per group.
  for (int o = 0; o < count; ++o) {
    const double wo = window_of(outputs[o].kernel_x);
    ComputeAxisWeights(outputs[o].grid.x0, cx, hx, qx, reach_of(wo, sx), sx, wo, derivs,
                       &ws->wx[o], &ws->edges);
  }
  for (int g = 0; g < num_groups; ++g) {
    const double wg = window_of(groups[g].kernel);
    ComputeAxisWeights(groups[g].y0, cy, hy, qy, reach_of(wg, sy), sy, wg, derivs, &ws->wy[g],
                       &ws->edges);
  }
  // Node ranges: every node some pixel of some output sees.
  int i_lo = 0, i_hi = 0, j_lo = 0, j_hi = 0;
  for (int o = 0; o < count; ++o) {
    const AxisWeights& wx = ws->wx[o];
    const int lo = wx.first, hi = wx.first + qx * (outputs[o].grid.nx - 1) + wx.w.rows() - 1;
    i_lo = o == 0 ? lo : std::min(i_lo, lo);
    i_hi = o == 0 ? hi : std::max(i_hi, hi);
  }
  for (int g = 0; g < num_groups; ++g) {
    const AxisWeights& wy = ws->wy[g];
    const int lo = wy.first, hi = wy.first + qy * (groups[g].ny - 1) + wy.w.rows() - 1;
    j_lo = g == 0 ? lo : std::min(j_lo, lo);
    j_hi = g == 0 ? hi : std::max(j_hi, hi);
  }
  const int ni = i_hi - i_lo + 1, nj = j_hi - j_lo + 1;
  CHECK_LE(static_cast<double>(ni) * nj, kMaxNodes) << "quadrature grid too large";

  // Radial image S on the nodes, through the symmetric quadrant.
  const int iu_max = std::max(std::abs(i_lo), std::abs(i_hi));
  const int ju_max = std::max(std::abs(j_lo), std::abs(j_hi));
  // Rows |i| of the half problem, padded to whole vectors of four (the extra rows hold S at
  // further nodes, computed like the others and never read into the output).
  const int nh = (iu_max + 1 + 3) / 4 * 4;
  // With equal spacings the fill mirrors S(|i|, |j|) = S(|j|, |i|) on a square quadrant, so
  // that which nodes are computed and which copied does not depend on the stamp.
  const bool square = hx == hy;
  QuadrantKey key{k, hx, hy, pillbox ? defocus : -1.0, nh, ju_max + 1, derivs};
  if (square) key.rows = key.cols = std::max(nh, (ju_max + 1 + 3) / 4 * 4);
  // S depends on neither the centre nor the grid's place, so the exposures of a joint fit
  // (one Airy radius and one set of widths) share it: it is filled only when the last fill
  // does not serve. A fill is a pure function of the key, and the passes below read only the
  // nh x (ju_max + 1) nodes they need, so reuse changes no value.
  if (!ws->quadrant_key.Serves(key)) {
    const QuadrantKey last = ws->quadrant_key;
    if (last.k == k && last.hx == hx && last.hy == hy &&
        last.pillbox_radius == key.pillbox_radius) {
      // The same S for another stamp (a joint fit's exposures sit at other sub-pixel places
      // in their stamps, which moves the farthest node by up to q / 2): room for them too.
      key.rows = std::max(key.rows, last.rows) + 4;
      key.cols = square ? key.rows : std::max(key.cols, last.cols) + 4;
      key.derivs = key.derivs || last.derivs;
    }
    ws->quadrant_key = QuadrantKey();  // nothing valid while the fill runs
    const int rows = key.rows, cols = key.cols;
    // The tables must reach the farthest node (the pillbox's, its profile's reach plus the disc's
    // radius).
    const double d_max = std::hypot((rows - 1) * hx, (cols - 1) * hy);
    if (pillbox) {
      EnsureDiscAverageTables(k * (AiryDiscProfile::Reach(k, d_max) + defocus));
    } else {
      model::EnsureAiryTable(k * d_max);
    }
    ws->quadrant.Resize(rows, cols);
    ws->quadrant_dr.Resize(rows, cols);
    if (pillbox && defocus > 0.0) {
      ws->quadrant_dR.Resize(rows, cols);
      FillPillboxQuadrant(k, dk_dr, defocus, hx, hy, key.derivs, &ws->quadrant, &ws->quadrant_dr,
                          &ws->quadrant_dR, &ws->pillbox_profile, &ws->distances,
                          &ws->pillbox_runs);
    } else {
      FillAiryQuadrant(k, dk_dr, hx, hy, key.derivs, &ws->quadrant, &ws->quadrant_dr,
                       &ws->distances);
      // A pillbox of zero radius: S = Airy, and dS/dR = 0 there (S - Airy is O(R^2)).
      if (pillbox) {
        ws->quadrant_dR.Resize(rows, cols);
        std::fill_n(ws->quadrant_dR.data(), static_cast<size_t>(rows) * cols, 0.0);
      }
    }
    ws->quadrant_key = key;
  }
  const int stride = ws->quadrant.rows;  // between node columns of S

  // First pass, along y, per group: B(|i|, b) = hy sum_j S(|i|, j) ky(yb - cy - j hy), and the
  // same with d ky / d cy, d ky / d sY, and with dS / dr (and dS / dR): nr right-hand sides.
  // Hand-written loops: at these sizes (~75 x 40 per output row) a general matrix product
  // spends more time packing than multiplying. The sums run down contiguous columns of S
  // (node column j is quadrant column |j|: S(i, -j) = S(i, j), read in place); each finished
  // row b is stored transposed, bt[(|i| * nr + rhs) * ny_pad + b], so that the second pass
  // runs over b in the same way, with the right-hand sides of one node side by side.
  const int nr = derivs ? (pillbox ? 5 : 4) : 1;
  // A group's first pass needs the node columns its members' second passes read, |i| up to
  // their farthest (the densities of a window near the spot need fewer than the stamp).
  int group_nh[kMaxIntegratedOutputs] = {};
  for (int o = 0; o < count; ++o) {
    const AxisWeights& wx = ws->wx[o];
    const int lo = wx.first, hi = wx.first + qx * (outputs[o].grid.nx - 1) + wx.w.rows() - 1;
    const int needed = (std::max(std::abs(lo), std::abs(hi)) + 1 + 3) / 4 * 4;
    group_nh[group_of[o]] = std::max(group_nh[group_of[o]], needed);
  }
  ws->row.resize(4 * static_cast<size_t>(nr) * nh);
  int max_wy = 0;
  for (int g = 0; g < num_groups; ++g) max_wy = std::max(max_wy, static_cast<int>(ws->wy[g].w.rows()) + qy);
  int max_wx = 0;
  for (int o = 0; o < count; ++o) max_wx = std::max(max_wx, static_cast<int>(ws->wx[o].w.rows()));
  ws->offset.resize(std::max(max_wx, max_wy));
  size_t* offset = ws->offset.data();
  for (int g = 0; g < num_groups; ++g) {
    const AxisWeights& wy = ws->wy[g];
    const int ny = groups[g].ny, ny_pad = groups[g].ny_pad;
    const int nh_g = group_nh[g];
    const size_t row_size = static_cast<size_t>(nr) * nh_g;  // one row b, [rhs * nh_g + |i|]
    // Node |i| keeps its place in bt whatever the group's nh_g: [(|i| * nr + rhs) * ny_pad + b].
    ws->bt[g].resize(static_cast<size_t>(nr) * nh_g * ny_pad);
    const int wy_size = static_cast<int>(wy.w.rows());
    // Rows b in fours, so that the transposed stores are of four b at once.
    for (int b0 = 0; b0 < ny_pad; b0 += 4) {
      // Rows b, b + 1 in pairs: the nodes of row b + 1 are those of row b shifted by qy, so
      // offsets m < wy_size + qy serve both, and single-weight sums run on both at once.
      for (int l = 0; l < 4; l += 2) {
        const int b = b0 + l;
        double* row = ws->row.data() + l * row_size;
        double* next = row + row_size;
        if (b >= ny) {
          std::fill_n(row, 2 * row_size, 0.0);
          continue;
        }
        for (int m = 0; m < wy_size + qy; ++m) {
          offset[m] = static_cast<size_t>(std::abs(wy.first + qy * b + m)) * stride;
        }
        const bool pair = b + 1 < ny;
        if (!pair) std::fill_n(next, row_size, 0.0);
        if (derivs) {
          WeightedSums3(wy_size, ws->quadrant.data(), offset, wy.w.data(), wy_size, nh_g, row, nh_g);
          if (pair) {
            WeightedSums3(wy_size, ws->quadrant.data(), offset + qy, wy.w.data(), wy_size, nh_g,
                          next, nh_g);
          }
        }
        // Single-weight sums: S (values only), else dS/dr and dS/dR.
        for (int rhs = derivs ? 3 : 0; rhs < nr; ++rhs) {
          const double* base = (rhs == 0   ? ws->quadrant
                                : rhs == 3 ? ws->quadrant_dr
                                           : ws->quadrant_dR)
                                   .data();
          if (pair) {
            PairSums(wy_size, qy, base, offset, wy.w.data(), nh_g, row + rhs * nh_g,
                     next + rhs * nh_g);
          } else {
            WeightedSums1(wy_size, base, offset, wy.w.data(), nh_g, row + rhs * nh_g);
          }
        }
      }
      TransposeStore4(ws->row.data(), row_size, nh_g, nr, ny_pad, b0, ws->bt[g].data());
    }
  }

  // Second pass, along x, per output: M(a, b) = hx sum_i kx(xa - cx - i hx) B(|i|, b), over
  // the output's rows b of its group's B.
  const double flux = p[kFlux];
  const double gx = (!pillbox && sx > 0) ? defocus / sx : 0.0;  // d sX / d sigma_f
  const double gy = (!pillbox && sy > 0) ? defocus / sy : 0.0;
  const double fx = pillbox ? 1.0 : p[kCcdSigmaX] / sx;          // d sX / d sigma_x
  const double fy = pillbox ? 1.0 : p[kCcdSigmaY] / sy;
  // acc rows: value, d/dcx, d/dsX, d/dcy, d/dsY, d/dr, d/dR.
  const int nacc = derivs ? (pillbox ? 7 : 6) : 1;
  for (int o = 0; o < count; ++o) {
    const model::PixelGrid& grid = outputs[o].grid;
    double* const model_out = outputs[o].values;
    double* const jacobian = outputs[o].jacobian;
    const AxisWeights& wx = ws->wx[o];
    const int wx_size = static_cast<int>(wx.w.rows());
    const int ny = grid.ny;
    const int ny_pad = (ny + 3) / 4 * 4;
    const int group_pad = groups[group_of[o]].ny_pad;
    ws->acc.resize(static_cast<size_t>(nacc) * ny_pad);
    double* acc = ws->acc.data();
    const int node_stride = nr * group_pad;  // one node's right-hand sides in bt
    const double* bt = ws->bt[group_of[o]].data() + row_offset[o];
    // The right-hand sides after the value lie group_pad apart; when that is the output's
    // own padded length they are one contiguous run.
    const bool contiguous = group_pad == ny_pad;
    for (int a = 0; a < grid.nx; ++a) {
      const int first = wx.first + qx * a;
      for (int m = 0; m < wx_size; ++m) {
        offset[m] = static_cast<size_t>(std::abs(first + m)) * node_stride;
      }
      if (derivs) {
        // B with the three weights, then every other right-hand side with the value weight.
        WeightedSums3(wx_size, bt, offset, wx.w.data(), wx_size, ny_pad, acc, ny_pad);
        if (contiguous) {
          WeightedSums1(wx_size, bt + ny_pad, offset, wx.w.data(), (nr - 1) * ny_pad,
                        acc + 3 * ny_pad);
        } else {
          for (int rhs = 1; rhs < nr; ++rhs) {
            WeightedSums1(wx_size, bt + static_cast<size_t>(rhs) * group_pad, offset, wx.w.data(),
                          ny_pad, acc + (2 + rhs) * ny_pad);
          }
        }
      } else {
        WeightedSums1(wx_size, bt, offset, wx.w.data(), ny_pad, acc);
      }
      for (int b = 0; b < ny; ++b) {
        const int pix = b * grid.nx + a;
        model_out[pix] = flux * acc[b];
        if (!derivs) continue;
        double* jrow = jacobian + static_cast<size_t>(pix) * kNumSpotParams;
        const double d_sx = acc[2 * ny_pad + b], d_sy = acc[4 * ny_pad + b];
        jrow[kFlux] = acc[b];
        jrow[kCentreX] = flux * acc[ny_pad + b];
        jrow[kCentreY] = flux * acc[3 * ny_pad + b];
        jrow[kAiryRadius] = flux * acc[5 * ny_pad + b];
        jrow[kDefocus] = pillbox ? flux * acc[6 * ny_pad + b] : flux * (d_sx * gx + d_sy * gy);
        jrow[kCcdSigmaX] = flux * d_sx * fx;
        jrow[kCcdSigmaY] = flux * d_sy * fy;
      }
    }
  }
}

}  // namespace ccdpsf::internal
