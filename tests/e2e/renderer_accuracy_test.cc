// Accuracy of the integrated-sampling renderer against the independent Fourier-space
// reference (tests/support/reference_model.h), over the whole parameter range the fits use.
//
// Tolerance: every compared pixel must agree with the reference to 1e-6 of the reference's
// peak pixel. Why 1e-6: the brightest exposures hold ~1.6e5 e- in the peak pixel, whose
// Poisson noise is 400 e- = 2.5e-3 of the peak; the noise of any fainter pixel is smaller in
// electrons but never below the read noise (4.5 e-, ~3e-5 of such a peak). A model error of
// 1e-6 of the peak (0.16 e-) is thus at least 30 times below the noise of every pixel and
// cannot bias a fit visibly. The renderer's own target (ModelOptions::relative_tolerance,
// 1e-10 of the flux; the peak pixel holds >= 5 % of the flux in this range) is far tighter,
// so a failure here is a real defect, not quadrature noise. The reference itself is
// converged to 1e-12 of the flux and checked in reference_model_test.cc.
//
// Pixels compared per case: the pixel holding the spot centre (the peak), its 8 neighbours,
// four pixels 3-6 px away in random directions, and the four stamp corners, where the Airy
// tail (~1 / d^3) is all that is left and where a renderer truncating its kernels would fail.
#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "ccdpsf/model/renderer.h"
#include "ccdpsf/model/spot_model.h"
#include "gtest/gtest.h"
#include "support/reference_model.h"

namespace ccdpsf::model {
namespace {

using testing_reference::FromSpotParams;
using testing_reference::ReferencePixel;
using testing_reference::ReferenceResult;

constexpr double kToleranceOfPeak = 1e-6;
constexpr double kPi = 3.14159265358979323846;

struct AccuracyCase {
  std::string label;
  DefocusKind kind = DefocusKind::kGaussian;
  SpotParams params{};
  int nx = 21;
  int ny = 21;
  double pixel_window = 1.0;  // ModelOptions::pixel_response_width
};

std::string Describe(const AccuracyCase& c) {
  std::ostringstream out;
  out.precision(17);
  out << c.label << " [" << ToString(c.kind) << ", " << c.nx << "x" << c.ny
      << "] flux=" << c.params[kFlux] << " x=" << c.params[kCentreX]
      << " y=" << c.params[kCentreY] << " r=" << c.params[kAiryRadius]
      << " defocus=" << c.params[kDefocus] << " sx=" << c.params[kCcdSigmaX]
      << " sy=" << c.params[kCcdSigmaY];
  return out.str();
}

// For RecordProperty: the measured worst error goes to the XML report (--gtest_output=xml),
// not to the console.
std::string Scientific(double value) {
  std::ostringstream out;
  out << std::scientific << value;
  return out.str();
}

double Uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

// A stamp size in [9, 41]; odd and even alike.
int StampSize(std::mt19937_64& rng) { return std::uniform_int_distribution<int>(9, 41)(rng); }

// The centre at a random sub-pixel position inside the pixel nearest the stamp centre.
void CentreNearStampCentre(std::mt19937_64& rng, AccuracyCase* c) {
  c->params[kCentreX] = std::floor(0.5 * (c->nx - 1)) + Uniform(rng, -0.5, 0.5);
  c->params[kCentreY] = std::floor(0.5 * (c->ny - 1)) + Uniform(rng, -0.5, 0.5);
}

AccuracyCase GaussianCase(const std::string& label, double r, double sigma_f, double sx,
                          double sy, int nx, int ny, std::mt19937_64& rng) {
  AccuracyCase c;
  c.label = label;
  c.kind = DefocusKind::kGaussian;
  c.nx = nx;
  c.ny = ny;
  c.params[kFlux] = Uniform(rng, 1e4, 1e6);
  c.params[kAiryRadius] = r;
  c.params[kDefocus] = sigma_f;
  c.params[kCcdSigmaX] = sx;
  c.params[kCcdSigmaY] = sy;
  CentreNearStampCentre(rng, &c);
  return c;
}

// The pixels to compare, as (i, j) stamp indices, without duplicates.
std::vector<std::pair<int, int>> PixelsToCompare(const AccuracyCase& c, std::mt19937_64& rng) {
  std::set<std::pair<int, int>> pixels;
  auto add = [&](int i, int j) {
    if (i >= 0 && i < c.nx && j >= 0 && j < c.ny) pixels.insert({i, j});
  };
  const int pi = static_cast<int>(std::lround(c.params[kCentreX]));
  const int pj = static_cast<int>(std::lround(c.params[kCentreY]));
  for (int dj = -1; dj <= 1; ++dj) {
    for (int di = -1; di <= 1; ++di) add(pi + di, pj + dj);
  }
  for (int k = 0; k < 4; ++k) {
    // A random direction and a distance in [3, 6] px, rounded to a pixel; retried until it
    // lands inside the stamp (a stamp is at least 9 px wide, so most directions do).
    for (int attempt = 0; attempt < 20; ++attempt) {
      const double angle = Uniform(rng, 0.0, 2.0 * kPi);
      const double distance = Uniform(rng, 3.0, 6.0);
      const int i = static_cast<int>(std::lround(c.params[kCentreX] + distance * std::cos(angle)));
      const int j = static_cast<int>(std::lround(c.params[kCentreY] + distance * std::sin(angle)));
      if (i >= 0 && i < c.nx && j >= 0 && j < c.ny) {
        add(i, j);
        break;
      }
    }
  }
  add(0, 0);
  add(c.nx - 1, 0);
  add(0, c.ny - 1);
  add(c.nx - 1, c.ny - 1);
  return {pixels.begin(), pixels.end()};
}

// Renders the case and compares the chosen pixels with the reference. Returns the largest
// |renderer - reference| / reference peak seen.
double CheckCase(const AccuracyCase& c, std::mt19937_64& rng) {
  ModelOptions options;
  options.sampling = Sampling::kIntegrated;
  options.defocus = c.kind;
  options.pixel_response_width = c.pixel_window;
  SpotRenderer renderer(options);
  PixelGrid grid;
  grid.nx = c.nx;
  grid.ny = c.ny;
  grid.x0 = 0.0;
  grid.y0 = 0.0;
  std::vector<double> model(grid.size());
  renderer.Render(c.params, grid, model.data(), nullptr);

  testing_reference::ReferenceSpot spot = FromSpotParams(c.params, c.kind);
  spot.pixel_window = c.pixel_window;
  const int pi = static_cast<int>(std::lround(c.params[kCentreX]));
  const int pj = static_cast<int>(std::lround(c.params[kCentreY]));
  const ReferenceResult peak = ReferencePixel(spot, pi, pj);
  EXPECT_TRUE(peak.converged) << Describe(c);
  const double peak_value = peak.values[0];
  EXPECT_GT(peak_value, 0.0) << Describe(c);

  double worst = 0.0;
  for (const auto& [i, j] : PixelsToCompare(c, rng)) {
    const ReferenceResult ref =
        (i == pi && j == pj) ? peak : ReferencePixel(spot, i, j);
    EXPECT_TRUE(ref.converged) << Describe(c) << " pixel (" << i << ", " << j << ")";
    const double rendered = model[j * grid.nx + i];
    const double error = std::abs(rendered - ref.values[0]) / peak_value;
    EXPECT_LE(error, kToleranceOfPeak)
        << Describe(c) << "\n  pixel (" << i << ", " << j << "): renderer " << rendered
        << " reference " << ref.values[0] << " peak " << peak_value;
    if (!(error <= worst)) worst = error;
  }
  return worst;
}

// The corners of the parameter box, where a renderer's quadrature is most likely to be
// under-resolved (all widths 0.1 px: a sharp, undersampled spot with a strong Airy tail) or
// to lose accuracy (all 0.8 px: wide kernels on a 9 x 9 stamp), and mixed corners where the
// x and y kernels differ by a factor 8.
TEST(RendererAccuracy, GaussianDefocusAtTheCornersOfTheParameterRange) {
  std::mt19937_64 rng(0x5eed0001);
  const std::vector<AccuracyCase> cases = {
      GaussianCase("sharpest", 0.3, 0.1, 0.1, 0.1, 41, 41, rng),
      GaussianCase("widest", 0.9, 0.8, 0.8, 0.8, 9, 9, rng),
      GaussianCase("small airy, wide blur", 0.3, 0.8, 0.8, 0.8, 20, 20, rng),
      GaussianCase("large airy, sharp blur", 0.9, 0.1, 0.1, 0.1, 40, 40, rng),
      GaussianCase("mixed 1", 0.3, 0.8, 0.1, 0.8, 17, 24, rng),
      GaussianCase("mixed 2", 0.9, 0.1, 0.8, 0.1, 33, 12, rng),
      GaussianCase("mixed 3", 0.3, 0.1, 0.8, 0.1, 10, 31, rng),
  };
  double worst = 0.0;
  for (const AccuracyCase& c : cases) worst = std::max(worst, CheckCase(c, rng));
  RecordProperty("max_error_of_peak", Scientific(worst));
}

// Random draws over the whole box: r in [0.3, 0.9], every sigma in [0.1, 0.8], stamps 9-41.
TEST(RendererAccuracy, GaussianDefocusRandomDraws) {
  std::mt19937_64 rng(0x5eed0002);
  double worst = 0.0;
  for (int k = 0; k < 17; ++k) {
    const int nx = StampSize(rng);
    const int ny = StampSize(rng);
    const double r = Uniform(rng, 0.3, 0.9);
    const double sigma_f = Uniform(rng, 0.1, 0.8);
    const double sx = Uniform(rng, 0.1, 0.8);
    const double sy = Uniform(rng, 0.1, 0.8);
    worst = std::max(
        worst,
        CheckCase(GaussianCase("random " + std::to_string(k), r, sigma_f, sx, sy, nx, ny, rng),
                  rng));
  }
  RecordProperty("max_error_of_peak", Scientific(worst));
}

// A spot in a stamp's corner pixel: the far corner is ~50 px away, deep in the Airy tail, and
// the near edges cut the spot; a renderer that assumed a centred spot would fail here.
TEST(RendererAccuracy, SpotNearAStampCorner) {
  std::mt19937_64 rng(0x5eed0003);
  AccuracyCase c = GaussianCase("near corner", 0.35, 0.15, 0.12, 0.2, 36, 33, rng);
  c.params[kCentreX] = 1.0 + Uniform(rng, -0.45, 0.45);
  c.params[kCentreY] = 0.0 + Uniform(rng, -0.45, 0.45);
  RecordProperty("max_error_of_peak", Scientific(CheckCase(c, rng)));
}

// The pillbox defocus: R in [0.2, 1.5] px (the edges of the range and random draws), CCD
// sigmas in [0.1, 0.8] px.
TEST(RendererAccuracy, PillboxDefocus) {
  std::mt19937_64 rng(0x5eed0004);
  std::vector<AccuracyCase> cases;
  const double fixed[][4] = {{0.3, 0.2, 0.1, 0.1}, {0.9, 1.5, 0.8, 0.8}, {0.5, 1.5, 0.1, 0.6}};
  for (const auto& f : fixed) {
    AccuracyCase c = GaussianCase("pillbox corner", f[0], f[1], f[2], f[3], StampSize(rng),
                                  StampSize(rng), rng);
    c.kind = DefocusKind::kPillbox;
    cases.push_back(c);
  }
  for (int k = 0; k < 3; ++k) {
    const int nx = StampSize(rng);
    const int ny = StampSize(rng);
    const double r = Uniform(rng, 0.3, 0.9);
    const double radius = Uniform(rng, 0.2, 1.5);
    const double sx = Uniform(rng, 0.1, 0.8);
    const double sy = Uniform(rng, 0.1, 0.8);
    AccuracyCase c =
        GaussianCase("pillbox random " + std::to_string(k), r, radius, sx, sy, nx, ny, rng);
    c.kind = DefocusKind::kPillbox;
    cases.push_back(c);
  }
  double worst = 0.0;
  for (const AccuracyCase& c : cases) worst = std::max(worst, CheckCase(c, rng));
  RecordProperty("max_error_of_peak", Scientific(worst));
}

// A pixel response narrower than the pixel (a collecting window of width 0.5-0.9 px, the
// alternative `ccdpsf diagnose` tests), Gaussian and pillbox defocus.
TEST(RendererAccuracy, NarrowPixelResponse) {
  std::mt19937_64 rng(0x5eed0005);
  double worst = 0.0;
  for (int k = 0; k < 4; ++k) {
    AccuracyCase c = GaussianCase("window " + std::to_string(k), Uniform(rng, 0.3, 0.9),
                                  Uniform(rng, 0.0, 0.6), Uniform(rng, 0.1, 0.6),
                                  Uniform(rng, 0.1, 0.6), StampSize(rng), StampSize(rng), rng);
    c.pixel_window = Uniform(rng, 0.5, 0.9);
    if (k == 3) c.kind = DefocusKind::kPillbox;
    worst = std::max(worst, CheckCase(c, rng));
  }
  RecordProperty("max_error_of_peak", Scientific(worst));
}

}  // namespace
}  // namespace ccdpsf::model
