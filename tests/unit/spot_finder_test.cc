// Tests of spot selection (spot_finder.h), contamination before the fit (contamination.h)
// and the checks across a set of exposures (exposure_set.h), on synthetic frames with known
// content: a pixel-integrated Gaussian spot (tests/support/fits_fixtures.h) plus, drawn
// here, a bright arc, a second source, a hot column.
#include "ccdpsf/spot_finder.h"

#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "ccdpsf/contamination.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/exposure_set.h"
#include "gtest/gtest.h"
#include "support/fits_fixtures.h"

namespace ccdpsf {
namespace {

using test_support::SyntheticFrame;

const FitsHeader kHeader = {{"GAIN", 3.1, ""}, {"PIXSIZE", 12.0, ""}, {"RDNOISE", 4.5, ""}};

Exposure Calibrate(const Image& frame, const CalibrationOptions& options = {},
                   const FitsHeader& header = kHeader) {
  FitsImage image;
  image.pixels = frame;
  image.header = header;
  image.bitpix = 16;
  std::string error;
  std::optional<Exposure> e = CalibrateExposure(image, "f.fits", options, &error);
  EXPECT_TRUE(e) << error;
  return e.value_or(Exposure{});
}

// Adds a bright arc: a quarter circle of radius 20 px around (cx, cy), 1.5 px wide, peaking
// at `peak_adu` - brighter than the spot, as the caustics of a real bench frame are.
void AddArc(Image* frame, double cx, double cy, double peak_adu) {
  for (int y = 0; y < frame->ny; ++y) {
    for (int x = 0; x < frame->nx; ++x) {
      const double r = std::hypot(x - cx, y - cy);
      if (x < cx || y < cy) continue;
      (*frame)(x, y) += peak_adu * std::exp(-0.5 * std::pow((r - 20.0) / 1.5, 2));
    }
  }
}

TEST(SpotFinder, TheCompactSpotIsChosenNotTheBrighterArc) {
  SyntheticFrame spec;
  spec.nx = spec.ny = 96;
  spec.spot_x_px = 30.2;
  spec.spot_y_px = 60.4;
  spec.flux_e = 6.0e4;  // peak ~ 5000 ADU
  Image frame = test_support::MakeSpotFrame(spec);
  AddArc(&frame, 40.0, 20.0, 20000.0);
  const Exposure e = Calibrate(frame);
  EXPECT_EQ(e.report.peak_x_px, 30);
  EXPECT_EQ(e.report.peak_y_px, 60);
  EXPECT_TRUE(e.report.spot.compact && e.report.spot.isolated);
  // The arc's brightest points are candidates, reported as not compact (or not isolated).
  const SpotSearch& s = e.report.spot_search;
  ASSERT_GE(s.candidates.size(), 2u);
  EXPECT_GT(s.candidates[0].peak_adu, e.report.peak_adu);  // the most significant is the arc
  EXPECT_NE(s.candidates[0].note, "chosen");
  EXPECT_FALSE(s.candidates[0].compact && s.candidates[0].isolated);
  EXPECT_EQ(e.report.quality.Verdict(), "ok") << e.report.quality.OneLine();
}

TEST(SpotFinder, OnlyAnExtendedSourceIsAnInvalidVerdictNotASilentFit) {
  // A defocused pedestal: a flat disc of radius 6 px and nothing else.
  SyntheticFrame spec;
  spec.flux_e = 0.0;
  Image frame = test_support::MakeSpotFrame(spec);
  for (int y = 0; y < frame.ny; ++y) {
    for (int x = 0; x < frame.nx; ++x) {
      if (std::hypot(x - 32.0, y - 32.0) <= 6.0) frame(x, y) += 400.0;
    }
  }
  const Exposure e = Calibrate(frame);
  EXPECT_FALSE(e.report.spot.compact);
  EXPECT_TRUE(e.report.quality.Has("spot_not_compact"));
  EXPECT_EQ(e.report.quality.Verdict(), "invalid");
}

TEST(SpotFinder, SearchRegionAndGivenPositionSteerTheChoice) {
  // Two equal spots: the search region picks the one it holds; a given position is used as
  // it is, with its shape measured.
  SyntheticFrame spec;
  spec.nx = spec.ny = 96;
  spec.spot_x_px = 25.0;
  spec.spot_y_px = 25.0;
  Image frame = test_support::MakeSpotFrame(spec);
  spec.spot_x_px = 70.0;
  spec.spot_y_px = 70.0;
  spec.seed = 2;
  const Image second = test_support::MakeSpotFrame(spec);
  for (size_t i = 0; i < frame.size(); ++i) frame.data[i] += second.data[i] - spec.bias_adu;
  CalibrationOptions region;
  region.SetText("search_region", "[50:96,50:96]", "flag --search_region");
  const Exposure a = Calibrate(frame, region);
  EXPECT_EQ(a.report.peak_x_px, 70);
  EXPECT_EQ(a.report.Source("search_region"), "flag --search_region");
  CalibrationOptions given;
  given.Set("spot_x_px", 25.1);
  given.Set("spot_y_px", 24.9);
  const Exposure b = Calibrate(frame, given);
  EXPECT_EQ(b.report.peak_x_px, 25);
  EXPECT_EQ(b.report.spot.note, "given");
  EXPECT_TRUE(b.report.spot.compact);
  CalibrationOptions outside;
  outside.SetText("search_region", "[200:210,1:10]");
  FitsImage image;
  image.pixels = frame;
  image.header = kHeader;
  std::string error;
  EXPECT_FALSE(CalibrateExposure(image, "f.fits", outside, &error));
  EXPECT_NE(error.find("outside the 96x96 frame"), std::string::npos) << error;
}

TEST(Contamination, HotColumnIsMaskedInTheStamp) {
  SyntheticFrame spec;
  Image frame = test_support::MakeSpotFrame(spec);
  for (int y = 0; y < frame.ny; ++y) frame(35, y) += 130.0;  // 400 e- of dark current
  const Exposure e = Calibrate(frame);
  ASSERT_EQ(e.report.column_defects.size(), 1u);
  EXPECT_EQ(e.report.column_defects[0].x, 35);
  EXPECT_NEAR(e.report.column_defects[0].excess_adu, 130.0, 3.0);
  for (int j = 0; j < e.stamp.ny(); ++j) {
    EXPECT_EQ(e.stamp.valid[static_cast<size_t>(j) * e.stamp.nx() + (35 - e.stamp.origin_x)], 0);
  }
  EXPECT_TRUE(e.report.quality.Has("column_defect"));
  // A clean frame flags no column.
  EXPECT_TRUE(Calibrate(test_support::MakeSpotFrame(spec)).report.column_defects.empty());
}

TEST(Contamination, AnotherSourceIsMaskedBeyondTheCore) {
  SyntheticFrame spec;
  Image frame = test_support::MakeSpotFrame(spec);
  // A single-pixel cosmic ray 5 px from the spot's peak pixel (31, 31).
  frame(36, 31) += 3000.0;
  const Exposure e = Calibrate(frame);
  ASSERT_EQ(e.report.stamp_sources.size(), 1u);
  EXPECT_EQ(e.report.stamp_sources[0].x, 36);
  EXPECT_EQ(e.stamp.valid[static_cast<size_t>(31 - e.stamp.origin_y) * e.stamp.nx() +
                          (36 - e.stamp.origin_x)],
            0);
  // The spot itself keeps every core pixel.
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      EXPECT_EQ(e.stamp.valid[static_cast<size_t>(31 + dy - e.stamp.origin_y) * e.stamp.nx() +
                              (31 + dx - e.stamp.origin_x)],
                1);
    }
  }
  EXPECT_EQ(e.report.quality.Verdict(), "ok");  // far from the core: a note only
  // The spot's own smooth wings are never taken for sources (a bright, wide spot).
  spec.flux_e = 2.0e6;
  spec.sigma_px = 1.2;
  EXPECT_TRUE(Calibrate(test_support::MakeSpotFrame(spec)).report.stamp_sources.empty());
}

TEST(Contamination, ClippedBlackLevelRefusesToEstimateTheNoise) {
  SyntheticFrame spec;
  spec.bias_adu = 0.0;  // the camera's black level at the ADC's zero
  Image frame = test_support::MakeSpotFrame(spec);
  for (double& v : frame.data) v = std::max(0.0, v);
  FitsImage image;
  image.pixels = frame;
  image.header = {{"GAIN", 3.1, ""}};
  image.adc_min = 0.0;
  image.adc_max = 65535.0;
  std::string error;
  EXPECT_FALSE(CalibrateExposure(image, "f.fits", CalibrationOptions(), &error));
  EXPECT_NE(error.find("clipped there"), std::string::npos) << error;
  // Given the bias and read noise, the floor is detected and the dark pixels censored.
  CalibrationOptions options;
  options.Set("bias_adu", 0.0);
  options.Set("read_noise_e", 4.5);
  std::optional<Exposure> e = CalibrateExposure(image, "f.fits", options, &error);
  ASSERT_TRUE(e) << error;
  EXPECT_EQ(e->report.floor_adu, 0.0);
  EXPECT_GT(e->report.censored_low, 100);
}

TEST(Contamination, ABiasSectionOverTheSpotIsRefused) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  FitsImage image;
  image.pixels = frame;
  image.header = {{"GAIN", 3.1, ""}, {"BIASSEC", std::string("[20:45,1:64]"), ""}};
  std::string error;
  EXPECT_FALSE(CalibrateExposure(image, "f.fits", CalibrationOptions(), &error));
  EXPECT_NE(error.find("overlaps the spot's stamp"), std::string::npos) << error;
  // Away from the spot it is used.
  image.header.back() = {"BIASSEC", std::string("[1:8,1:64]"), ""};
  EXPECT_TRUE(CalibrateExposure(image, "f.fits", CalibrationOptions(), &error)) << error;
}

// A set whose peak stops growing with the signal: flagged from where it falls short.
TEST(ExposureSet, CompressionAcrossASeries) {
  std::vector<Exposure> exposures;
  const double fluxes[] = {1e4, 2e4, 3e4, 4e4, 6e4, 8e4};
  for (int k = 0; k < 6; ++k) {
    SyntheticFrame spec;
    spec.flux_e = fluxes[k];
    spec.seed = 50 + k;
    spec.sigma_px = 0.6;
    Image frame = test_support::MakeSpotFrame(spec);
    // Compress the peak pixel of the two brightest by 12 % and 20 %.
    if (k >= 4) frame(31, 31) = spec.bias_adu + (frame(31, 31) - spec.bias_adu) * (k == 4 ? 0.88 : 0.80);
    Exposure e = Calibrate(frame);
    e.stamp.info.exptime_s = fluxes[k] / 1e4;
    exposures.push_back(e);
  }
  Quality q;
  CheckPeakCompression(exposures, &q);
  ASSERT_EQ(q.findings.size(), 2u) << q.OneLine();
  EXPECT_EQ(q.findings[0].code, "compressed_peak");
  EXPECT_EQ(q.findings[0].exposure, 4);
  EXPECT_EQ(q.findings[1].exposure, 5);
  // The intensity scaled by exposure time: the shortfall against the peak line is stated
  // (12 % of the peak pixel, so about 12 % below the line; 3 % either way is noise and the
  // line's own fit).
  const std::string& message = q.findings[0].message;
  const size_t at = message.find("lies ");
  ASSERT_NE(at, std::string::npos) << message;
  EXPECT_NEAR(std::stod(message.substr(at + 5)), 12.0, 3.0) << message;
  // Equal exposure times (the lamp varied instead): no line against time is drawn.
  for (Exposure& e : exposures) e.stamp.info.exptime_s = 4.1;
  Quality same_time;
  CheckPeakCompression(exposures, &same_time);
  ASSERT_EQ(same_time.findings.size(), 2u) << same_time.OneLine();
  EXPECT_EQ(same_time.findings[0].message.find("exposure time"), std::string::npos)
      << same_time.findings[0].message;
  // Uncompressed, nothing is flagged.
  std::vector<Exposure> linear;
  for (int k = 0; k < 6; ++k) {
    SyntheticFrame spec;
    spec.flux_e = fluxes[k];
    spec.seed = 50 + k;
    spec.sigma_px = 0.6;
    linear.push_back(Calibrate(test_support::MakeSpotFrame(spec)));
  }
  Quality none;
  CheckPeakCompression(linear, &none);
  EXPECT_TRUE(none.findings.empty()) << none.OneLine();
  // A fit whose model holds brighter_fatter: the finding is a note that says so.
  Quality modelled;
  CheckPeakCompression(exposures, &modelled, "the model fits brighter_fatter");
  ASSERT_EQ(modelled.findings.size(), 2u) << modelled.OneLine();
  EXPECT_EQ(modelled.findings[0].severity, Severity::kNote);
  EXPECT_NE(modelled.findings[0].message.find("the model fits brighter_fatter"), std::string::npos);
}

// A through-focus series at two intensities: the bright exposures are wider because they are
// out of focus (sigma 0.6 -> 1.0 px), not compressed, and are compared only with exposures
// at their own focus position.
TEST(ExposureSet, NoCompressionAcrossFocusPositions) {
  std::vector<Exposure> exposures;
  const double fluxes[] = {1e4, 1.5e4, 2e4, 6e4, 7e4, 8e4};
  for (int k = 0; k < 6; ++k) {
    SyntheticFrame spec;
    spec.flux_e = fluxes[k];
    spec.seed = 70 + k;
    spec.sigma_px = k < 3 ? 0.6 : 1.0;
    Exposure e = Calibrate(test_support::MakeSpotFrame(spec));
    e.stamp.info.focus_position_um = k < 3 ? 300.0 : 400.0;
    exposures.push_back(e);
  }
  Quality q;
  CheckPeakCompression(exposures, &q);
  EXPECT_TRUE(q.findings.empty()) << q.OneLine();
  // Without the focus positions the wide bright ones are flagged (the check's reading).
  for (Exposure& e : exposures) e.stamp.info.focus_position_um = NAN;
  Quality unknown;
  CheckPeakCompression(exposures, &unknown);
  EXPECT_FALSE(unknown.findings.empty());
}

// A linear series whose spot falls anywhere in its pixel: the peak pixel's raw share changes
// by up to 1.6x with the sub-pixel position here, which the centring correction takes out.
TEST(ExposureSet, NoCompressionFromSubPixelPosition) {
  std::vector<Exposure> exposures;
  const double fluxes[] = {1e4, 2e4, 3e4, 4e4, 6e4, 8e4};
  // Faint ones centred, bright ones towards a corner and an edge (the worst case for a raw
  // share).
  const double offsets[][2] = {{0.02, -0.05}, {-0.04, 0.03}, {0.45, 0.44},
                               {-0.46, 0.1}, {0.3, -0.45}, {-0.44, -0.43}};
  for (int k = 0; k < 6; ++k) {
    SyntheticFrame spec;
    spec.flux_e = fluxes[k];
    spec.seed = 70 + k;
    spec.sigma_px = 0.6;
    spec.spot_x_px = 31 + offsets[k][0];
    spec.spot_y_px = 31 + offsets[k][1];
    exposures.push_back(Calibrate(test_support::MakeSpotFrame(spec)));
  }
  Quality q;
  CheckPeakCompression(exposures, &q);
  EXPECT_TRUE(q.findings.empty()) << q.OneLine();
}

TEST(ExposureSet, DuplicatesAndMixedWavelengthsAreRefused) {
  test_support::ScopedTempDir dir;
  SyntheticFrame spec;
  std::string error;
  FitsHeader header = kHeader;
  header.push_back({"WAVELEN", 800.0, ""});
  ASSERT_TRUE(WriteFitsImageU16(dir.File("a.fits"), test_support::MakeSpotFrame(spec), header, &error));
  ASSERT_TRUE(WriteFitsImageU16(dir.File("copy.fits"), test_support::MakeSpotFrame(spec), header, &error));
  spec.seed = 2;
  header.back() = {"WAVELEN", 600.0, ""};
  ASSERT_TRUE(WriteFitsImageU16(dir.File("b.fits"), test_support::MakeSpotFrame(spec), header, &error));
  ExposureSet set;
  auto input = [&](const std::string& name) { return InputFile{dir.File(name), "", {}}; };
  EXPECT_FALSE(LoadExposureSet({input("a.fits"), input("a.fits")}, {}, &set, &error));
  EXPECT_NE(error.find("given twice"), std::string::npos) << error;
  EXPECT_FALSE(LoadExposureSet({input("a.fits"), input("copy.fits")}, {}, &set, &error));
  EXPECT_NE(error.find("identical pixels"), std::string::npos) << error;
  EXPECT_FALSE(LoadExposureSet({input("a.fits"), input("b.fits")}, {}, &set, &error));
  EXPECT_NE(error.find("800 nm and 600 nm"), std::string::npos) << error;
  ExposureSetOptions mixed;
  mixed.allow_mixed_wavelengths = true;
  EXPECT_TRUE(LoadExposureSet({input("a.fits"), input("b.fits")}, mixed, &set, &error)) << error;
}

}  // namespace
}  // namespace ccdpsf
