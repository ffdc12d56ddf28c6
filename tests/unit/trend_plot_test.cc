// The trend report's plots: the relation's band against the closed-form uncertainty of a
// weighted straight-line fit, and the truth drawn only when given.
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "ccdpsf/trend/relations.h"
#include "ccdpsf/trend/trend_report.h"
#include "gtest/gtest.h"
#include "support/fits_fixtures.h"

namespace ccdpsf::trend {
namespace {

using test_support::ScopedTempDir;

// The numeric rows of a gnuplot data file's first block ('#' lines skipped).
std::vector<std::vector<double>> FirstBlock(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::vector<double>> rows;
  std::string line;
  int blank = 0;
  while (std::getline(in, line)) {
    if (line.empty()) {
      if (++blank >= 2 && !rows.empty()) break;
      continue;
    }
    if (line[0] == '#') continue;
    blank = 0;
    std::istringstream fields(line);
    std::vector<double> row;
    std::string token;
    while (fields >> token) row.push_back(std::strtod(token.c_str(), nullptr));
    rows.push_back(row);
  }
  return rows;
}

struct IntensityTrend {
  TrendResult result;
  std::vector<double> x, sd;
};

// One intensity relation of FWHM_x through five Gaussian points (median on a line, known sd).
IntensityTrend MakeTrend() {
  IntensityTrend s;
  s.x = {23000, 50000, 109000, 157800, 190000};
  s.sd = {0.05, 0.04, 0.03, 0.03, 0.06};
  std::vector<RelationPoint> points;
  for (size_t i = 0; i < s.x.size(); ++i) {
    const double y = 6.66 + 1.14e-5 * s.x[i] + (i % 2 ? 0.01 : -0.01);
    points.push_back(RelationPoint::FromGaussian("g" + std::to_string(i), s.x[i], y, s.sd[i]));
  }
  RelationOptions options;
  options.resamples = 4000;
  std::string error;
  auto fit = FitRelation(RelationKind::kLinear, points, options, &error);
  EXPECT_TRUE(fit.has_value()) << error;
  s.result.relations["fwhm_x_um_vs_intensity"] = *fit;
  s.result.intensity_wavelength_nm = 800.0;
  return s;
}

TEST(TrendPlot, BandHalfWidthIsTheWeightedFitsSdAtEachIntensity) {
  const IntensityTrend s = MakeTrend();
  ScopedTempDir dir;
  std::vector<std::string> warnings;
  std::string error;
  ASSERT_TRUE(WriteTrendReport(dir.path(), s.result, nlohmann::json::object(), &warnings, &error))
      << error;
  const std::vector<std::vector<double>> curve =
      FirstBlock(dir.File("fwhm_vs_intensity_curves.dat"));
  ASSERT_GE(curve.size(), 20u);
  // Closed form: y = c0 + c1 x with weights 1/sd^2 has Cov(c) = (A^T W A)^-1, so the sd of
  // the line at x is sqrt(C00 + 2 x C01 + x^2 C11).
  double s0 = 0, s1 = 0, s2 = 0;
  for (size_t i = 0; i < s.x.size(); ++i) {
    const double w = 1.0 / (s.sd[i] * s.sd[i]);
    s0 += w;
    s1 += w * s.x[i];
    s2 += w * s.x[i] * s.x[i];
  }
  const double det = s0 * s2 - s1 * s1;
  const double c00 = s2 / det, c01 = -s1 / det, c11 = s0 / det;
  for (const std::vector<double>& row : curve) {
    ASSERT_EQ(row.size(), 4u);
    const double x = row[0];
    const double sd = std::sqrt(c00 + 2 * x * c01 + x * x * c11);
    // Half the central 68.27 % interval of 4000 resampled lines: its Monte-Carlo error is
    // ~1.5 sd / sqrt(4000) = 2.4 % of sd per bound; 8 % is over three of those.
    EXPECT_NEAR(0.5 * (row[3] - row[2]), sd, 0.08 * sd) << "x = " << x;
    EXPECT_LE(row[2], row[1]);
    EXPECT_GE(row[3], row[1]);
  }
  EXPECT_FALSE(std::ifstream(dir.File("fwhm_vs_intensity_truth.dat")).good());
}

TEST(TrendPlot, TruthRelationDrawnWhenGivenInTheTrendsFrame) {
  const IntensityTrend s = MakeTrend();
  ScopedTempDir dir;
  TrendReportOptions options;
  options.truth = TruthFile{"truth.json", nlohmann::json::parse(R"({"relations": {
      "fwhm_x_um_vs_intensity": {"intercept": 6.66, "slope": 1.14e-05},
      "reference_intensity_e": 157800.0, "reference_wavelength_nm": 800.0}})")};
  std::vector<std::string> warnings;
  std::string error;
  ASSERT_TRUE(
      WriteTrendReport(dir.path(), s.result, nlohmann::json::object(), &warnings, &error, options))
      << error;
  const std::vector<std::vector<double>> truth =
      FirstBlock(dir.File("fwhm_vs_intensity_truth.dat"));
  ASSERT_FALSE(truth.empty());
  for (const std::vector<double>& row : truth) {
    EXPECT_NEAR(row[1], 6.66 + 1.14e-5 * row[0], 1e-12);
  }
  std::ifstream md(dir.File("report.md"));
  std::stringstream text;
  text << md.rdbuf();
  EXPECT_NE(text.str().find("true values from truth.json"), std::string::npos);
  // The truth's intensity relation holds at its reference wavelength: at another, none.
  TrendResult other = s.result;
  other.intensity_wavelength_nm = 700.0;
  ScopedTempDir dir2;
  ASSERT_TRUE(
      WriteTrendReport(dir2.path(), other, nlohmann::json::object(), &warnings, &error, options))
      << error;
  EXPECT_FALSE(std::ifstream(dir2.File("fwhm_vs_intensity_truth.dat")).good());
}

}  // namespace
}  // namespace ccdpsf::trend
