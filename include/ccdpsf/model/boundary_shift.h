// Brighter-fatter as a CCD makes it: pixel boundaries moved by the charge already collected
// (the catalogue's `boundary_shift`; Antilogus et al. 2014, Guyonnet et al. 2015, Astier et
// al. 2019, Coulton et al. 2018).
//
// Coefficients. a_ij [1/e-] is the fractional area change of pixel (i, j) per electron held
// in pixel (0, 0) (Astier et al. 2019's convention; i along x, j along y): the charge pushes
// the boundaries of its own pixel inwards, so a_00 < 0 and the neighbours gain, a_ij > 0.
// Boundaries only move, so no area is made or lost: the sum of a_ij over all lags is 0 (the
// sum rule), and in a flat of mean mu [e-] the covariances are C_ij = a_ij mu^2 to first order.
// The model's coefficients:
//   a_10, a_01, a_11   the nearest lags, free (a_-1,0 = a_10 and so on by symmetry);
//   a_far              the lags at distance r = sqrt(i^2 + j^2) >= 2 follow a power law,
//                      a_ij = a_far (2 / r)^kFarExponent, out to |i|, |j| <= kLagRange and
//                      0 beyond (a_far is the coefficient at r = 2, e.g. a_20);
//   a_00               from the sum rule: minus the sum of all the others.
// The far exponent is held, not fitted: a spot's light falls within two pixels of its centre,
// so spots do not measure the far lags' shape; flats do (`ccdpsf ptc` reports a_ij per lag).
// kFarExponent = 4: the collected charge sits next to the gate electrodes, which screen it
// like an image charge, so far away its lateral field - a boundary's shift - is a dipole's,
// falling as the cube of the distance, and a_ij, the divergence of the shifts, as the fourth
// power. Through the sum rule the far lags set a_00 and so what a spot's centre loses: with
// the power 3 the model moved 10.6 % more charge out of the centre of a bright spot than the
// photon-shooting reference sensor (docs/conventions.md, boundary_shift_sensor_test.cc).
//
// From areas to boundaries. A spot needs the shift of each boundary, not only the areas. As
// Coulton et al. 2018, the shifts are taken as the gradient of a potential K with a = lap K
// (the discrete Laplacian): the boundary between pixels (i, j) and (i + 1, j) moves along +x by
//   Dx(i, j) = K(i + 1, j) - K(i, j)                      per electron in (0, 0) [px / e-]
// and the one between (i, j) and (i, j + 1) along +y by Dy(i, j) = K(i, j + 1) - K(i, j); the
// outward moves of pixel (i, j)'s four sides then add up to exactly a_ij. K is linear in the
// coefficients, so each coefficient's K (and Dx, Dy) is computed once (Basis()).
//
// Stiffness. The areas do not fix the shifts: a pattern of shifts without divergence moves
// boundaries without changing any area, so flats cannot see it, while a spot, whose light
// crosses the boundaries, does. A CCD makes its column boundaries with channel stops and its
// row boundaries with gate potentials, which yield differently to the same field: a field
// E = -grad phi moves them by s_x d phi / dx and s_y d phi / dy. With s_x = 1 + eta and
// s_y = 1 - eta (eta = `anisotropy`, dimensionless) and the areas kept at a_ij, K solves
//   (1 + eta) dxx K + (1 - eta) dyy K = a,  Dx = (1 + eta) dx+ K,  Dy = (1 - eta) dy+ K,
// and the model keeps this to first order in eta:
//   Dx = Dx0 + eta Ex,  Dy = Dy0 + eta Ey,  (Ex, Ey) = (dx+ (K0 + K1), dy+ (-K0 + K1)),
//   K1 = -lap^-1 (dxx - dyy) K0,
// whose divergence is exactly 0 for every eta: the areas stay a_ij, the sum rule holds, and
// flats (C_ij = a_ij mu^2) are unchanged. eta = 0 is the potential field above; a sensor whose
// column boundaries yield 0.78 times as much as its rows (B_x / B_y of the reference sensor) has
// eta = (0.78 - 1) / (0.78 + 1) = -0.12, where the second-order term is ~eta^2 = 1.5 % of the
// shifts. Spots measure eta only together with the areas; with the flats' a_ij as a prior
// (`--ptc`) the spots measure it well.
//
// The charge arrives during the exposure, so the first electrons see the undistorted pixels
// and the last the full distortion. With a constant illumination the charge collected by time
// t is (t / T) of the final charge Q, the shifts grow in proportion, and to first order in
// a Q the pixel (i, j) gains
//   dQ_ij = 1/2 [X(i, j) Lx(i, j) - X(i - 1, j) Lx(i - 1, j) + Y(i, j) Ly(i, j) - Y(i, j - 1) Ly(i,
//   j - 1)]
// where X(i, j) = sum_kl Dx(i - k, j - l) Q_kl is the final shift of the boundary at
// x = i + 1/2 in row j [px], Lx(i, j) the line integral of the spot's continuous image along
// that boundary [e- / px] (Y, Ly likewise along y), and 1/2 the time average of a shift that
// grows linearly from 0. The sum over pixels of dQ is 0 (each boundary's gain is its
// neighbour's loss): charge is conserved. The charge moved so is itself moved again (the
// second term of dQ/dt = M + S Q, Q = M + S M / 2 + S^2 M / 6). And each side moves rigidly,
// so where two sides of one pixel both move into it the patch beyond both (area the product
// of their shifts) goes to the diagonal neighbour, not to the two edge neighbours the strips
// give it to: at each corner, +P, -P, -P, +P to the lower-left, lower-right, upper-left and
// upper-right pixels, P the signed products of such pairs times the light at the corner and
// 1/3 (the area grows as the square of the charge). docs/conventions.md gives the error
// against an exact sequential accumulation and against the photon-shooting sensor.
//
// Units: lengths in pixels [px], charges in electrons [e-], coefficients per electron [1/e-].
#ifndef CCDPSF_MODEL_BOUNDARY_SHIFT_H_
#define CCDPSF_MODEL_BOUNDARY_SHIFT_H_

#include <array>
#include <cstddef>
#include <vector>

namespace ccdpsf::model {

// Lags |i|, |j| <= kLagRange carry a coefficient; the far power law stops there.
constexpr int kBoundaryShiftLagRange = 5;
constexpr double kBoundaryShiftFarExponent = 4.0;
// Boundary shifts are kept for charges up to kBoundaryShiftReach pixels away along each axis:
// beyond, the shift of the potential of a charge-neutral pattern of coefficients (a
// quadrupole-like field) is below 1e-3 of the nearest boundary's (checked in a test).
constexpr int kBoundaryShiftReach = 8;

struct BoundaryShiftParams {
  // The catalogue's realistic strengths (their reasoning is in effects.cc).
  double a_10 = 1.5e-7;   // [1/e-] area gain of the pixel one column over, per electron
  double a_01 = 2.0e-7;   // [1/e-] ... one row over (parallel boundaries)
  double a_11 = 6.0e-8;   // [1/e-] ... diagonal
  double a_far = 1.5e-8;  // [1/e-] at lag distance 2, falling as (2 / r)^kFarExponent
  double anisotropy = 0.0;  // eta: column boundaries yield (1 + eta), rows (1 - eta) (above)
};
// a_10, a_01, a_11, a_far, anisotropy: the order of every vector. The first
// kNumBoundaryShiftCoefficients are the area coefficients.
constexpr int kNumBoundaryShiftParams = 5;
constexpr int kNumBoundaryShiftCoefficients = 4;
constexpr int kBoundaryShiftAnisotropy = 4;  // the index of anisotropy

// The coefficients of `p` as an array of values in parameter order.
std::array<double, kNumBoundaryShiftParams> BoundaryShiftValues(const BoundaryShiftParams& p);

// a_ij of one parameter at unit value (its lag pattern, a_00 included by the sum rule; 0 for
// the anisotropy, which changes no area) and of a parameter set; lag (i, j) with |i|, |j| <=
// kBoundaryShiftLagRange.
double BoundaryShiftBasisCoefficient(int parameter, int i, int j);
double BoundaryShiftCoefficient(const BoundaryShiftParams& p, int i, int j);

// The boundary shifts per electron of each area coefficient at unit value: Dx(p, i, j) and
// Dy(p, i, j) (the potential field), and its anisotropy pattern Ex(p, i, j), Ey(p, i, j) (the
// shifts per unit eta), for |i|, |j| <= kBoundaryShiftReach (0 beyond), from K solved once per process
// on a 128 x 128 periodic lattice (the images of a charge-neutral pattern 128 px away change
// the shifts by < 1e-6 of the nearest one).
class BoundaryShiftBasis {
 public:
  static const BoundaryShiftBasis& Get();
  static constexpr int kSide = 2 * kBoundaryShiftReach + 1;
  double Dx(int parameter, int i, int j) const { return At(dx_, parameter, i, j); }
  double Dy(int parameter, int i, int j) const { return At(dy_, parameter, i, j); }
  double Ex(int parameter, int i, int j) const { return At(ex_, parameter, i, j); }
  double Ey(int parameter, int i, int j) const { return At(ey_, parameter, i, j); }
  // One parameter's whole table, kSide x kSide, [j + reach][i + reach] (the kernels' layout).
  const double* DxTable(int parameter) const { return Table(dx_, parameter); }
  const double* DyTable(int parameter) const { return Table(dy_, parameter); }
  const double* ExTable(int parameter) const { return Table(ex_, parameter); }
  const double* EyTable(int parameter) const { return Table(ey_, parameter); }

 private:
  BoundaryShiftBasis();
  static double At(const std::vector<double>& table, int parameter, int i, int j) {
    if (i < -kBoundaryShiftReach || i > kBoundaryShiftReach || j < -kBoundaryShiftReach ||
        j > kBoundaryShiftReach) {
      return 0.0;
    }
    return table[(static_cast<size_t>(parameter) * kSide + (j + kBoundaryShiftReach)) * kSide +
                 (i + kBoundaryShiftReach)];
  }
  static const double* Table(const std::vector<double>& table, int parameter) {
    return table.data() + static_cast<size_t>(parameter) * kSide * kSide;
  }
  std::vector<double> dx_, dy_, ex_, ey_;  // [coefficient][j][i]
};

// The shift kernels of a parameter set: Dx(i, j) = sum_p a_p (Dx(p, i, j) + eta Ex(p, i, j)),
// likewise Dy; and their derivatives by parameter `parameter` (the kernel of a unit a_p at
// the set's eta, or sum_p a_p Ex(p, i, j) for eta).
struct BoundaryShiftKernel {
  std::vector<double> dx, dy;  // [j + reach][i + reach], kSide x kSide
  double Dx(int i, int j) const { return Get(dx, i, j); }
  double Dy(int i, int j) const { return Get(dy, i, j); }

 private:
  static double Get(const std::vector<double>& t, int i, int j) {
    constexpr int r = kBoundaryShiftReach, s = BoundaryShiftBasis::kSide;
    if (i < -r || i > r || j < -r || j > r) return 0.0;
    return t[static_cast<size_t>(j + r) * s + (i + r)];
  }
};
BoundaryShiftKernel MakeBoundaryShiftKernel(const BoundaryShiftParams& p);
BoundaryShiftKernel MakeBoundaryShiftDerivativeKernel(const BoundaryShiftParams& p, int parameter);

// The pixels whose charge moves boundaries, and whose boundaries move, in a render: a square
// of side 2 kBoundaryShiftWindowHalf + 1 around the spot, clipped to the image (pixel indices,
// inclusive). The spot's light outside it, and the line density along boundaries outside it,
// are so small that the charge they would move is below 1e-4 of the largest pixel change
// (checked in a test against the whole stamp); computing only there keeps the effect's cost
// below a render's. A fit fixes the window per exposure, so that the model stays smooth.
struct PixelWindow {
  int i0 = 0, i1 = 0, j0 = 0, j1 = 0;
};
constexpr int kBoundaryShiftWindowHalf = 4;
PixelWindow BoundaryShiftWindow(int centre_i, int centre_j, int nx, int ny);

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_BOUNDARY_SHIFT_H_
