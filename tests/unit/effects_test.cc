// The catalogue of physical effects and their forward application (model/effects.h), each
// against values computed independently: closed forms, brute-force integrals, or the
// renderer called another way. Simulator injection is tested in simulate_test.cc.
#include "ccdpsf/model/effects.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "ccdpsf/model/renderer.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::model {
namespace {

using nlohmann::json;

SpotParams PaperSpot(double x = 7.07, double y = 6.96) {
  SpotParams p;
  p[kFlux] = 3.0e5;
  p[kCentreX] = x;
  p[kCentreY] = y;
  p[kAiryRadius] = 0.47;
  p[kDefocus] = 0.41;
  p[kCcdSigmaX] = 0.291;
  p[kCcdSigmaY] = 0.335;
  return p;
}

PixelGrid Grid(int nx, int ny, double x0 = 0.0, double y0 = 0.0) {
  PixelGrid g;
  g.nx = nx;
  g.ny = ny;
  g.x0 = x0;
  g.y0 = y0;
  return g;
}

std::vector<double> Render(const SpotRenderer& renderer, const SpotParams& p,
                           const PixelGrid& grid) {
  std::vector<double> m(grid.size());
  renderer.Render(p, grid, m.data(), nullptr);
  return m;
}

double Sum(const std::vector<double>& v) { return std::accumulate(v.begin(), v.end(), 0.0); }

double MaxAbsDiff(const std::vector<double>& a, const std::vector<double>& b) {
  double d = 0.0;
  for (size_t q = 0; q < a.size(); ++q) d = std::max(d, std::fabs(a[q] - b[q]));
  return d;
}

// ------------------------------------------------------------------------------------------
// The catalogue.

TEST(Effects, NamesAreTheCatalogueNamesAndRoundTrip) {
  const std::vector<std::string> names = {"defocus", "brighter_fatter", "serial_cti",
                                          "parallel_cti", "ipc", "jitter", "background",
                                          "nonlinearity", "halo", "defocus_offset",
                                          "boundary_shift"};
  ASSERT_EQ(AllEffectKinds().size(), names.size());
  ASSERT_EQ(EffectCatalogue().size(), names.size());
  for (size_t i = 0; i < names.size(); ++i) {
    EXPECT_EQ(ToString(AllEffectKinds()[i]), names[i]);
    EXPECT_EQ(EffectCatalogue()[i].name, names[i]);
    EffectKind kind = EffectKind::kDefocus;
    ASSERT_TRUE(ParseEffectKind(names[i], &kind));
    EXPECT_EQ(kind, AllEffectKinds()[i]);
  }
  EffectKind untouched = EffectKind::kHalo;
  EXPECT_FALSE(ParseEffectKind("Halo", &untouched));
  EXPECT_FALSE(ParseEffectKind("cti", &untouched));
  EXPECT_EQ(untouched, EffectKind::kHalo);
  EXPECT_FALSE(DescribeEffect(EffectKind::kDefocus).injectable);
}

// The struct defaults are the catalogue's; every default lies inside its prior and domain,
// and each prior lies inside the domain.
TEST(Effects, CatalogueDefaultsPriorsAndDomainsAgree) {
  for (const EffectInfo& info : EffectCatalogue()) {
    ASSERT_FALSE(info.parameters.empty()) << info.name;
    for (size_t p = 0; p < info.parameters.size(); ++p) {
      const EffectParameterInfo& pi = info.parameters[p];
      SCOPED_TRACE(info.name + "." + pi.name);
      EXPECT_LT(pi.prior_lower, pi.prior_upper);
      EXPECT_GE(pi.default_value, pi.prior_lower);
      EXPECT_LE(pi.default_value, pi.prior_upper);
      std::string error;
      EXPECT_TRUE(CheckEffectParameter(info.kind, static_cast<int>(p), pi.default_value, "x",
                                       &error)) << error;
      EXPECT_TRUE(CheckEffectParameter(info.kind, static_cast<int>(p), pi.prior_lower, "x",
                                       &error)) << error;
      EXPECT_TRUE(CheckEffectParameter(info.kind, static_cast<int>(p), pi.prior_upper, "x",
                                       &error)) << error;
      // A search starts inside the prior, where a fit can begin.
      EXPECT_GE(pi.start, pi.prior_lower);
      EXPECT_LE(pi.start, pi.prior_upper);
      for (const std::vector<double>& start : info.search_starts) {
        ASSERT_EQ(start.size(), info.parameters.size());
        EXPECT_GE(start[p], pi.prior_lower);
        EXPECT_LE(start[p], pi.prior_upper);
      }
      // A "no effect" value on the boundary is the prior's lower edge, 0.
      if (pi.null_on_boundary) {
        EXPECT_EQ(pi.prior_lower, 0.0);
      }
    }
    EXPECT_FALSE(info.search_starts.empty()) << info.name;
    // The catalogue is indexed by kind; exactly the kinds a fit cannot hold say why (jitter
    // is fitted per exposure, defocus_offset in pixel_centre sampling: FitModel::Create).
    EXPECT_EQ(&DescribeEffect(info.kind), &info);
    const bool fittable = info.kind != EffectKind::kDefocus;
    EXPECT_EQ(info.not_fittable.empty(), fittable) << info.name;
    if (info.kind == EffectKind::kDefocus) {
      EXPECT_EQ(info.parameters[0].default_value, DefocusEffectParams().sigma_px);
      continue;
    }
    ExposureEffects from_catalogue;
    AddDefaultEffect(info.kind, &from_catalogue);
    std::vector<double> want;
    switch (info.kind) {
      case EffectKind::kBrighterFatter:
        want = {BrighterFatterParams().slope_x_px_per_e, BrighterFatterParams().slope_y_px_per_e};
        break;
      case EffectKind::kSerialCti:
      case EffectKind::kParallelCti:
        want = {CtiParams().trail_fraction, CtiParams().trail_length_px};
        break;
      case EffectKind::kIpc: want = {IpcParams().alpha}; break;
      case EffectKind::kJitter:
        want = {JitterParams().sigma_x_px, JitterParams().sigma_y_px,
                JitterParams().motion_length_px, JitterParams().motion_angle_deg};
        break;
      case EffectKind::kBackground: want = {BackgroundParams().pedestal_e}; break;
      case EffectKind::kNonlinearity: want = {NonlinearityParams().beta_per_e}; break;
      case EffectKind::kHalo: want = {HaloParams().fraction, HaloParams().sigma_px}; break;
      case EffectKind::kDefocusOffset:
        want = {DefocusOffsetParams().dx_px, DefocusOffsetParams().dy_px};
        break;
      case EffectKind::kBoundaryShift: {
        const BoundaryShiftParams b;
        want = {b.a_10, b.a_01, b.a_11, b.a_far, b.anisotropy};
        break;
      }
      case EffectKind::kDefocus: break;
    }
    EXPECT_EQ(GetEffectParameters(from_catalogue, info.kind), want) << info.name;
    EXPECT_EQ(from_catalogue.Kinds(), std::vector<EffectKind>{info.kind});
  }
  // The paper's brighter-fatter slope, 1.14e-5 um/e- of FWHM with 12 um pixels, is
  // 4.034e-7 px/e- of sigma; the default rounds it to 4.0e-7 (the paper's uncertainty is 7 %).
  const double paper = 1.14e-5 / 12.0 / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  EXPECT_NEAR(BrighterFatterParams().slope_x_px_per_e, paper, 0.01 * paper);
  EXPECT_NEAR(BrighterFatterParams().slope_y_px_per_e, paper, 0.01 * paper);
  // Nonlinearity: a few tenths of a percent to 1 % at the paper's brightest peaks (160 ke-).
  const double loss = NonlinearityParams().beta_per_e * 1.6e5;
  EXPECT_GE(loss, 0.002);
  EXPECT_LE(loss, 0.01);
  // CTI: f = n c for ~1000 transfers at c between 1e-7 and 1e-5 per transfer (unirradiated
  // to end-of-life irradiated).
  EXPECT_GE(CtiParams().trail_fraction, 1e-4);
  EXPECT_LE(CtiParams().trail_fraction, 1e-2);
}

TEST(Effects, CatalogueListingNamesEveryEffectAndParameter) {
  const std::string text = FormatEffectCatalogue();
  const json j = EffectCatalogueJson();
  ASSERT_EQ(j.size(), EffectCatalogue().size());
  for (size_t i = 0; i < EffectCatalogue().size(); ++i) {
    const EffectInfo& info = EffectCatalogue()[i];
    EXPECT_NE(text.find(info.name + " ("), std::string::npos) << info.name;
    EXPECT_EQ(j[i]["name"], info.name);
    for (size_t p = 0; p < info.parameters.size(); ++p) {
      EXPECT_NE(text.find(info.parameters[p].name), std::string::npos);
      EXPECT_EQ(j[i]["parameters"][p]["name"], info.parameters[p].name);
      EXPECT_EQ(j[i]["parameters"][p]["default"].get<double>(), info.parameters[p].default_value);
    }
  }
  EXPECT_NE(text.find("trail_length_px [px]"), std::string::npos);
  EXPECT_NE(text.find("domain [0, 0.25)"), std::string::npos);  // ipc alpha
}

TEST(Effects, ParameterVectorsRoundTripAndRejectValuesOutsideTheDomain) {
  ExposureEffects e;
  std::string error;
  ASSERT_TRUE(SetEffectParameters(EffectKind::kHalo, {0.05, 3.0}, &e, &error)) << error;
  EXPECT_EQ(GetEffectParameters(e, EffectKind::kHalo), (std::vector<double>{0.05, 3.0}));
  EXPECT_FALSE(SetEffectParameters(EffectKind::kHalo, {1.5, 3.0}, &e, &error));
  EXPECT_EQ(error, "'halo.fraction' must be in [0, 1] (got 1.5)");
  EXPECT_FALSE(SetEffectParameters(EffectKind::kIpc, {0.25}, &e, &error));
  EXPECT_NE(error.find("[0, 0.25)"), std::string::npos);
  EXPECT_FALSE(SetEffectParameters(EffectKind::kSerialCti, {1e-3}, &e, &error));
  EXPECT_NE(error.find("2 parameters"), std::string::npos);
  EXPECT_FALSE(SetEffectParameters(EffectKind::kSerialCti, {1e-3, 0.0}, &e, &error));
  EXPECT_NE(error.find("'serial_cti.trail_length_px' must be in (0, inf)"), std::string::npos);
  EXPECT_FALSE(e.ipc.has_value());
  EXPECT_FALSE(e.serial_cti.has_value());
  EXPECT_EQ(e.halo->fraction, 0.05);  // untouched by the failures
}

// ------------------------------------------------------------------------------------------
// Image effects.

// One bright pixel: the trail is (1 - f) Q at the pixel and f Q exp(-d / L) / S at distance
// d, S = sum_{d >= 1} exp(-d / L) computed here by brute force (2000 terms: the remainder is
// below exp(-2000 / 1.5)). Tolerance 1e-13 relative: the recursion multiplies by r once per
// pixel, a few ulp of rounding per step over at most 40 steps.
TEST(Effects, CtiTrailOfOneBrightPixelIsTheNormalisedExponential) {
  const double q = 1.0e5, f = 5.0e-4, length = 1.5;
  double s = 0.0;
  for (int d = 1; d <= 2000; ++d) s += std::exp(-d / length);
  for (const bool serial : {true, false}) {
    const int nx = serial ? 48 : 5, ny = serial ? 5 : 48;
    std::vector<double> image(nx * ny, 0.0);
    const int i0 = serial ? 6 : 2, j0 = serial ? 2 : 6;
    image[j0 * nx + i0] = q;
    if (serial) ApplySerialCti({f, length}, nx, ny, image.data());
    else ApplyParallelCti({f, length}, nx, ny, image.data());
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const int along = serial ? i - i0 : j - j0;
        const bool on_line = serial ? j == j0 : i == i0;
        double want = 0.0;
        if (on_line && along == 0) want = (1.0 - f) * q;
        if (on_line && along > 0) want = f * q * std::exp(-along / length) / s;
        EXPECT_NEAR(image[j * nx + i], want, 1e-13 * want + 1e-300)
            << (serial ? "serial " : "parallel ") << i << "," << j;
      }
    }
  }
  // A pixel on the last column keeps (1 - f): its trail leaves the frame and is lost.
  std::vector<double> edge(8, 0.0);
  edge[7] = q;
  ApplySerialCti({f, length}, 8, 1, edge.data());
  EXPECT_DOUBLE_EQ(Sum(edge), (1.0 - f) * q);
}

// Charge is conserved when nothing reaches the edge: charge only in the first 8 columns/rows
// of a 70-pixel line, so the trail beyond the edge is below exp(-62 / 1.5) ~ 1e-18 of it.
// Tolerance 1e-12 relative (summation of ~3000 positive terms).
TEST(Effects, CtiConservesChargeAndActsAlongItsAxisOnly) {
  const int n = 70, m = 9;
  std::vector<double> serial(n * m, 0.0), parallel(n * m, 0.0);
  for (int a = 0; a < m; ++a) {
    for (int b = 0; b < 8; ++b) {
      const double v = 1000.0 + 37.0 * a + 11.0 * b * b;
      serial[a * n + b] = v;      // row a, column b
      parallel[b * m + a] = v;    // row b, column a
    }
  }
  const double total = Sum(serial);
  ApplySerialCti({2e-3, 2.5}, n, m, serial.data());
  ApplyParallelCti({2e-3, 2.5}, m, n, parallel.data());
  EXPECT_NEAR(Sum(serial), total, 1e-12 * total);
  EXPECT_NEAR(Sum(parallel), total, 1e-12 * total);
  for (int a = 0; a < m; ++a) {
    double row = 0.0, column = 0.0, want = 0.0;
    for (int b = 0; b < 8; ++b) want += 1000.0 + 37.0 * a + 11.0 * b * b;
    for (int b = 0; b < n; ++b) {
      row += serial[a * n + b];
      column += parallel[b * m + a];
    }
    EXPECT_NEAR(row, want, 1e-12 * want);  // serial CTI moves charge within its row
    EXPECT_NEAR(column, want, 1e-12 * want);
  }
}

TEST(Effects, IpcOfOneBrightPixelIsTheKernelAndConservesCharge) {
  const int nx = 7, ny = 6;
  const double a = 0.015, q = 5.0e4;
  std::vector<double> image(nx * ny, 0.0);
  image[3 * nx + 2] = q;
  ApplyIpc({a}, nx, ny, image.data());
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const int d = std::abs(i - 2) + std::abs(j - 3);
      const double want = d == 0 ? (1.0 - 4.0 * a) * q : d == 1 ? a * q : 0.0;
      EXPECT_NEAR(image[j * nx + i], want, 1e-15 * q) << i << "," << j;
    }
  }
  // An image with a zero border conserves charge (to rounding, 1e-12 relative).
  std::vector<double> inner(nx * ny, 0.0);
  for (int j = 1; j < ny - 1; ++j) {
    for (int i = 1; i < nx - 1; ++i) inner[j * nx + i] = 100.0 + i * 7.0 + j * j;
  }
  const double total = Sum(inner);
  ApplyIpc({a}, nx, ny, inner.data());
  EXPECT_NEAR(Sum(inner), total, 1e-12 * total);
  // Zero padding: a corner pixel gives alpha to each of its two outside neighbours.
  std::vector<double> corner(nx * ny, 0.0);
  corner[0] = q;
  ApplyIpc({a}, nx, ny, corner.data());
  EXPECT_NEAR(Sum(corner), (1.0 - 2.0 * a) * q, 1e-12 * q);
}

// The closed-form pixel integral of the halo Gaussian against a brute-force 2-D midpoint rule
// with 128 x 128 points per pixel. The midpoint error relative to the pixel's value is at most
// (h^2 / 24) max|d2/dx2 + d2/dy2| / mean ~ (1/128)^2 / 24 (2 * 11^2 / 2.5^4 + 2 / 2.5^2)
// e^{0.9} ~ 4e-5 on this grid (|offset| <= 11 px; e^{0.9} the variation of the Gaussian
// across one pixel there), so the tolerance is 1e-4 relative.
TEST(Effects, HaloIsTheExactPixelIntegralOfAGaussian) {
  const PixelGrid grid = Grid(21, 19, 3.0, -2.0);
  const SpotReference spot{2.0e5, 13.3, 7.8};
  const HaloParams halo{0.04, 2.5};
  std::vector<double> spot_image(grid.size());
  for (int q = 0; q < grid.size(); ++q) spot_image[q] = 10.0 + (q % 13);
  std::vector<double> image = spot_image;
  AddHalo(halo, grid, spot, image.data());
  const int k = 128;
  const double h = 1.0 / k, s2 = halo.sigma_px * halo.sigma_px;
  const double norm = 1.0 / (2.0 * M_PI * s2);
  for (int j = 0; j < grid.ny; ++j) {
    for (int i = 0; i < grid.nx; ++i) {
      double integral = 0.0;
      for (int b = 0; b < k; ++b) {
        const double y = grid.y0 + j - 0.5 + (b + 0.5) * h - spot.y_px;
        for (int a = 0; a < k; ++a) {
          const double x = grid.x0 + i - 0.5 + (a + 0.5) * h - spot.x_px;
          integral += norm * std::exp(-(x * x + y * y) / (2.0 * s2));
        }
      }
      integral *= h * h;
      const int q = j * grid.nx + i;
      const double halo_part = image[q] - (1.0 - halo.fraction) * spot_image[q];
      EXPECT_NEAR(halo_part, halo.fraction * spot.flux_e * integral,
                  1e-4 * halo.fraction * spot.flux_e * integral)
          << i << "," << j;
    }
  }
  // Far tails are evaluated with erfc, without cancellation: [8, 9] sigma.
  const double tail = GaussianIntervalIntegral(8.0, 9.0, 1.0);
  const double want = 0.5 * (std::erfc(8.0 / M_SQRT2) - std::erfc(9.0 / M_SQRT2));
  EXPECT_NEAR(tail, want, 1e-14 * want);
  EXPECT_NEAR(GaussianIntervalIntegral(-9.0, -8.0, 1.0), want, 1e-14 * want);
  EXPECT_NEAR(GaussianIntervalIntegral(-40.0, 40.0, 1.0), 1.0, 1e-15);
}

TEST(Effects, NonlinearityIsTheQuadraticResponseAndSaturatesAtItsTurningPoint) {
  const NonlinearityParams nl{1.0e-7};
  std::vector<double> v = {0.0, 1.0, 1.6e5, 4.0e6, 5.0e6, 6.0e6, 1.0e9};
  ApplyNonlinearity(nl, static_cast<int>(v.size()), v.data());
  EXPECT_EQ(v[0], 0.0);
  EXPECT_DOUBLE_EQ(v[1], 1.0 - 1.0e-7);
  EXPECT_DOUBLE_EQ(v[2], 1.6e5 * (1.0 - 0.016));  // 1.6 % low at 160 ke-
  EXPECT_DOUBLE_EQ(v[3], 4.0e6 * (1.0 - 0.4));
  EXPECT_DOUBLE_EQ(v[4], 2.5e6);  // the turning point 1 / (2 beta): maximum 1 / (4 beta)
  EXPECT_DOUBLE_EQ(v[5], 2.5e6);  // held there beyond it
  EXPECT_DOUBLE_EQ(v[6], 2.5e6);
  std::vector<double> same = {123.0, 4.5e4};
  ApplyNonlinearity({0.0}, 2, same.data());
  EXPECT_EQ(same, (std::vector<double>{123.0, 4.5e4}));
}

TEST(Effects, ImageEffectsComposeInTheDocumentedOrder) {
  const PixelGrid grid = Grid(15, 13, 4.0, 0.0);
  SpotRenderer renderer{ModelOptions()};
  const std::vector<double> spot = Render(renderer, PaperSpot(11.2, 6.1), grid);
  ExposureEffects e;
  e.halo = HaloParams{0.05, 2.0};
  e.nonlinearity = NonlinearityParams{2e-7};
  e.ipc = IpcParams{0.02};
  e.serial_cti = CtiParams{1e-3, 1.2};
  e.parallel_cti = CtiParams{2e-3, 0.8};
  e.background = BackgroundParams{-7.5};
  const SpotReference ref{3.0e5, 11.2, 6.1};
  std::vector<double> want = spot;
  AddHalo(*e.halo, grid, ref, want.data());
  ApplyNonlinearity(*e.nonlinearity, grid.size(), want.data());
  ApplyIpc(*e.ipc, grid.nx, grid.ny, want.data());
  ApplySerialCti(*e.serial_cti, grid.nx, grid.ny, want.data());
  ApplyParallelCti(*e.parallel_cti, grid.nx, grid.ny, want.data());
  std::vector<double> charge = spot;
  ApplyChargeEffects(e, grid, ref, charge.data());
  EXPECT_EQ(charge, want);
  AddBackground(*e.background, grid.size(), want.data());
  std::vector<double> image = spot;
  ApplyImageEffects(e, grid, ref, image.data());
  EXPECT_EQ(image, want);
  for (int q = 0; q < grid.size(); ++q) EXPECT_EQ(image[q], charge[q] - 7.5);
}

// ------------------------------------------------------------------------------------------
// Kernel effects.

// brighter_fatter: widths grow by slope * I, I the peak pixel of the spot rendered without it.
TEST(Effects, BrighterFatterWidthsFollowThePeakSignal) {
  const ModelOptions options;
  ExposureEffects e;
  e.brighter_fatter = BrighterFatterParams{4.0e-7, 2.5e-7};
  const SpotParams p = PaperSpot();
  const SpotParams at_160k = AdjustSpotParams(options, e, p, 1.6e5);
  EXPECT_DOUBLE_EQ(at_160k[kCcdSigmaX], 0.291 + 0.064);
  EXPECT_DOUBLE_EQ(at_160k[kCcdSigmaY], 0.335 + 0.04);
  EXPECT_EQ(AdjustSpotParams(options, e, p, 0.0), p);

  const PixelGrid grid = Grid(15, 14);
  SpotRenderer renderer(options);
  const std::vector<double> bare = Render(renderer, p, grid);
  const double peak = *std::max_element(bare.begin(), bare.end());
  EXPECT_EQ(BrighterFatterSignal(renderer, e, p, grid), peak);
  std::vector<double> model(grid.size());
  KernelEffectDetails details;
  RenderSpotWithEffects(renderer, e, p, grid, model.data(), &details);
  EXPECT_EQ(details.peak_e, peak);
  EXPECT_DOUBLE_EQ(details.ccd_sigma_x_px, 0.291 + 4.0e-7 * peak);
  EXPECT_DOUBLE_EQ(details.ccd_sigma_y_px, 0.335 + 2.5e-7 * peak);
  SpotParams wide = p;
  wide[kCcdSigmaX] = 0.291 + 4.0e-7 * peak;
  wide[kCcdSigmaY] = 0.335 + 2.5e-7 * peak;
  EXPECT_EQ(model, Render(renderer, wide, grid));
  // The spot is broader: its peak pixel is lower.
  EXPECT_LT(*std::max_element(model.begin(), model.end()), peak);
}

// Gaussian jitter in integrated sampling is exact as a variance addition. Checked
// independently: the average of renders at Gaussian-distributed shifts, E[M(x + d)] with
// d ~ N(0, j^2) along x, by 48-point Gauss-Legendre on [-8 j, 8 j] (truncation < 1e-15; the
// integrand is analytic, so the rule is converged far below the renderer's own 1e-10 flux
// tolerance). Tolerance 1e-8 of the flux.
TEST(Effects, GaussianJitterIsAVarianceAdditionInIntegratedSampling) {
  const ModelOptions options;
  SpotRenderer renderer(options);
  const PixelGrid grid = Grid(15, 14);
  const SpotParams p = PaperSpot();
  ExposureEffects e;
  e.jitter = JitterParams{0.2, 0.0, 0.0, 0.0};
  std::vector<double> jittered(grid.size());
  RenderSpotWithKernelEffects(renderer, e, p, grid, 0.0, jittered.data());
  SpotParams wide = p;
  wide[kCcdSigmaX] = std::hypot(0.291, 0.2);
  EXPECT_EQ(jittered, Render(renderer, wide, grid));

  const int n = 48;
  std::vector<double> nodes(n), weights(n);
  {
    // Gauss-Legendre nodes by Newton's method on P_n (independent of the library's rule).
    for (int i = 0; i < n; ++i) {
      double x = std::cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 0.0;
      for (int it = 0; it < 100; ++it) {
        double p0 = 1.0, p1 = x;
        for (int k = 2; k <= n; ++k) {
          const double p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
          p0 = p1;
          p1 = p2;
        }
        dp = n * (x * p1 - p0) / (x * x - 1.0);
        const double dx = p1 / dp;
        x -= dx;
        if (std::fabs(dx) < 1e-16) break;
      }
      nodes[i] = x;
      weights[i] = 2.0 / ((1.0 - x * x) * dp * dp);
    }
  }
  const double j = 0.2, half = 8.0 * j;
  std::vector<double> average(grid.size(), 0.0);
  for (int i = 0; i < n; ++i) {
    const double d = half * nodes[i];
    const double w = half * weights[i] * std::exp(-d * d / (2 * j * j)) /
                     (std::sqrt(2.0 * M_PI) * j);
    SpotParams shifted = p;
    shifted[kCentreX] += d;
    const std::vector<double> m = Render(renderer, shifted, grid);
    for (int q = 0; q < grid.size(); ++q) average[q] += w * m[q];
  }
  EXPECT_LT(MaxAbsDiff(average, jittered), 1e-8 * p[kFlux]);
}

// Motion blur: length 0 is no blur (exactly); the Gauss-Legendre average converges quickly as
// the node count grows; the automatic count meets its bound (1e-10 of the flux, the renderer's
// tolerance; checked at 2e-10 to allow for the reference's own error) against a 64-node
// reference.
TEST(Effects, MotionBlurIsExactAtZeroLengthAndConverges) {
  const ModelOptions options;
  SpotRenderer renderer(options);
  const PixelGrid grid = Grid(17, 17);
  const SpotParams p = PaperSpot(8.1, 7.9);
  ExposureEffects e;
  e.jitter = JitterParams{0.0, 0.0, 0.0, 30.0};
  std::vector<double> still(grid.size());
  KernelEffectDetails details;
  RenderSpotWithKernelEffects(renderer, e, p, grid, 0.0, still.data(), &details);
  EXPECT_EQ(still, Render(renderer, p, grid));
  EXPECT_EQ(details.motion_nodes, 1);
  EXPECT_EQ(MotionBlurNodeCount(0.0, 30.0, 0.5, 0.5, 1e-10), 1);

  e.jitter->motion_length_px = 1.2;
  std::vector<double> reference(grid.size());
  RenderSpotWithKernelEffects(renderer, e, p, grid, 0.0, reference.data(), nullptr, 64);
  double previous = HUGE_VAL;
  for (int n : {1, 2, 3, 4, 6, 8}) {
    std::vector<double> m(grid.size());
    RenderSpotWithKernelEffects(renderer, e, p, grid, 0.0, m.data(), nullptr, n);
    const double err = MaxAbsDiff(m, reference);
    EXPECT_LT(err, previous) << n << " nodes";
    previous = err;
  }
  EXPECT_LT(previous, 1e-6 * p[kFlux]);  // 8 nodes
  std::vector<double> automatic(grid.size());
  RenderSpotWithKernelEffects(renderer, e, p, grid, 0.0, automatic.data(), &details);
  EXPECT_GE(details.motion_nodes, 2);
  EXPECT_LE(details.motion_nodes, 20);
  EXPECT_LT(MaxAbsDiff(automatic, reference), 2e-10 * p[kFlux]);
  // The blur is along the segment: at 30 deg it spreads light both ways in x and y, and
  // lowers the peak.
  EXPECT_LT(*std::max_element(automatic.begin(), automatic.end()),
            *std::max_element(still.begin(), still.end()));
  // More nodes for longer segments and narrower spots.
  EXPECT_LE(MotionBlurNodeCount(1.0, 0.0, 0.5, 0.5, 1e-10),
            MotionBlurNodeCount(2.0, 0.0, 0.5, 0.5, 1e-10));
  EXPECT_LE(MotionBlurNodeCount(1.0, 0.0, 0.5, 0.5, 1e-10),
            MotionBlurNodeCount(1.0, 0.0, 0.2, 0.5, 1e-10));
  EXPECT_LE(MotionBlurNodeCount(1.0, 0.0, 0.5, 0.5, 1e-10),
            MotionBlurNodeCount(1.0, 0.0, 0.5, 0.5, 1e-12));
}

// defocus_offset in integrated sampling: a convolution with a shifted kernel is the same
// image shifted, i.e. the spot rendered at (x + dx, y + dy).
TEST(Effects, DefocusOffsetShiftsTheImageInIntegratedSampling) {
  const ModelOptions options;
  SpotRenderer renderer(options);
  const PixelGrid grid = Grid(15, 15);
  const SpotParams p = PaperSpot();
  ExposureEffects e;
  e.defocus_offset = DefocusOffsetParams{0.2, -0.15};
  std::vector<double> m(grid.size());
  KernelEffectDetails details;
  RenderSpotWithEffects(renderer, e, p, grid, m.data(), &details);
  const SpotParams moved = PaperSpot(7.07 + 0.2, 6.96 - 0.15);
  EXPECT_EQ(m, Render(renderer, moved, grid));
  EXPECT_DOUBLE_EQ(details.centre_x_px, 7.27);
  EXPECT_DOUBLE_EQ(details.centre_y_px, 6.81);
}

// ------------------------------------------------------------------------------------------
// Configuration.

TEST(Effects, ConfigTakesDefaultsAndPerExposureJitter) {
  EffectsConfig c;
  std::string error;
  const json j = json::parse(R"({"ipc": {}, "serial_cti": {"trail_fraction": 1e-3},
      "jitter": {"sigma_x_px": [0.0, 0.15, 0.3], "sigma_y_px": 0.05},
      "background": {"pedestal_e": -12}})");
  ASSERT_TRUE(ParseEffectsConfig(j, 3, Sampling::kIntegrated, &c, &error)) << error;
  EXPECT_EQ(c.common.ipc->alpha, IpcParams().alpha);
  EXPECT_EQ(c.common.serial_cti->trail_fraction, 1e-3);
  EXPECT_EQ(c.common.serial_cti->trail_length_px, CtiParams().trail_length_px);
  EXPECT_EQ(c.common.background->pedestal_e, -12.0);
  EXPECT_FALSE(c.common.halo.has_value());
  ASSERT_EQ(c.jitter_per_exposure.size(), 3u);
  EXPECT_EQ(c.ForExposure(1).jitter->sigma_x_px, 0.15);
  EXPECT_EQ(c.ForExposure(2).jitter->sigma_x_px, 0.3);
  EXPECT_EQ(c.ForExposure(2).jitter->sigma_y_px, 0.05);
  EXPECT_EQ(c.ForExposure(0).jitter->motion_length_px, 0.0);
  // Written back in the config's form, and read again to the same values.
  const json back = EffectsConfigToJson(c);
  EXPECT_EQ(back["jitter"]["sigma_x_px"], json({0.0, 0.15, 0.3}));
  EXPECT_EQ(back["jitter"]["sigma_y_px"], json({0.05, 0.05, 0.05}));
  EXPECT_EQ(back["ipc"]["alpha"], IpcParams().alpha);
  EffectsConfig again;
  ASSERT_TRUE(ParseEffectsConfig(back, 3, Sampling::kIntegrated, &again, &error)) << error;
  EXPECT_EQ(EffectsConfigToJson(again), back);

  // A pure motion blur: the Gaussian widths default to 0 when only motion is given.
  ASSERT_TRUE(ParseEffectsConfig(json::parse(R"({"jitter": {"motion_length_px": 0.4,
      "motion_angle_deg": 45}})"), 2, Sampling::kIntegrated, &c, &error)) << error;
  EXPECT_TRUE(c.jitter_per_exposure.empty());
  EXPECT_EQ(c.common.jitter->sigma_x_px, 0.0);
  EXPECT_EQ(c.common.jitter->motion_angle_deg, 45.0);
  EXPECT_EQ(c.ForExposure(1).jitter->motion_length_px, 0.4);
  ASSERT_TRUE(ParseEffectsConfig(json::parse(R"({"jitter": {}})"), 2, Sampling::kIntegrated,
                                 &c, &error));
  EXPECT_EQ(c.common.jitter->sigma_y_px, JitterParams().sigma_y_px);
  ASSERT_TRUE(ParseEffectsConfig(json::object(), 2, Sampling::kIntegrated, &c, &error));
  EXPECT_TRUE(c.empty());
  EXPECT_EQ(EffectsConfigToJson(c), json::object());
}

TEST(Effects, BadConfigsAreOneLineErrorsNamingTheKey) {
  struct Case {
    std::string json, message;
    Sampling sampling = Sampling::kIntegrated;
  };
  const std::vector<Case> cases = {
      {R"({"ipcc": {}})", "unknown effect 'effects.ipcc'"},
      {R"({"defocus": {"sigma_px": 0.3}})", "'effects.defocus' cannot be injected"},
      {R"({"ipc": {"alpha": 0.3}})", "'effects.ipc.alpha' must be in [0, 0.25) (got 0.3)"},
      {R"({"ipc": {"alpa": 0.01}})", "unknown key 'effects.ipc.alpa'"},
      {R"({"ipc": 0.01})", "'effects.ipc' must be a JSON object"},
      {R"({"halo": {"sigma_px": "wide"}})", "'effects.halo.sigma_px' must be a finite number"},
      {R"({"halo": {"sigma_px": 0}})", "'effects.halo.sigma_px' must be in (0, inf)"},
      {R"({"serial_cti": {"trail_fraction": -1e-4}})", "'effects.serial_cti.trail_fraction'"},
      {R"({"parallel_cti": {"trail_length_px": -1}})", "'effects.parallel_cti.trail_length_px'"},
      {R"({"nonlinearity": {"beta_per_e": -1e-7}})", "'effects.nonlinearity.beta_per_e'"},
      {R"({"brighter_fatter": {"slope_x_px_per_e": -1e-7}})",
       "'effects.brighter_fatter.slope_x_px_per_e'"},
      {R"({"jitter": {"sigma_x_px": [0.1, 0.2]}})",
       "'effects.jitter.sigma_x_px' must be a finite number or a list of 3"},
      {R"({"jitter": {"sigma_y_px": [0.1, -0.2, 0.1]}})", "'effects.jitter.sigma_y_px' must be in"},
      {R"({"jitter": {"motion_angle_deg": 30}})", "needs 'effects.jitter.motion_length_px'"},
      {R"({"jitter": {"motion_length_px": 50}})", "'effects.jitter.motion_length_px' must be in"},
      {R"({"jitter": {"shake": 1}})", "unknown key 'effects.jitter.shake'"},
      {R"({"defocus_offset": {"dx_px": 9}})", "'effects.defocus_offset.dx_px' must be in"},
      {R"([1, 2])", "'effects' must be a JSON object"},
  };
  for (const Case& c : cases) {
    EffectsConfig out;
    std::string error;
    EXPECT_FALSE(ParseEffectsConfig(json::parse(c.json), 3, c.sampling, &out, &error)) << c.json;
    EXPECT_NE(error.find(c.message), std::string::npos) << c.json << " -> " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
}

}  // namespace
}  // namespace ccdpsf::model
