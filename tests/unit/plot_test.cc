#include "ccdpsf/plot.h"

#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "internal/subprocess.h"
#include "support/fits_fixtures.h"
#include "support/slow_test.h"

namespace ccdpsf {
namespace {

using test_support::ScopedTempDir;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
const char kMissingGnuplot[] = "/nonexistent/ccdpsf-test/gnuplot";

bool Exists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

// The numeric rows of a gnuplot data file, split into its `index` blocks (two or more blank
// lines apart); '#' lines are skipped. Values are read with strtod, which reads "NaN" too.
using Block = std::vector<std::vector<double>>;
std::vector<Block> ReadBlocks(const std::string& path) {
  std::vector<Block> blocks(1);
  std::istringstream in(ReadText(path));
  std::string line;
  int blank_run = 0;
  while (std::getline(in, line)) {
    if (line.empty()) {
      ++blank_run;
      continue;
    }
    if (line[0] == '#') continue;
    if (blank_run >= 2 && !blocks.back().empty()) blocks.emplace_back();
    blank_run = 0;
    std::istringstream fields(line);
    std::vector<double> row;
    std::string token;
    while (fields >> token) row.push_back(std::strtod(token.c_str(), nullptr));
    blocks.back().push_back(row);
  }
  return blocks;
}

// Same value, NaN matching NaN.
bool SameValue(double a, double b) { return (std::isnan(a) && std::isnan(b)) || a == b; }

struct PngInfo {
  bool valid = false;
  uint32_t width = 0, height = 0;
  size_t bytes = 0;
};

// Checks the 8-byte PNG signature and reads the size from the IHDR chunk that must follow.
PngInfo ReadPngInfo(const std::string& path) {
  const std::string bytes = ReadText(path);
  PngInfo info;
  info.bytes = bytes.size();
  const std::string signature = "\x89PNG\r\n\x1a\n";
  if (bytes.size() < 24 || bytes.compare(0, 8, signature) != 0 ||
      bytes.compare(12, 4, "IHDR") != 0) {
    return info;
  }
  auto be32 = [&](size_t at) {
    uint32_t v = 0;
    for (size_t i = 0; i < 4; ++i) v = (v << 8) | static_cast<unsigned char>(bytes[at + i]);
    return v;
  };
  info.valid = true;
  info.width = be32(16);
  info.height = be32(20);
  return info;
}

// When gnuplot is here, the PNG must be a real picture of a plausible size; without it, the
// result must say so.
void ExpectPng(const PlotResult& result, uint32_t min_width, uint32_t max_width,
               uint32_t min_height, uint32_t max_height) {
  if (!GnuplotAvailable()) {
    EXPECT_FALSE(result.image_written);
    EXPECT_FALSE(result.message.empty());
    return;
  }
  ASSERT_TRUE(result.image_written) << result.message;
  const PngInfo png = ReadPngInfo(result.image_path);
  ASSERT_TRUE(png.valid) << result.image_path;
  EXPECT_GE(png.width, min_width);
  EXPECT_LE(png.width, max_width);
  EXPECT_GE(png.height, min_height);
  EXPECT_LE(png.height, max_height);
  EXPECT_GT(png.bytes, 5000u) << "suspiciously small picture";
}

// No temporary file of the atomic writes may be left behind.
void ExpectNoTemporaries(const ScopedTempDir& dir) {
  for (const std::string& name : dir.List()) {
    EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
  }
}

// A one-line, non-empty reason.
void ExpectOneLineError(const std::string& error) {
  EXPECT_FALSE(error.empty());
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
}

// dim correlated Gaussian parameters: x_k = mu_k + sd_k (z_k + 0.6 z_{k-1}), so neighbours
// are correlated and the exact covariance is known.
CornerPlotInput MakeCornerInput(int dim, int num_samples, uint64_t seed) {
  std::mt19937_64 engine(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  CornerPlotInput in;
  for (int k = 0; k < dim; ++k) in.names.push_back("param_" + std::to_string(k) + "_px");
  std::vector<double> mu(dim), sd(dim);
  for (int k = 0; k < dim; ++k) {
    mu[k] = 10.0 * k + 0.5;
    sd[k] = 0.1 * (k + 1);
  }
  in.num_samples = num_samples;
  for (int i = 0; i < num_samples; ++i) {
    std::vector<double> z(dim);
    for (double& v : z) v = normal(engine);
    for (int k = 0; k < dim; ++k) {
      in.samples.push_back(mu[k] + sd[k] * (z[k] + (k > 0 ? 0.6 * z[k - 1] : 0.0)));
    }
  }
  in.map = mu;
  in.laplace_covariance.assign(static_cast<size_t>(dim) * dim, 0.0);
  for (int a = 0; a < dim; ++a) {
    for (int b = 0; b < dim; ++b) {
      double c = 0;
      if (a == b) c = 1.0 + (a > 0 ? 0.36 : 0.0);
      if (b == a - 1 || a == b - 1) c = 0.6;
      in.laplace_covariance[static_cast<size_t>(a) * dim + b] = c * sd[a] * sd[b];
    }
  }
  in.truth = mu;
  in.truth[0] += 0.05;
  in.title = "test corner: it's a_b";
  return in;
}

// ---------------------------------------------------------------------------------------------

TEST(Plot, GnuplotAvailableIsFalseForAMissingProgram) {
  EXPECT_FALSE(GnuplotAvailable(kMissingGnuplot));
  EXPECT_FALSE(GnuplotAvailable("ccdpsf-no-such-gnuplot-on-path"));
}

TEST(Plot, CornerWritesDataScriptAndPng) {
  ScopedTempDir dir;
  const int dim = 3, n = 2000;
  const CornerPlotInput in = MakeCornerInput(dim, n, 17);
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "corner", in, &result, &error)) << error;
  EXPECT_EQ(result.script_path, dir.File("corner.gp"));
  EXPECT_EQ(result.image_path, dir.File("corner.png"));
  ASSERT_TRUE(Exists(result.script_path));
  for (const std::string& path : result.data_paths) EXPECT_TRUE(Exists(path)) << path;
  const std::string script = ReadText(result.script_path);
  EXPECT_NE(script.find("corner_samples.dat"), std::string::npos);
  EXPECT_NE(script.find("if (!exists(\"outfile\")) outfile = 'corner.' . plot_format"),
            std::string::npos);

  // Fewer than 5000 samples: every one is kept, and reads back exactly.
  const std::vector<Block> samples = ReadBlocks(dir.File("corner_samples.dat"));
  ASSERT_EQ(samples.size(), 1u);
  ASSERT_EQ(samples[0].size(), static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    ASSERT_EQ(samples[0][i].size(), static_cast<size_t>(dim));
    for (int k = 0; k < dim; ++k) {
      ASSERT_EQ(samples[0][i][k], in.samples[static_cast<size_t>(i) * dim + k]) << i << "," << k;
    }
  }

  // One histogram per parameter whose counts add up to n and whose density integrates to 1.
  const std::vector<Block> hist = ReadBlocks(dir.File("corner_hist.dat"));
  ASSERT_EQ(hist.size(), static_cast<size_t>(dim));
  for (const Block& block : hist) {
    double count = 0, integral = 0;
    for (const auto& row : block) {
      ASSERT_EQ(row.size(), 4u);
      integral += row[1] * row[2];
      count += row[3];
    }
    EXPECT_EQ(count, n);
    EXPECT_NEAR(integral, 1.0, 1e-12);
  }

  // Summary: index name map laplace_sd truth axis_lo axis_hi.
  std::istringstream summary(ReadText(dir.File("corner_summary.dat")));
  std::string line;
  int k = 0;
  while (std::getline(summary, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    int index;
    std::string name, map, sd, truth, lo, hi;
    fields >> index >> name >> map >> sd >> truth >> lo >> hi;
    ASSERT_LT(k, dim);
    EXPECT_EQ(index, k);
    EXPECT_EQ(name, in.names[k]);
    EXPECT_EQ(std::strtod(map.c_str(), nullptr), in.map[k]);
    EXPECT_EQ(std::strtod(sd.c_str(), nullptr),
              std::sqrt(in.laplace_covariance[static_cast<size_t>(k) * dim + k]));
    EXPECT_EQ(std::strtod(truth.c_str(), nullptr), in.truth[k]);
    EXPECT_LT(std::strtod(lo.c_str(), nullptr), in.map[k]);
    EXPECT_GT(std::strtod(hi.c_str(), nullptr), in.map[k]);
    ++k;
  }
  EXPECT_EQ(k, dim);

  // Ellipses: two levels for each of the 3 panels, every point at the stated Mahalanobis
  // radius of its 2x2 covariance (checked here with the explicit inverse).
  const std::vector<Block> ellipses = ReadBlocks(dir.File("corner_ellipses.dat"));
  ASSERT_EQ(ellipses.size(), 6u);
  const double radius2[2] = {-2.0 * std::log(0.32), -2.0 * std::log(0.05)};
  int block = 0;
  for (int r = 1; r < dim; ++r) {
    for (int c = 0; c < r; ++c) {
      const double sxx = in.laplace_covariance[c * dim + c];
      const double syy = in.laplace_covariance[r * dim + r];
      const double sxy = in.laplace_covariance[c * dim + r];
      const double det = sxx * syy - sxy * sxy;
      for (int level = 0; level < 2; ++level, ++block) {
        ASSERT_GT(ellipses[block].size(), 50u);
        for (const auto& row : ellipses[block]) {
          const double dx = row[0] - in.map[c], dy = row[1] - in.map[r];
          const double m2 = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det;
          EXPECT_NEAR(m2, radius2[level], 1e-9 * radius2[level]);
        }
      }
    }
  }

  // 3 panels of ~200 px plus margins.
  ExpectPng(result, 600, 1000, 600, 1000);
  ExpectNoTemporaries(dir);
}

TEST(Plot, CornerThinsTheScatterToAtMost2500Points) {
  ScopedTempDir dir;
  const int n = 12001;
  const CornerPlotInput in = MakeCornerInput(2, n, 3);
  PlotOptions options;
  options.gnuplot_path = kMissingGnuplot;  // only the data matter here
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "thin", in, nullptr, &error, options)) << error;
  const std::vector<Block> samples = ReadBlocks(dir.File("thin_samples.dat"));
  ASSERT_EQ(samples.size(), 1u);
  // stride ceil(12001 / 2500) = 5: samples 0, 5, ..., 12000.
  ASSERT_EQ(samples[0].size(), 2401u);
  for (size_t i = 0; i < samples[0].size(); ++i) {
    EXPECT_EQ(samples[0][i][0], in.samples[(5 * i) * 2]);
    EXPECT_EQ(samples[0][i][1], in.samples[(5 * i) * 2 + 1]);
  }
  // The histograms still use every sample.
  double count = 0;
  const std::vector<Block> hist = ReadBlocks(dir.File("thin_hist.dat"));
  for (const auto& row : hist[0]) count += row[3];
  EXPECT_EQ(count, n);
}

TEST(Plot, CornerSkipsLaplaceWhereTheSdIsUndefined) {
  ScopedTempDir dir;
  const int dim = 4;
  CornerPlotInput in = MakeCornerInput(dim, 500, 5);
  for (int j = 0; j < dim; ++j) {  // parameter 2 is not identified
    in.laplace_covariance[2 * dim + j] = kNaN;
    in.laplace_covariance[j * dim + 2] = kNaN;
  }
  in.truth = {};
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "corner", in, &result, &error)) << error;
  // Pairs without parameter 2: (1,0), (3,0), (3,1): 3 panels x 2 levels.
  EXPECT_EQ(ReadBlocks(dir.File("corner_ellipses.dat")).size(), 6u);
  const std::string summary = ReadText(dir.File("corner_summary.dat"));
  EXPECT_NE(summary.find("2 param_2_px 20.5 NaN NaN"), std::string::npos) << summary;
  const std::string script = ReadText(result.script_path);
  EXPECT_NE(script.find("No Laplace sd (not identified by the data): param_2_px"),
            std::string::npos);
  EXPECT_EQ(script.find("title 'true value'"), std::string::npos);  // no truth: no key entry
  ExpectPng(result, 700, 1300, 700, 1300);
}

TEST(Plot, CornerWithOneParameterAndNoLaplace) {
  ScopedTempDir dir;
  CornerPlotInput in = MakeCornerInput(1, 300, 9);
  in.laplace_covariance.clear();
  in.map.clear();
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "one", in, &result, &error)) << error;
  EXPECT_FALSE(Exists(dir.File("one_ellipses.dat")));
  ExpectPng(result, 300, 800, 250, 600);
}

TEST(Plot, CornerRejectsBadInput) {
  ScopedTempDir dir;
  const CornerPlotInput good = MakeCornerInput(3, 100, 1);
  std::string error;
  auto rejects = [&](const CornerPlotInput& in, const std::string& stem = "corner") {
    error.clear();
    const bool ok = WriteCornerPlot(dir.path(), stem, in, nullptr, &error);
    ExpectOneLineError(error);
    return !ok;
  };
  CornerPlotInput in = good;
  in.samples.pop_back();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.num_samples = 0;
  in.samples.clear();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.names[1].clear();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.names.clear();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.map.push_back(1.0);
  EXPECT_TRUE(rejects(in));
  in = good;
  in.laplace_covariance.resize(4);
  EXPECT_TRUE(rejects(in));
  in = good;
  in.truth.resize(2);
  EXPECT_TRUE(rejects(in));
  in = good;
  in.samples[7] = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(rejects(in));
  EXPECT_TRUE(rejects(good, "sub/corner"));
  EXPECT_TRUE(rejects(good, ""));
  EXPECT_TRUE(rejects(good, "it's"));
  EXPECT_TRUE(rejects(good, "-x"));
  // Nothing was written by the rejected calls.
  EXPECT_TRUE(dir.List().empty());

  // A folder that cannot be created: a file is in the way.
  std::ofstream(dir.File("blocker")) << "x";
  error.clear();
  EXPECT_FALSE(WriteCornerPlot(dir.File("blocker/plots"), "corner", good, nullptr, &error));
  ExpectOneLineError(error);
}

// ---------------------------------------------------------------------------------------------

StampPanels MakeStamp(int nx, int ny, int origin_x, int origin_y, uint64_t seed) {
  std::mt19937_64 engine(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  StampPanels p;
  p.title = "exposure " + std::to_string(seed);
  p.data = p.model = p.residual = p.normalised = Image(nx, ny);
  p.origin_x = origin_x;
  p.origin_y = origin_y;
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) {
      const double r2 = std::pow(x - nx / 2.0, 2) + std::pow(y - ny / 2.0, 2);
      const double model = 3e4 * std::exp(-r2 / 1.5) + 12.0;
      const double sigma = std::sqrt(model + 20.0);
      const double data = model + sigma * normal(engine);
      p.data(x, y) = data;
      p.model(x, y) = model;
      p.residual(x, y) = data - model;
      p.normalised(x, y) = (data - model) / sigma;
    }
  }
  return p;
}

TEST(Plot, ResidualMapsRoundTripAndMarkMaskedPixels) {
  ScopedTempDir dir;
  std::vector<StampPanels> exposures = {MakeStamp(21, 21, 1000, 500, 1), MakeStamp(15, 11, 0, 0, 2),
                                        MakeStamp(21, 21, 1001, 499, 3)};
  // Masked pixels: NaN, and an infinity the caller forgot to mask; both are written as NaN.
  for (Image* image : {&exposures[1].data, &exposures[1].residual, &exposures[1].normalised}) {
    (*image)(3, 4) = kNaN;
  }
  exposures[2].normalised(0, 0) = std::numeric_limits<double>::infinity();
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteResidualMaps(dir.path(), "residuals", exposures, &result, &error)) << error;
  ASSERT_EQ(result.data_paths.size(), 3u);
  EXPECT_EQ(result.data_paths[1], dir.File("residuals_001.dat"));
  for (size_t e = 0; e < exposures.size(); ++e) {
    const StampPanels& p = exposures[e];
    const std::vector<Block> blocks = ReadBlocks(result.data_paths[e]);
    ASSERT_EQ(blocks.size(), 1u);  // stamp rows are one blank line apart: one gnuplot block
    ASSERT_EQ(blocks[0].size(), p.data.size());
    size_t row = 0;
    for (int y = 0; y < p.data.ny; ++y) {
      for (int x = 0; x < p.data.nx; ++x, ++row) {
        const std::vector<double>& v = blocks[0][row];
        ASSERT_EQ(v.size(), 6u);
        EXPECT_EQ(v[0], p.origin_x + x);
        EXPECT_EQ(v[1], p.origin_y + y);
        EXPECT_TRUE(SameValue(v[2], p.data(x, y)));
        EXPECT_TRUE(SameValue(v[3], p.model(x, y)));
        EXPECT_TRUE(SameValue(v[4], p.residual(x, y)));
        const double expected = std::isfinite(p.normalised(x, y)) ? p.normalised(x, y) : kNaN;
        EXPECT_TRUE(SameValue(v[5], expected)) << e << " " << x << " " << y;
      }
    }
  }
  const std::string header = ReadText(result.data_paths[0]).substr(0, 400);
  EXPECT_NE(header.find("data [e-]"), std::string::npos) << header;
  // 4 panels of ~250 px across, 3 rows.
  ExpectPng(result, 1200, 2000, 800, 1400);
  ExpectNoTemporaries(dir);
}

TEST(Plot, ResidualMapsRejectBadInput) {
  ScopedTempDir dir;
  std::string error;
  EXPECT_FALSE(WriteResidualMaps(dir.path(), "maps", {}, nullptr, &error));
  ExpectOneLineError(error);
  StampPanels p = MakeStamp(9, 9, 0, 0, 1);
  p.model = Image(9, 8);
  error.clear();
  EXPECT_FALSE(WriteResidualMaps(dir.path(), "maps", {p}, nullptr, &error));
  ExpectOneLineError(error);
  p = MakeStamp(9, 9, 0, 0, 1);
  p.residual.data.pop_back();
  error.clear();
  EXPECT_FALSE(WriteResidualMaps(dir.path(), "maps", {p}, nullptr, &error));
  ExpectOneLineError(error);
  p = MakeStamp(9, 9, 0, 0, 1);
  p.data = p.model = p.residual = p.normalised = Image();
  error.clear();
  EXPECT_FALSE(WriteResidualMaps(dir.path(), "maps", {p}, nullptr, &error));
  ExpectOneLineError(error);
  error.clear();
  EXPECT_FALSE(
      WriteResidualMaps(dir.path(), "a/maps", {MakeStamp(9, 9, 0, 0, 1)}, nullptr, &error));
  ExpectOneLineError(error);
  EXPECT_TRUE(dir.List().empty());
}

// ---------------------------------------------------------------------------------------------

XyPlotInput MakeXyInput() {
  XyPlotInput in;
  in.title = "FWHM vs wavelength (it's @x {a}_b)";
  in.x_label = "wavelength [nm]";
  in.y_label = "FWHM [um]";
  Series x;
  x.label = "FWHM_x";
  x.x = {600, 700, 800, 890};
  x.y = {8.1, 7.7, 7.3, 7.0};
  x.y_lo = {7.9, 7.5, 7.1, 6.7};
  x.y_hi = {8.3, 7.9, 7.5, 7.2};
  in.series.push_back(x);
  Series y;
  y.label = "FWHM_y";
  y.x = {600, 700, 800, 890};
  y.y = {8.6, 8.2, 7.9, 7.6};
  in.series.push_back(y);
  Curve curve;
  curve.label = "a lambda^alpha";
  for (double l = 580; l <= 910; l += 10) {
    curve.x.push_back(l);
    curve.y.push_back(8.1 * std::pow(l / 600.0, -0.272));
  }
  in.curves.push_back(curve);
  in.requirements.push_back({"FWHM <= 10.8 um", 10.8});
  return in;
}

TEST(Plot, XyPlotRoundTripsSeriesCurvesAndRequirements) {
  ScopedTempDir dir;
  const XyPlotInput in = MakeXyInput();
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "fwhm", in, &result, &error)) << error;
  const std::vector<Block> series = ReadBlocks(dir.File("fwhm_series.dat"));
  ASSERT_EQ(series.size(), 2u);
  for (size_t k = 0; k < 2; ++k) {
    const Series& s = in.series[k];
    ASSERT_EQ(series[k].size(), s.x.size());
    for (size_t i = 0; i < s.x.size(); ++i) {
      EXPECT_EQ(series[k][i][0], s.x[i]);
      EXPECT_EQ(series[k][i][1], s.y[i]);
      EXPECT_EQ(series[k][i][2], s.y_lo.empty() ? s.y[i] : s.y_lo[i]);
      EXPECT_EQ(series[k][i][3], s.y_hi.empty() ? s.y[i] : s.y_hi[i]);
    }
  }
  const std::vector<Block> curves = ReadBlocks(dir.File("fwhm_curves.dat"));
  ASSERT_EQ(curves.size(), 1u);
  ASSERT_EQ(curves[0].size(), in.curves[0].x.size());
  for (size_t i = 0; i < curves[0].size(); ++i) {
    EXPECT_EQ(curves[0][i][0], in.curves[0].x[i]);
    EXPECT_EQ(curves[0][i][1], in.curves[0].y[i]);
  }
  const std::string script = ReadText(result.script_path);
  EXPECT_NE(script.find("'FWHM <= 10.8 um'"), std::string::npos);
  EXPECT_NE(script.find("first 10.8"), std::string::npos);
  EXPECT_NE(script.find("'FWHM vs wavelength (it''s @x {a}_b)'"), std::string::npos);
  ExpectPng(result, 600, 1400, 400, 900);
  ExpectNoTemporaries(dir);
}

TEST(Plot, XyPlotOnLogAxesAllowsLowerBoundsBelowZero) {
  ScopedTempDir dir;
  XyPlotInput in = MakeXyInput();
  in.log_x = in.log_y = true;
  in.series[0].y_lo[0] = -1.0;  // a bar that reaches below zero on a log axis
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "fwhm_log", in, &result, &error)) << error;
  ExpectPng(result, 600, 1400, 400, 900);
  EXPECT_TRUE(result.message.empty() || !result.image_written) << result.message;
}

// The y range the script sets: "set yrange [lo:hi]".
std::pair<double, double> ScriptYRange(const std::string& script) {
  const size_t at = script.find("set yrange [");
  if (at == std::string::npos) return {kNaN, kNaN};
  const char* p = script.c_str() + at + std::strlen("set yrange [");
  char* end = nullptr;
  const double lo = std::strtod(p, &end);
  const double hi = std::strtod(end + 1, nullptr);
  return {lo, hi};
}

// Upper limits: a block per series that has them (a series may have only limits), each arrow
// pointing down by 4 % of the plotted y range (of its logarithm on a log axis), inside the plot.
TEST(Plot, XyPlotDrawsUpperLimitsAsDownwardArrows) {
  for (const bool log_y : {false, true}) {
    ScopedTempDir dir;
    XyPlotInput in = MakeXyInput();
    in.log_y = log_y;
    in.series[0].limit_x = {650.0};
    in.series[0].limit_y = {6.2};  // the lowest value drawn: its arrow must stay inside
    in.series[0].limit_label = "FWHM_x: upper limit";
    Series only_limits;
    only_limits.label = "FWHM (bound only)";
    only_limits.limit_x = {750.0, 850.0};
    only_limits.limit_y = {8.0, 9.5};
    in.series.push_back(only_limits);
    PlotResult result;
    std::string error;
    ASSERT_TRUE(WriteXyPlot(dir.path(), "lim", in, &result, &error)) << error;
    // The points file has blocks only for the two series with points.
    EXPECT_EQ(ReadBlocks(dir.File("lim_series.dat")).size(), 2u);
    const std::vector<Block> limits = ReadBlocks(dir.File("lim_limits.dat"));
    ASSERT_EQ(limits.size(), 2u);
    const std::string script = ReadText(result.script_path);
    const auto [lo, hi] = ScriptYRange(script);
    ASSERT_TRUE(lo < 6.2 && hi > 9.5) << lo << " " << hi;
    const std::vector<const Series*> owners = {&in.series[0], &in.series[2]};
    for (size_t b = 0; b < 2; ++b) {
      ASSERT_EQ(limits[b].size(), owners[b]->limit_x.size());
      for (size_t i = 0; i < limits[b].size(); ++i) {
        const double y = owners[b]->limit_y[i];
        EXPECT_EQ(limits[b][i][0], owners[b]->limit_x[i]);
        EXPECT_EQ(limits[b][i][1], y);
        // Closed forms; 1e-6 relative covers the 10 significant digits of the script's range.
        const double expected = log_y ? y * (std::pow(lo / hi, 0.04) - 1.0) : -0.04 * (hi - lo);
        EXPECT_NEAR(limits[b][i][2], expected, 1e-6 * std::fabs(expected));
        EXPECT_GE(y + limits[b][i][2], lo);
      }
    }
    // Drawn in the owning series' line style (3 for the third series), with its key entry.
    EXPECT_NE(script.find("'lim_limits.dat' index 1 using 4:2:(0):3 with vectors"),
              std::string::npos);
    EXPECT_NE(script.find("ls 3 notitle"), std::string::npos);
    EXPECT_NE(script.find("'FWHM_x: upper limit'"), std::string::npos);
    ExpectPng(result, 600, 1400, 400, 900);
    EXPECT_TRUE(result.message.empty() || !result.image_written) << result.message;
  }
}

TEST(Plot, XyPlotRejectsBadInput) {
  ScopedTempDir dir;
  const XyPlotInput good = MakeXyInput();
  std::string error;
  auto rejects = [&](const XyPlotInput& in) {
    error.clear();
    const bool ok = WriteXyPlot(dir.path(), "xy", in, nullptr, &error);
    ExpectOneLineError(error);
    return !ok;
  };
  XyPlotInput in = good;
  in.series[0].y.pop_back();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.series[0].y_hi.clear();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.series[0].y_lo[1] = 8.0;  // above y = 7.7: an error size passed as a bound
  EXPECT_TRUE(rejects(in)) << error;
  in = good;
  in.series[1].x.clear();
  in.series[1].y.clear();
  EXPECT_TRUE(rejects(in));
  in = good;
  in.curves[0].y[3] = kNaN;
  EXPECT_TRUE(rejects(in));
  in = good;
  in.log_y = true;
  in.requirements[0].y = 0.0;
  EXPECT_TRUE(rejects(in));
  in = good;
  in.log_x = true;
  in.curves[0].x[0] = -5.0;
  EXPECT_TRUE(rejects(in));
  in = good;
  in.series[0].limit_x = {650.0, 700.0};
  in.series[0].limit_y = {6.0};
  EXPECT_TRUE(rejects(in));
  in = good;
  in.series[0].limit_x = {650.0};
  in.series[0].limit_y = {kNaN};
  EXPECT_TRUE(rejects(in));
  in = good;
  in.log_y = true;
  in.series[0].limit_x = {650.0};
  in.series[0].limit_y = {-1.0};
  EXPECT_TRUE(rejects(in));
  in = XyPlotInput();
  in.requirements.push_back({"only a line", 1.0});
  EXPECT_TRUE(rejects(in));
  EXPECT_TRUE(dir.List().empty());
}

// ---------------------------------------------------------------------------------------------
// Without a working gnuplot: data and script are still written, the PNG is reported missing.

// A picture not asked for (PlotOptions::draw false): data and script as always, gnuplot not
// run (a program that would fail is named, so running it would show in the message), no
// stale picture left, and the message says how to draw it.
TEST(Plot, PictureNotAskedForKeepsDataAndScript) {
  ScopedTempDir dir;
  std::ofstream(dir.File("fwhm.svg")) << "old picture";
  PlotOptions options;
  options.format = PlotFormat::kSvg;
  options.gnuplot_path = "/bin/false";
  options.draw = false;
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "fwhm", MakeXyInput(), &result, &error, options)) << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_NE(result.message.find("not drawn"), std::string::npos) << result.message;
  EXPECT_EQ(result.message.find("failed"), std::string::npos) << result.message;
  EXPECT_NE(result.message.find("gnuplot -e \"plot_format='svg'\" fwhm.gp"), std::string::npos)
      << result.message;
  EXPECT_TRUE(Exists(dir.File("fwhm.gp")));
  EXPECT_TRUE(Exists(dir.File("fwhm_series.dat")));
  EXPECT_FALSE(Exists(dir.File("fwhm.svg")));
}

TEST(Plot, MissingGnuplotStillWritesDataAndScript) {
  ScopedTempDir dir;
  PlotResult result;
  std::string error;
  // A PNG from an earlier, successful run must not survive as a picture of the new data.
  std::ofstream(dir.File("fwhm.png")) << "old picture";
  PlotOptions options;
  options.gnuplot_path = kMissingGnuplot;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "fwhm", MakeXyInput(), &result, &error, options)) << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_NE(result.message.find("not found"), std::string::npos) << result.message;
  EXPECT_NE(result.message.find("gnuplot fwhm.gp"), std::string::npos) << result.message;
  EXPECT_EQ(result.message.find('\n'), std::string::npos);
  EXPECT_TRUE(Exists(dir.File("fwhm.gp")));
  EXPECT_TRUE(Exists(dir.File("fwhm_series.dat")));
  EXPECT_TRUE(Exists(dir.File("fwhm_curves.dat")));
  EXPECT_FALSE(Exists(dir.File("fwhm.png")));

  // The same for the other two plots.
  ASSERT_TRUE(
      WriteCornerPlot(dir.path(), "corner", MakeCornerInput(2, 50, 1), &result, &error, options))
      << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_TRUE(Exists(dir.File("corner.gp")));
  ASSERT_TRUE(
      WriteResidualMaps(dir.path(), "maps", {MakeStamp(9, 9, 0, 0, 1)}, &result, &error, options))
      << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_TRUE(Exists(dir.File("maps.gp")));
  EXPECT_TRUE(Exists(dir.File("maps_000.dat")));
  ExpectNoTemporaries(dir);
}

TEST(Plot, EnvironmentVariableChoosesTheGnuplotProgram) {
  ScopedTempDir dir;
  ASSERT_EQ(::setenv("CCDPSF_GNUPLOT", kMissingGnuplot, 1), 0);
  PlotResult result;
  std::string error;
  const bool ok = WriteXyPlot(dir.path(), "xy", MakeXyInput(), &result, &error);
  const bool available = GnuplotAvailable();
  ::unsetenv("CCDPSF_GNUPLOT");
  ASSERT_TRUE(ok) << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_NE(result.message.find(kMissingGnuplot), std::string::npos) << result.message;
  EXPECT_FALSE(available);
}

TEST(Plot, FailingGnuplotIsReportedNotAnError) {
  const std::optional<std::string> false_program = internal::FindExecutable("false");
  if (!false_program) GTEST_SKIP() << "no 'false' program";
  ScopedTempDir dir;
  PlotOptions options;
  options.gnuplot_path = *false_program;  // runs, makes nothing, exits with status 1
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "xy", MakeXyInput(), &result, &error, options)) << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_NE(result.message.find("exit status 1"), std::string::npos) << result.message;
  EXPECT_FALSE(Exists(dir.File("xy.png")));
  ExpectNoTemporaries(dir);
}

TEST(Plot, HangingGnuplotIsStoppedAfterTheTimeLimit) {
  ScopedTempDir dir;
  // A stand-in that never finishes (exec, so that the process we kill is the sleeper).
  const std::string fake = dir.File("slow-gnuplot");
  std::ofstream(fake) << "#!/bin/sh\nexec sleep 30\n";
  ASSERT_EQ(::chmod(fake.c_str(), 0755), 0);
  PlotOptions options;
  options.gnuplot_path = fake;
  options.timeout_s = 0.3;
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.File("out"), "xy", MakeXyInput(), &result, &error, options)) << error;
  EXPECT_FALSE(result.image_written);
  EXPECT_NE(result.message.find("did not finish"), std::string::npos) << result.message;
}

TEST(Plot, ScriptRemakesThePngWhenRunByHandInItsFolder) {
  if (!GnuplotAvailable()) GTEST_SKIP() << "gnuplot is not installed";
  ScopedTempDir dir;
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteResidualMaps(dir.path(), "maps", {MakeStamp(21, 21, 0, 0, 4)}, &result, &error))
      << error;
  ASSERT_EQ(std::remove(result.image_path.c_str()), 0);
  // `cd DIR && gnuplot maps.gp`, with no outfile given: the script's default name is used.
  const std::optional<std::string> gnuplot = internal::FindExecutable("gnuplot");
  ASSERT_TRUE(gnuplot.has_value());
  const internal::SubprocessOutcome run =
      internal::RunSubprocess(*gnuplot, {"maps.gp"}, dir.path(), 60.0);
  ASSERT_TRUE(run.Succeeded()) << run.error << run.output;
  EXPECT_TRUE(ReadPngInfo(dir.File("maps.png")).valid);
  // The log-scale switch in the script works too.
  const internal::SubprocessOutcome log_run = internal::RunSubprocess(
      *gnuplot, {"-e", "data_log = 1; outfile = 'log.png'", "maps.gp"}, dir.path(), 60.0);
  ASSERT_TRUE(log_run.Succeeded()) << log_run.error << log_run.output;
  EXPECT_TRUE(ReadPngInfo(dir.File("log.png")).valid);
}

// Every number that follows `prefix` in `text` (e.g. the x of each "set arrow from first X").
std::vector<double> NumbersAfter(const std::string& text, const std::string& prefix) {
  std::vector<double> out;
  for (size_t at = text.find(prefix); at != std::string::npos; at = text.find(prefix, at + 1)) {
    out.push_back(std::strtod(text.c_str() + at + prefix.size(), nullptr));
  }
  return out;
}

// The quantile of `values` at level q, computed here on its own: the order statistic at
// rank q (n - 1), interpolated linearly to the next (the definition fit.json uses).
double QuantileOf(std::vector<double> values, double q) {
  const double rank = q * (values.size() - 1);
  const size_t below = static_cast<size_t>(rank);
  std::nth_element(values.begin(), values.begin() + below, values.end());
  const double low = values[below];
  if (below + 1 >= values.size()) return low;
  const double high = *std::min_element(values.begin() + below + 1, values.end());
  return low + (rank - below) * (high - low);
}

TEST(Plot, EachFormatWritesAFileWithItsExtensionAndMagicBytes) {
  CCDPSF_RELEASE_ONLY();  // gnuplot three times over; the plot writer runs sanitized in
  // Plot.CornerWritesDataScriptAndPng
  if (!GnuplotAvailable()) GTEST_SKIP() << "gnuplot is not installed";
  struct Case {
    PlotFormat format;
    const char* extension;
  };
  for (const Case& c : {Case{PlotFormat::kPng, ".png"}, Case{PlotFormat::kPdf, ".pdf"},
                        Case{PlotFormat::kSvg, ".svg"}}) {
    ScopedTempDir dir;
    PlotOptions options;
    options.format = c.format;
    PlotResult xy, corner, maps;
    std::string error;
    ASSERT_TRUE(WriteXyPlot(dir.path(), "xy", MakeXyInput(), &xy, &error, options)) << error;
    ASSERT_TRUE(
        WriteCornerPlot(dir.path(), "corner", MakeCornerInput(3, 500, 5), &corner, &error, options))
        << error;
    std::vector<StampPanels> panels(1);
    for (Image* image :
         {&panels[0].data, &panels[0].model, &panels[0].residual, &panels[0].normalised}) {
      *image = Image(8, 8);
      for (int q = 0; q < 64; ++q)
        image->data[q] = std::exp(-0.1 * ((q % 8 - 4) * (q % 8 - 4) + (q / 8 - 4) * (q / 8 - 4)));
    }
    ASSERT_TRUE(WriteResidualMaps(dir.path(), "maps", panels, &maps, &error, options)) << error;
    for (const PlotResult* r : {&xy, &corner, &maps}) {
      ASSERT_TRUE(r->image_written) << r->message;
      ASSERT_GE(r->image_path.size(), 4u);
      EXPECT_EQ(r->image_path.substr(r->image_path.size() - 4), c.extension);
      const std::string bytes = ReadText(r->image_path);
      if (c.format == PlotFormat::kPng) {
        EXPECT_EQ(bytes.compare(0, 8, std::string("\x89PNG\r\n\x1a\n", 8)), 0);
      } else if (c.format == PlotFormat::kPdf) {
        EXPECT_EQ(bytes.compare(0, 4, "%PDF"), 0);
      } else {
        EXPECT_TRUE(bytes.compare(0, 5, "<?xml") == 0 || bytes.compare(0, 4, "<svg") == 0)
            << bytes.substr(0, 40);
        EXPECT_NE(bytes.find("</svg>"), std::string::npos);
      }
    }
    // No file of another format is left under the same names.
    for (const std::string& name : dir.List()) {
      const size_t dot = name.rfind('.');
      const std::string ext = name.substr(dot);
      if (ext == ".png" || ext == ".pdf" || ext == ".svg") {
        EXPECT_EQ(ext, c.extension) << name;
      }
    }
  }
}

TEST(Plot, ParsePlotFormatAcceptsOnlyTheThreeNames) {
  PlotFormat f = PlotFormat::kPng;
  std::string error;
  EXPECT_TRUE(ParsePlotFormat("pdf", &f, &error));
  EXPECT_EQ(f, PlotFormat::kPdf);
  EXPECT_TRUE(ParsePlotFormat("svg", &f, &error));
  EXPECT_EQ(f, PlotFormat::kSvg);
  EXPECT_FALSE(ParsePlotFormat("PDF", &f, &error));
  ExpectOneLineError(error);
  EXPECT_NE(error.find("png, pdf or svg"), std::string::npos);
  EXPECT_FALSE(ParsePlotFormat("jpeg", &f, &error));
}

TEST(Plot, CornerDrawsTheSamplesQuantilesAndTitlesEachColumn) {
  ScopedTempDir dir;
  const int dim = 3, n = 3001;
  CornerPlotInput in = MakeCornerInput(dim, n, 99);
  // Skew parameter 2 so that the interval is asymmetric about the median.
  for (int i = 0; i < n; ++i) {
    double& v = in.samples[static_cast<size_t>(i) * dim + 2];
    v = std::exp(v - 20.0);
  }
  in.map.clear();
  in.laplace_covariance.clear();
  in.truth.clear();
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "q", in, &result, &error)) << error;
  const std::string script = ReadText(result.script_path);
  const std::vector<Block> summary = ReadBlocks(dir.File("q_summary.dat"));
  ASSERT_EQ(summary[0].size(), static_cast<size_t>(dim));
  const std::vector<double> arrows = NumbersAfter(script, "set arrow from first ");
  for (int k = 0; k < dim; ++k) {
    std::vector<double> column;
    for (int i = 0; i < n; ++i) column.push_back(in.samples[static_cast<size_t>(i) * dim + k]);
    const double q16 = QuantileOf(column, 0.158655), q50 = QuantileOf(column, 0.5),
                 q84 = QuantileOf(column, 0.841345);
    // Columns: index name map sd truth lo hi q16 q50 q84. The data are written to round-trip
    // exactly; 1e-12 relative allows only the last bit of the interpolation's rounding.
    ASSERT_EQ(summary[0][k].size(), 10u);
    EXPECT_NEAR(summary[0][k][7], q16, 1e-12 * std::fabs(q16));
    EXPECT_NEAR(summary[0][k][8], q50, 1e-12 * std::fabs(q50));
    EXPECT_NEAR(summary[0][k][9], q84, 1e-12 * std::fabs(q84));
    // A vertical line at each of the three on the histogram (no MAP, no truth: nothing else).
    for (double q : {q16, q50, q84}) {
      bool found = false;
      for (double a : arrows) found = found || std::fabs(a - q) <= 1e-12 * std::fabs(q);
      EXPECT_TRUE(found) << "no line at " << q << " for parameter " << k;
    }
  }
  EXPECT_EQ(arrows.size(), static_cast<size_t>(3 * dim));
  // The title over the third column: median +(q84 - q50) -(q50 - q16), two significant
  // digits of the smaller error.
  std::vector<double> third;
  for (int i = 0; i < n; ++i) third.push_back(in.samples[static_cast<size_t>(i) * dim + 2]);
  const double m = QuantileOf(third, 0.5), up = QuantileOf(third, 0.841345) - m,
               down = m - QuantileOf(third, 0.158655);
  const int decimals =
      std::max(0, 1 - static_cast<int>(std::floor(std::log10(std::min(up, down)))));
  char expected[128];
  std::snprintf(expected, sizeof(expected), "'%.*f +%.*f -%.*f'", decimals, m, decimals, up,
                decimals, down);
  EXPECT_NE(script.find(expected), std::string::npos) << expected;
}

TEST(Plot, CornerDrawsTruthOnlyWhenGiven) {
  ScopedTempDir dir;
  CornerPlotInput in = MakeCornerInput(2, 400, 3);
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "with", in, &result, &error)) << error;
  const std::string with = ReadText(result.script_path);
  in.truth.clear();
  ASSERT_TRUE(WriteCornerPlot(dir.path(), "without", in, &result, &error)) << error;
  const std::string without = ReadText(result.script_path);
  EXPECT_NE(with.find("title 'true value'"), std::string::npos);
  EXPECT_NE(with.find("nohead ls 5"), std::string::npos);
  EXPECT_EQ(without.find("title 'true value'"), std::string::npos);
  EXPECT_EQ(without.find("nohead ls 5"), std::string::npos);
}

TEST(Plot, XyPlotDodgesSeriesThatShareXAndKeepsTheTrueX) {
  ScopedTempDir dir;
  XyPlotInput in;
  in.title = "dodge";
  for (int k = 0; k < 3; ++k) {
    Series s;
    s.label = "series " + std::to_string(k);
    s.x = {600, 700, 800};
    s.y = {1.0 + k * 1e-3, 2.0, 3.0};
    s.y_lo = {0.9, 1.9, 2.9};
    s.y_hi = {1.1, 2.1, 3.1};
    in.series.push_back(s);
  }
  in.dodge_fraction = 0.01;
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "d", in, &result, &error)) << error;
  const std::string script = ReadText(result.script_path);
  // The undodged axis: the data's span (600..800 nm) with a 5 % margin on each side.
  const double x_lo = 600 - 0.05 * 200, x_hi = 800 + 0.05 * 200;
  const std::vector<Block> series = ReadBlocks(dir.File("d_series.dat"));
  ASSERT_EQ(series.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(series[k][i][0], in.series[k].x[i]);  // the true x is kept
      // Series k is drawn at x + (k - 1) f (x_hi - x_lo); 1e-9 relative: rounding only.
      const double expected = in.series[k].x[i] + (k - 1) * 0.01 * (x_hi - x_lo);
      EXPECT_NEAR(series[k][i][4], expected, 1e-9 * std::fabs(expected));
    }
    // Distinct drawn positions, apart by more than a point's half width (~0.5 % of the axis).
    EXPECT_GT(series[1][i][4] - series[0][i][4], 0.005 * (x_hi - x_lo));
    EXPECT_GT(series[2][i][4] - series[1][i][4], 0.005 * (x_hi - x_lo));
  }
  EXPECT_NE(script.find("using 5:2:3:4 with yerrorbars"), std::string::npos);
  // Without the option, drawn x = x.
  in.dodge_fraction = 0.0;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "n", in, &result, &error)) << error;
  for (const Block& b : ReadBlocks(dir.File("n_series.dat"))) {
    for (const auto& row : b) EXPECT_EQ(row[4], row[0]);
  }
  in.dodge_fraction = 0.5;
  EXPECT_FALSE(WriteXyPlot(dir.path(), "bad", in, &result, &error));
  ExpectOneLineError(error);
}

TEST(Plot, XyPlotWritesBandsAndTruthsOnlyWhenGiven) {
  ScopedTempDir dir;
  XyPlotInput in = MakeXyInput();
  in.curves[0].y_lo = in.curves[0].y;
  in.curves[0].y_hi = in.curves[0].y;
  for (size_t i = 0; i < in.curves[0].x.size(); ++i) {
    in.curves[0].y_lo[i] -= 0.1;
    in.curves[0].y_hi[i] += 0.2;
  }
  PlotResult result;
  std::string error;
  ASSERT_TRUE(WriteXyPlot(dir.path(), "b", in, &result, &error)) << error;
  EXPECT_FALSE(Exists(dir.File("b_truth.dat")));
  const std::vector<Block> curves = ReadBlocks(dir.File("b_curves.dat"));
  for (size_t i = 0; i < curves[0].size(); ++i) {
    EXPECT_EQ(curves[0][i][2], in.curves[0].y_lo[i]);
    EXPECT_EQ(curves[0][i][3], in.curves[0].y_hi[i]);
  }
  EXPECT_NE(ReadText(result.script_path).find("with filledcurves"), std::string::npos);
  Curve truth;
  truth.label = "truth: FWHM";
  truth.x = {600, 900};
  truth.y = {9.0, 8.0};
  in.truth.curves.push_back(truth);
  ASSERT_TRUE(WriteXyPlot(dir.path(), "t", in, &result, &error)) << error;
  const std::vector<Block> truths = ReadBlocks(dir.File("t_truth.dat"));
  ASSERT_EQ(truths.size(), 1u);
  EXPECT_EQ(truths[0][1][1], 8.0);
  EXPECT_NE(ReadText(result.script_path).find("'truth: FWHM'"), std::string::npos);
}

TEST(Plot, SubprocessReportsAMissingWorkingFolder) {
  const std::optional<std::string> true_program = internal::FindExecutable("true");
  if (!true_program) GTEST_SKIP() << "no 'true' program";
  const internal::SubprocessOutcome run =
      internal::RunSubprocess(*true_program, {}, "/nonexistent/ccdpsf-folder", 10.0);
  EXPECT_FALSE(run.started);
  EXPECT_NE(run.error.find("cannot enter folder"), std::string::npos) << run.error;
  EXPECT_TRUE(internal::RunSubprocess(*true_program, {}, ".", 10.0).Succeeded());
}

}  // namespace
}  // namespace ccdpsf
