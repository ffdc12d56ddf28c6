// Self-tests of the Fourier-space reference model (tests/support/reference_model.h) against
// results known independently of it: closed forms, Lord Rayleigh's encircled energy, and
// real-space brute-force quadrature. The renderer is not involved here.
#include "support/reference_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "gtest/gtest.h"

namespace ccdpsf::testing_reference {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Composite Gauss-Legendre rule on [lo, hi] with `panels` panels of `order` nodes.
void CompositeRule(double lo, double hi, int panels, int order, std::vector<double>* x,
                   std::vector<double>* w) {
  std::vector<double> gx, gw;
  GaussLegendre(order, &gx, &gw);
  x->clear();
  w->clear();
  const double h = (hi - lo) / panels;
  for (int p = 0; p < panels; ++p) {
    const double mid = lo + (p + 0.5) * h;
    for (int k = 0; k < order; ++k) {
      x->push_back(mid + 0.5 * h * gx[k]);
      w->push_back(0.5 * h * gw[k]);
    }
  }
}

TEST(GaussLegendre, IntegratesPolynomialsOfDegree2nMinus1Exactly) {
  for (int n : {1, 2, 3, 5, 8, 16, 32, 64}) {
    std::vector<double> x, w;
    GaussLegendre(n, &x, &w);
    ASSERT_EQ(x.size(), static_cast<size_t>(n));
    for (int i = 1; i < n; ++i) EXPECT_LT(x[i - 1], x[i]) << "n = " << n;
    for (int degree = 0; degree <= 2 * n - 1; ++degree) {
      double sum = 0.0;
      for (int i = 0; i < n; ++i) sum += w[i] * std::pow(x[i], degree);
      const double exact = degree % 2 == 1 ? 0.0 : 2.0 / (degree + 1);
      EXPECT_NEAR(sum, exact, 1e-14) << "n = " << n << ", degree = " << degree;
    }
  }
  // And the textbook two-point rule.
  std::vector<double> x, w;
  GaussLegendre(2, &x, &w);
  EXPECT_NEAR(x[1], 1.0 / std::sqrt(3.0), 4e-16);
  EXPECT_NEAR(w[0], 1.0, 4e-16);
}

TEST(GaussianIntervalProbability, MatchesKnownValuesIncludingFarTails) {
  // P(|Z| < 1) = erf(1 / sqrt 2) and the one-sided tail Q(8), both to 17 digits from tables.
  EXPECT_NEAR(GaussianIntervalProbability(-1.0, 1.0, 1.0), 0.68268949213708590, 4e-16);
  EXPECT_NEAR(GaussianIntervalProbability(8.0, 1e300, 1.0) / 6.2209605742717841e-16, 1.0,
              1e-13);
  EXPECT_NEAR(GaussianIntervalProbability(-1e300, -8.0, 1.0) / 6.2209605742717841e-16, 1.0,
              1e-13);
  // Scaling: an interval in units of sigma.
  EXPECT_NEAR(GaussianIntervalProbability(-0.3, 0.3, 0.3), 0.68268949213708590, 4e-16);
}

// The Airy helpers are consistent: the radial integral of the unit-flux intensity from 0 to
// D is 1 - J0(kD)^2 - J1(kD)^2. This checks the normalisation 4 pi A / k^2 = flux used by the
// model and the encircled-energy formula used by the grid-sum test below.
TEST(AiryHelpers, EncircledEnergyIsTheRadialIntegralOfTheIntensity) {
  for (double r : {0.3, 0.47, 0.9}) {
    for (double d_max : {0.2, 1.0, 7.3}) {
      std::vector<double> x, w;
      CompositeRule(0.0, d_max, 400, 16, &x, &w);
      double inside = 0.0;
      for (size_t i = 0; i < x.size(); ++i) {
        inside += w[i] * 2.0 * kPi * x[i] * AiryIntensity(x[i], r);
      }
      EXPECT_NEAR(inside, 1.0 - AiryEnergyOutside(d_max, r), 1e-13)
          << "r = " << r << ", D = " << d_max;
    }
  }
}

// (a) The point-source limit: with OTF = 1 the integrand's transform is that of a Gaussian of
// variance sigma_f^2 + sigma_ccd^2 per axis, so the pixel values must equal the closed form
// [Phi((dx + 1/2) / s) - Phi((dx - 1/2) / s)] [same in y]. Both sides are accurate to ~1e-15;
// 1e-12 of the flux is the reference's own convergence target.
TEST(ReferenceModel, PointSourceMatchesClosedFormPixelIntegratedGaussian) {
  struct Case {
    double sigma_f, sigma_x, sigma_y, cx, cy;
  };
  const Case cases[] = {{0.41, 0.291, 0.335, 0.07, -0.04},
                        {0.0, 0.1, 0.1, 0.5, 0.0},  // smallest widths, centre on a pixel edge
                        {0.8, 0.8, 0.1, -0.31, 0.22},
                        {0.1, 0.6, 0.25, 0.0, 0.0}};
  const double pixels[][2] = {{0, 0}, {1, 0}, {0, -1}, {1, 1}, {-2, 1}, {3, -2}, {-4, -4}};
  for (const Case& c : cases) {
    ReferenceSpot spot;
    spot.pupil = Pupil::kPointSource;
    spot.flux_e = 1.0;
    spot.centre_x_px = c.cx;
    spot.centre_y_px = c.cy;
    spot.defocus_kind = model::DefocusKind::kGaussian;
    spot.defocus_px = c.sigma_f;
    spot.ccd_sigma_x_px = c.sigma_x;
    spot.ccd_sigma_y_px = c.sigma_y;
    const double sx = std::hypot(c.sigma_f, c.sigma_x);
    const double sy = std::hypot(c.sigma_f, c.sigma_y);
    for (const auto& pixel : pixels) {
      const ReferenceResult ref = ReferencePixel(spot, pixel[0], pixel[1]);
      ASSERT_TRUE(ref.converged);
      const double exact =
          PixelIntegratedGaussian(1.0, pixel[0] - c.cx, pixel[1] - c.cy, sx, sy);
      EXPECT_NEAR(ref.values[0], exact, 1e-12)
          << "sigma_f " << c.sigma_f << " sigma " << c.sigma_x << "," << c.sigma_y
          << " pixel " << pixel[0] << "," << pixel[1];
    }
  }
}

// The pillbox transform 2 J1(2 pi R rho) / (2 pi R rho): a point source spread uniformly over
// a disc of radius R, then by the CCD Gaussian, gives in a pixel the disc average of the
// pixel-integrated Gaussian, computed here in real space (polar Gauss-Legendre over the disc,
// whose integrand is analytic). Agreement to 1e-12 of the flux.
TEST(ReferenceModel, PointSourcePillboxMatchesRealSpaceDiscAverage) {
  struct Case {
    double radius, sigma_x, sigma_y, cx, cy;
  };
  const Case cases[] = {{0.2, 0.1, 0.15, 0.13, -0.21}, {1.5, 0.3, 0.8, -0.4, 0.1}};
  const double pixels[][2] = {{0, 0}, {1, 0}, {-1, 1}, {2, -2}, {0, 3}};
  for (const Case& c : cases) {
    ReferenceSpot spot;
    spot.pupil = Pupil::kPointSource;
    spot.centre_x_px = c.cx;
    spot.centre_y_px = c.cy;
    spot.defocus_kind = model::DefocusKind::kPillbox;
    spot.defocus_px = c.radius;
    spot.ccd_sigma_x_px = c.sigma_x;
    spot.ccd_sigma_y_px = c.sigma_y;
    std::vector<double> qr, wr, qt, wt;
    CompositeRule(0.0, c.radius, 16, 16, &qr, &wr);
    CompositeRule(0.0, 2.0 * kPi, 32, 16, &qt, &wt);
    for (const auto& pixel : pixels) {
      double brute = 0.0;
      for (size_t i = 0; i < qr.size(); ++i) {
        for (size_t j = 0; j < qt.size(); ++j) {
          // The disc point q shifts the source to centre + q.
          const double qx = qr[i] * std::cos(qt[j]);
          const double qy = qr[i] * std::sin(qt[j]);
          brute += wr[i] * qr[i] * wt[j] *
                   PixelIntegratedGaussian(1.0, pixel[0] - c.cx - qx, pixel[1] - c.cy - qy,
                                           c.sigma_x, c.sigma_y);
        }
      }
      brute /= kPi * c.radius * c.radius;
      const ReferenceResult ref = ReferencePixel(spot, pixel[0], pixel[1]);
      ASSERT_TRUE(ref.converged);
      EXPECT_NEAR(ref.values[0], brute, 1e-12)
          << "R " << c.radius << " pixel " << pixel[0] << "," << pixel[1];
    }
  }
}

// Fraction of a unit-flux Airy pattern centred at (cx, cy) that falls inside the rectangle
// [xl, xh] x [yl, yh] (which contains the centre): (1 / 2 pi) Integral EE(R(theta)) d theta,
// with R(theta) the distance to the boundary along theta and EE(d) = 1 - J0^2 - J1^2. The
// integrand is smooth between the directions of the four corners, where it is split.
double AiryEnergyInRectangle(double r, double cx, double cy, double xl, double xh, double yl,
                             double yh, int panels) {
  std::vector<double> breaks;
  for (double x : {xl, xh}) {
    for (double y : {yl, yh}) {
      double angle = std::atan2(y - cy, x - cx);
      if (angle < 0.0) angle += 2.0 * kPi;
      breaks.push_back(angle);
    }
  }
  std::sort(breaks.begin(), breaks.end());
  breaks.insert(breaks.begin(), 0.0);
  breaks.push_back(2.0 * kPi);
  double sum = 0.0;
  for (size_t b = 0; b + 1 < breaks.size(); ++b) {
    if (breaks[b + 1] <= breaks[b]) continue;
    std::vector<double> x, w;
    CompositeRule(breaks[b], breaks[b + 1], panels, 16, &x, &w);
    for (size_t i = 0; i < x.size(); ++i) {
      const double c = std::cos(x[i]);
      const double s = std::sin(x[i]);
      double dist = std::numeric_limits<double>::infinity();
      if (c > 0) dist = std::min(dist, (xh - cx) / c);
      if (c < 0) dist = std::min(dist, (xl - cx) / c);
      if (s > 0) dist = std::min(dist, (yh - cy) / s);
      if (s < 0) dist = std::min(dist, (yl - cy) / s);
      sum += w[i] * (1.0 - AiryEnergyOutside(dist, r));
    }
  }
  return sum / (2.0 * kPi);
}

// (b) Normalisation. Without any blur, the pixel values summed over a grid must equal the
// Airy energy inside the grid's outer boundary, which Rayleigh's formula gives in closed form
// per direction. The Airy tail outside a 21 x 21 grid is J0^2 + J1^2 ~ 2 / (pi k L) ~ 0.7 % of
// the flux (k = pi Rz / r, L ~ 10 px), so comparing the sum with the flux itself would need a
// tolerance of 1e-2; comparing with the encircled energy allows 1e-9: 441 pixels, each
// converged to 1e-12 of the flux, plus 1e-14 for the angular integral.
TEST(ReferenceModel, UnblurredGridSumEqualsAiryEnergyInsideGrid) {
  ReferenceSpot spot;
  spot.flux_e = 1.0;
  spot.centre_x_px = 10.3;
  spot.centre_y_px = 9.8;
  spot.airy_radius_px = 0.5;
  const int n = 21;
  const ReferenceResult ref = ReferenceImage(spot, n, n, 0.0, 0.0);
  ASSERT_TRUE(ref.converged);
  double sum = 0.0;
  for (double v : ref.values) sum += v;
  const double inside = AiryEnergyInRectangle(spot.airy_radius_px, spot.centre_x_px,
                                              spot.centre_y_px, -0.5, n - 0.5, -0.5, n - 0.5,
                                              64);
  // The angular integral is itself converged (doubling its panels changes nothing).
  ASSERT_NEAR(inside,
              AiryEnergyInRectangle(spot.airy_radius_px, spot.centre_x_px, spot.centre_y_px,
                                    -0.5, n - 0.5, -0.5, n - 0.5, 128),
              1e-14);
  EXPECT_GT(1.0 - inside, 3e-3);  // the tail is real: the flux alone would be the wrong target
  EXPECT_NEAR(sum, inside, 1e-9);
}

// (b, blurred) With blur the exact inside energy has no closed form, but it is bracketed:
// blurring moves energy by more than w = 10 sigma_total with probability < exp(-50), so the
// energy outside the grid lies between the Airy energy outside a circle of radius
// (distance to the farthest corner + w) and outside one of radius (distance to the nearest
// edge - w). The bracket is wide (a factor ~1.6) but excludes both 0 and any factor-of-two
// normalisation error in the OTF or the defocus transform.
TEST(ReferenceModel, BlurredGridSumLeavesTheAiryTailOutside) {
  ReferenceSpot spot;
  spot.flux_e = 1.0;
  spot.centre_x_px = 10.3;
  spot.centre_y_px = 9.8;
  spot.airy_radius_px = 0.5;
  spot.defocus_kind = model::DefocusKind::kGaussian;
  spot.defocus_px = 0.3;
  spot.ccd_sigma_x_px = 0.25;
  spot.ccd_sigma_y_px = 0.35;
  const int n = 21;
  const ReferenceResult ref = ReferenceImage(spot, n, n, 0.0, 0.0);
  ASSERT_TRUE(ref.converged);
  double sum = 0.0;
  for (double v : ref.values) sum += v;
  const double w = 10.0 * std::hypot(spot.defocus_px, spot.ccd_sigma_y_px);
  const double nearest_edge = std::min({spot.centre_x_px + 0.5, n - 0.5 - spot.centre_x_px,
                                        spot.centre_y_px + 0.5, n - 0.5 - spot.centre_y_px});
  const double farthest_corner =
      std::hypot(std::max(spot.centre_x_px + 0.5, n - 0.5 - spot.centre_x_px),
                 std::max(spot.centre_y_px + 0.5, n - 0.5 - spot.centre_y_px));
  const double outside = 1.0 - sum;
  EXPECT_GT(outside, AiryEnergyOutside(farthest_corner + w, spot.airy_radius_px) - 1e-12);
  EXPECT_LT(outside, AiryEnergyOutside(nearest_edge - w, spot.airy_radius_px) + 1e-12);
}

// (c) Real-space brute force for a Gaussian defocus. Writing the pixel-integrated Gaussian
// kernel (total sigma^2 = sigma_f^2 + sigma_ccd^2 per axis) as B(p) = Bx(px) By(py), the pixel
// value is flux * Integral I_airy(p) Bx(px) By(py) d^2p, p the position relative to the spot
// centre. B is below 1e-20 outside a box reaching 9.5 sigma beyond the pixel, so a tensor
// Gauss-Legendre rule over that box (panels no wider than half an Airy ring or a sigma,
// doubled until the change is below 1e-14 of the flux) is an independent real-space value.
double RealSpacePixel(const ReferenceSpot& spot, double pixel_x, double pixel_y) {
  const double sx = std::hypot(spot.defocus_px, spot.ccd_sigma_x_px);
  const double sy = std::hypot(spot.defocus_px, spot.ccd_sigma_y_px);
  const double dx = pixel_x - spot.centre_x_px;
  const double dy = pixel_y - spot.centre_y_px;
  const double k = kPi * model::kAiryRz / spot.airy_radius_px;
  const double h0 = std::min({kPi / k, sx, sy});
  const double half_x = 0.5 + 9.5 * sx;
  const double half_y = 0.5 + 9.5 * sy;
  double previous = 0.0;
  for (int level = 0; level < 4; ++level) {
    const int px = static_cast<int>(std::ceil(2.0 * half_x / h0)) << level;
    const int py = static_cast<int>(std::ceil(2.0 * half_y / h0)) << level;
    std::vector<double> x, wx, y, wy;
    CompositeRule(dx - half_x, dx + half_x, px, 16, &x, &wx);
    CompositeRule(dy - half_y, dy + half_y, py, 16, &y, &wy);
    std::vector<double> bx(x.size()), by(y.size());
    for (size_t i = 0; i < x.size(); ++i) {
      bx[i] = wx[i] * GaussianIntervalProbability(dx - x[i] - 0.5, dx - x[i] + 0.5, sx);
    }
    for (size_t j = 0; j < y.size(); ++j) {
      by[j] = wy[j] * GaussianIntervalProbability(dy - y[j] - 0.5, dy - y[j] + 0.5, sy);
    }
    double sum = 0.0;
    for (size_t j = 0; j < y.size(); ++j) {
      double row = 0.0;
      for (size_t i = 0; i < x.size(); ++i) {
        row += bx[i] * AiryIntensity(std::hypot(x[i], y[j]), spot.airy_radius_px);
      }
      sum += by[j] * row;
    }
    sum *= spot.flux_e;
    if (level > 0 && std::abs(sum - previous) < 1e-14 * spot.flux_e) return sum;
    previous = sum;
  }
  ADD_FAILURE() << "real-space brute force did not converge";
  return previous;
}

// The brute force and the Fourier reference share only the Airy definition; agreement to
// 1e-12 of the flux (the reference's convergence target; measured ~1e-14) confirms the OTF,
// its edge treatment, the sinc pixel response and the Gaussian transforms together. One case
// at the paper's values (near and far pixels), one with the smallest widths where the Airy
// tail dominates far from the centre.
TEST(ReferenceModel, MatchesRealSpaceBruteForceForGaussianDefocus) {
  struct Case {
    double r, sigma_f, sigma_x, sigma_y, cx, cy;
    double pixels[3][2];
  };
  const Case cases[] = {
      {0.47, 0.41, 0.291, 0.335, 10.07, 9.96, {{10, 10}, {12, 9}, {16, 14}}},
      {0.3, 0.1, 0.12, 0.1, 5.38, 4.77, {{5, 5}, {4, 5}, {10, 0}}},
  };
  for (const Case& c : cases) {
    ReferenceSpot spot;
    spot.flux_e = 1.0;
    spot.centre_x_px = c.cx;
    spot.centre_y_px = c.cy;
    spot.airy_radius_px = c.r;
    spot.defocus_kind = model::DefocusKind::kGaussian;
    spot.defocus_px = c.sigma_f;
    spot.ccd_sigma_x_px = c.sigma_x;
    spot.ccd_sigma_y_px = c.sigma_y;
    for (const auto& pixel : c.pixels) {
      const ReferenceResult ref = ReferencePixel(spot, pixel[0], pixel[1]);
      ASSERT_TRUE(ref.converged);
      const double brute = RealSpacePixel(spot, pixel[0], pixel[1]);
      EXPECT_NEAR(ref.values[0], brute, 1e-12)
          << "r " << c.r << " pixel " << pixel[0] << "," << pixel[1];
    }
  }
}

// The two accumulation paths (single pixel: direct cosines; grid: cosine recurrences over a
// row) agree, and the flux only scales the result.
TEST(ReferenceModel, ImageAndPixelPathsAgree) {
  ReferenceSpot spot;
  spot.flux_e = 2.5e5;
  spot.centre_x_px = 3.2;
  spot.centre_y_px = 4.45;
  spot.airy_radius_px = 0.62;
  spot.defocus_kind = model::DefocusKind::kPillbox;
  spot.defocus_px = 0.7;
  spot.ccd_sigma_x_px = 0.3;
  spot.ccd_sigma_y_px = 0.2;
  const int nx = 9, ny = 8;
  const ReferenceResult image = ReferenceImage(spot, nx, ny, 0.0, 0.0);
  ASSERT_TRUE(image.converged);
  for (const auto& pixel : {std::pair<int, int>{3, 4}, {0, 0}, {8, 7}, {5, 2}}) {
    const ReferenceResult one = ReferencePixel(spot, pixel.first, pixel.second);
    ASSERT_TRUE(one.converged);
    EXPECT_NEAR(one.values[0], image.values[pixel.second * nx + pixel.first],
                1e-12 * spot.flux_e);
  }
}

}  // namespace
}  // namespace ccdpsf::testing_reference
