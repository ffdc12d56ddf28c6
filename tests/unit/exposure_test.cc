// Tests of exposure calibration (exposure.h): keyword / option precedence, bias and read
// noise estimates, spot finding, masking, stamp placement and every bad-input path.
//
// Frames are synthetic (tests/support/fits_fixtures.h): a pixel-integrated Gaussian spot of
// known flux and position, Poisson and read noise, a known bias and gain, rounded to whole ADU.
// Expected values are the ones put into the frames; tolerances are derived from the sampling
// error of each estimator. All random streams have fixed seeds.
#include "ccdpsf/exposure.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "support/fits_fixtures.h"

namespace ccdpsf {
namespace {

using test_support::ScopedTempDir;
using test_support::SyntheticFrame;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Standard deviation of one pixel of the default synthetic frame's background [ADU]: read
// noise 4.5 e- at 3.1 e-/ADU, plus the 1/12 ADU^2 of rounding.
double BackgroundSigmaAdu(const SyntheticFrame& spec) {
  const double rn_adu = spec.read_noise_e / spec.gain_e_per_adu;
  return std::sqrt(rn_adu * rn_adu + 1.0 / 12.0);
}

FitsImage AsFitsImage(const Image& pixels, const FitsHeader& header) {
  FitsImage image;
  image.pixels = pixels;
  image.header = header;
  image.bitpix = 16;
  return image;
}

// Calibrates and expects success.
Exposure Calibrate(const Image& pixels, const FitsHeader& header,
                   const CalibrationOptions& options = {}) {
  std::string error;
  std::optional<Exposure> exposure =
      CalibrateExposure(AsFitsImage(pixels, header), "frame.fits", options, &error);
  EXPECT_TRUE(exposure.has_value()) << error;
  return exposure.value_or(Exposure{});
}

// Calibrates, expects failure, and returns the error (checked to be one line that names the
// source).
std::string CalibrateError(const Image& pixels, const FitsHeader& header,
                           const CalibrationOptions& options = {}) {
  std::string error;
  EXPECT_FALSE(
      CalibrateExposure(AsFitsImage(pixels, header), "frame.fits", options, &error).has_value());
  EXPECT_EQ(error.rfind("'frame.fits': ", 0), 0u) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  return error;
}

std::string LoadError(const std::string& path) {
  std::string error;
  EXPECT_FALSE(LoadExposure(path, CalibrationOptions(), &error).has_value());
  EXPECT_NE(error.find("'" + path + "'"), std::string::npos) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  return error;
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

const FitsHeader kGainHeader = {{"GAIN", 3.1, "e-/ADU"}};

// ------------------------------------------------------------------------------------------
// Bad input through LoadExposure: the reader's errors reach the caller unchanged.

TEST(Exposure, MissingFile) {
  ScopedTempDir dir;
  EXPECT_TRUE(Contains(LoadError(dir.File("absent.fits")), "no such file"));
}

TEST(Exposure, NotFits) {
  ScopedTempDir dir;
  const std::string path = dir.File("spot.fits");
  ASSERT_TRUE(test_support::WriteBytes(path, "GAIN = 3.1\n"));
  EXPECT_TRUE(Contains(LoadError(path), "is not a FITS file"));
}

TEST(Exposure, TruncatedFits) {
  ScopedTempDir dir;
  const std::string whole = dir.File("whole.fits");
  std::string error;
  ASSERT_TRUE(
      WriteFitsImageU16(whole, test_support::MakeSpotFrame(SyntheticFrame()), kGainHeader, &error))
      << error;
  const std::string bytes = test_support::ReadBytes(whole);
  const std::string cut = dir.File("cut.fits");
  ASSERT_TRUE(test_support::WriteBytes(cut, bytes.substr(0, bytes.size() / 2)));
  EXPECT_TRUE(Contains(LoadError(cut), "is truncated or corrupt"));
}

TEST(Exposure, EmptyImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("empty.fits");
  test_support::RawImageSpec spec;
  spec.bitpix = 16;
  spec.naxes = {64, 0};
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  EXPECT_TRUE(Contains(LoadError(path), "image is empty"));
  // And an in-memory frame without pixels.
  EXPECT_TRUE(Contains(CalibrateError(Image(), kGainHeader), "empty"));
}

TEST(Exposure, OneDimensionalImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("row.fits");
  test_support::RawImageSpec spec;
  spec.naxes = {64};
  spec.raw.assign(64, 1000.0);
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  EXPECT_TRUE(Contains(LoadError(path), "image is 1-D, expected 2-D"));
}

TEST(Exposure, ThreeDimensionalImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("cube.fits");
  test_support::RawImageSpec spec;
  spec.naxes = {16, 16, 3};
  spec.raw.assign(16 * 16 * 3, 1000.0);
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  EXPECT_TRUE(Contains(LoadError(path), "image is 3-D, expected 2-D"));
}

TEST(Exposure, TableInsteadOfImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("table.fits");
  std::string error;
  ASSERT_TRUE(test_support::WriteTableOnlyFits(path, &error)) << error;
  EXPECT_TRUE(Contains(LoadError(path), "has no image (first extension is a table)"));
}

// ------------------------------------------------------------------------------------------
// Bad input to the calibration itself.

TEST(Exposure, SpotAtFrameEdge) {
  SyntheticFrame spec;
  spec.spot_x_px = 4.2;  // a 21 x 21 stamp needs 10 px on each side of the peak pixel
  spec.spot_y_px = 30.0;
  const std::string error = CalibrateError(test_support::MakeSpotFrame(spec), kGainHeader);
  EXPECT_TRUE(Contains(error, "too close to the frame edge for a 21x21 stamp")) << error;
  EXPECT_TRUE(Contains(error, "spot at (4.")) << error;

  // The same frame with a stamp that fits: 9 x 9 needs 4 px each side of pixel 4.
  CalibrationOptions small;
  small.stamp_size = 9;
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader, small);
  EXPECT_EQ(exposure.stamp.origin_x, 0);
}

TEST(Exposure, ConstantImageHasNoSpot) {
  const std::string error = CalibrateError(Image(64, 64, 1000.0), kGainHeader);
  EXPECT_TRUE(Contains(error, "no spot found")) << error;
}

TEST(Exposure, NoiseOnlyImageHasNoSpot) {
  SyntheticFrame spec;
  spec.flux_e = 0.0;
  spec.seed = 11;
  const std::string error = CalibrateError(test_support::MakeSpotFrame(spec), kGainHeader);
  EXPECT_TRUE(Contains(error, "no spot found")) << error;
  EXPECT_TRUE(Contains(error, "min_peak_snr")) << error;
}

TEST(Exposure, AllNanImage) {
  const std::string error = CalibrateError(Image(32, 32, kNaN), kGainHeader);
  EXPECT_TRUE(Contains(error, "no usable pixels")) << error;
}

TEST(Exposure, NoGain) {
  const std::string error = CalibrateError(test_support::MakeSpotFrame(SyntheticFrame()), {});
  EXPECT_EQ(error,
            "'frame.fits': no gain: give --gain_e_per_adu, a manifest column gain_e_per_adu or a "
            "GAIN keyword");
}

TEST(Exposure, NegativeOrZeroGain) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  EXPECT_TRUE(Contains(CalibrateError(frame, {{"GAIN", -3.1, ""}}), "gain must be positive"));
  EXPECT_TRUE(Contains(CalibrateError(frame, {{"GAIN", 0LL, ""}}), "gain must be positive"));
  EXPECT_TRUE(Contains(CalibrateError(frame, {{"GAIN", std::string("high"), ""}}),
                       "keyword GAIN (gain_e_per_adu) is not a finite number"));
  CalibrationOptions zero;
  zero.Set("gain_e_per_adu", 0.0);
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, zero),
                       "gain_e_per_adu must be positive and finite, got 0 (option)"));
  CalibrationOptions nan;
  nan.Set("gain_e_per_adu", kNaN);
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, nan), "gain_e_per_adu must be positive"));
}

TEST(Exposure, StampWhollyMasked) {
  // The frame is fine except for a NaN block; a spot position given inside that block puts
  // the whole stamp on masked pixels.
  Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  for (int y = 0; y < 64; ++y) {
    for (int x = 0; x < 28; ++x) frame(x, y) = kNaN;
  }
  CalibrationOptions options;
  options.Set("spot_x_px", 13.0);
  options.Set("spot_y_px", 30.0);
  const std::string error = CalibrateError(frame, kGainHeader, options);
  EXPECT_TRUE(Contains(error, "every pixel of the 21x21 stamp")) << error;
}

TEST(Exposure, MalformedBiassec) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  for (const char* section : {"[1:10;1:64]", "1:10,1:64", "[1:10]", "[a:b,1:64]", "[1:10,1:64",
                              "[1:2:1,1:64]", "[-1:10,1:64]", ""}) {
    FitsHeader header = kGainHeader;
    header.push_back({"BIASSEC", std::string(section), ""});
    const std::string error = CalibrateError(frame, header);
    EXPECT_TRUE(Contains(error, "bias section (keyword BIASSEC) '" + std::string(section) +
                                    "' is malformed"))
        << error;
  }
  // Not a string at all.
  FitsHeader header = kGainHeader;
  header.push_back({"BIASSEC", 5LL, ""});
  EXPECT_TRUE(Contains(CalibrateError(frame, header), "keyword BIASSEC (bias_section) is not a string"));
}

TEST(Exposure, BiassecOutsideFrame) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  for (const char* section : {"[1:10,1:65]", "[0:10,1:64]", "[60:70,1:64]"}) {
    FitsHeader header = kGainHeader;
    header.push_back({"BIASSEC", std::string(section), ""});
    const std::string error = CalibrateError(frame, header);
    EXPECT_TRUE(Contains(error, "bias section (keyword BIASSEC) '" + std::string(section) +
                                    "' is outside the 64x64 frame"))
        << error;
  }
}

TEST(Exposure, InvalidOptions) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  CalibrationOptions tiny;
  tiny.stamp_size = 4;
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, tiny), "stamp_size must be at least 5"));
  CalibrationOptions half_position;
  half_position.Set("spot_x_px", 30.0);
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, half_position), "give both"));
  CalibrationOptions outside;
  outside.Set("spot_x_px", 80.0);
  outside.Set("spot_y_px", 30.0);
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, outside), "outside the 64x64 frame"))
      << CalibrateError(frame, kGainHeader, outside);
  CalibrationOptions negative_noise;
  negative_noise.Set("read_noise_e", -1.0);
  EXPECT_TRUE(Contains(CalibrateError(frame, kGainHeader, negative_noise), "read_noise_e"));
}

// ------------------------------------------------------------------------------------------
// Bias and read noise.

// BIASLVL is taken as written (even when, as here, it differs from the true level by 0.55 ADU).
TEST(Exposure, BiasFromBiaslvl) {
  SyntheticFrame spec;
  spec.bias_adu = 1000.3;
  FitsHeader header = kGainHeader;
  header.push_back({"BIASLVL", 999.75, "ADU"});
  header.push_back({"BIASSEC", std::string("[1:10,1:64]"), ""});  // lower precedence
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), header);
  EXPECT_EQ(exposure.stamp.bias_adu, 999.75);
  EXPECT_EQ(exposure.report.Source("bias_adu"), "keyword BIASLVL");
  // The read noise still comes from the BIASSEC pixels.
  EXPECT_EQ(exposure.report.Source("read_noise_e"),
            "bias section [1:10,1:64] (" + std::to_string(exposure.report.noise_pixels) + " px)");
}

// The overscan columns 1-10 (IRAF, 1-based) are given a different level, 990.7 ADU, from the
// image area (1000.3 ADU), so the estimate shows which pixels were used. 640 pixels of
// sigma = 1.48 ADU give a clipped-mean standard error of 1.48 / sqrt(640) x 1.02 = 0.060 ADU
// (the 1.02: efficiency of a 3-sigma clipped mean); the tolerance is 5 of those.
TEST(Exposure, BiasFromBiassec) {
  SyntheticFrame spec;
  spec.bias_adu = 1000.3;
  Image frame = test_support::MakeSpotFrame(spec);
  SyntheticFrame overscan = spec;
  overscan.bias_adu = 990.7;
  overscan.flux_e = 0.0;
  overscan.seed = 99;
  const Image overscan_frame = test_support::MakeSpotFrame(overscan);
  for (int y = 0; y < spec.ny; ++y) {
    for (int x = 0; x < 10; ++x) frame(x, y) = overscan_frame(x, y);
  }
  FitsHeader header = kGainHeader;
  header.push_back({"BIASSEC", std::string(" [1:10, 1:64] "), ""});
  const Exposure exposure = Calibrate(frame, header);
  const double standard_error = BackgroundSigmaAdu(spec) / std::sqrt(640.0) * 1.02;
  EXPECT_NEAR(exposure.stamp.bias_adu, 990.7, 5.0 * standard_error);
  EXPECT_TRUE(Contains(exposure.report.Source("bias_adu"), "bias section"))
      << exposure.report.Source("bias_adu");
  // 3-sigma clipping drops ~0.3 % of Gaussian values: a handful of the 640.
  EXPECT_GE(exposure.report.noise_pixels, 625);
  EXPECT_LE(exposure.report.noise_pixels, 640);
}

// Without BIASLVL or BIASSEC: the sigma-clipped mean of the pixels outside a box of
// half-size 21 around the spot: 96^2 - 43^2 = 7367 pixels, standard error
// 1.48 / sqrt(7367) x 1.02 = 0.018 ADU; tolerance 5 standard errors.
TEST(Exposure, BiasFromBackground) {
  SyntheticFrame spec;
  spec.nx = spec.ny = 96;
  spec.spot_x_px = 47.6;
  spec.spot_y_px = 50.2;
  spec.bias_adu = 1000.3;
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader);
  const double standard_error = BackgroundSigmaAdu(spec) / std::sqrt(7367.0) * 1.02;
  EXPECT_NEAR(exposure.stamp.bias_adu, 1000.3, 5.0 * standard_error);
  EXPECT_TRUE(Contains(exposure.report.Source("bias_adu"), "sigma-clipped background"));
  EXPECT_GE(exposure.report.noise_pixels, 7300);
  EXPECT_LE(exposure.report.noise_pixels, 7367);
}

// A frame that is just a stamp (21 x 21): the background is the pixels at least 6 px from
// the peak, counted here independently; standard error 1.48 / sqrt(n) x 1.02 ~ 0.085 ADU.
TEST(Exposure, BiasFromBackgroundOfStampSizedFrame) {
  SyntheticFrame spec;
  spec.nx = spec.ny = 21;
  spec.spot_x_px = 10.2;
  spec.spot_y_px = 9.9;
  spec.bias_adu = 1000.3;
  int far_pixels = 0;
  for (int y = 0; y < 21; ++y) {
    for (int x = 0; x < 21; ++x) far_pixels += (x - 10) * (x - 10) + (y - 10) * (y - 10) >= 36;
  }
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader);
  EXPECT_EQ(exposure.stamp.origin_x, 0);
  EXPECT_EQ(exposure.stamp.origin_y, 0);
  EXPECT_LE(exposure.report.noise_pixels, far_pixels);
  EXPECT_GE(exposure.report.noise_pixels, far_pixels - 5);
  const double standard_error = BackgroundSigmaAdu(spec) / std::sqrt(far_pixels) * 1.02;
  EXPECT_NEAR(exposure.stamp.bias_adu, 1000.3, 5.0 * standard_error);
}

// The read noise from 128^2 - 43^2 = 14535 background pixels. The standard error of a
// standard deviation from n Gaussian values is sigma / sqrt(2n) (0.59 % here), ~1.1 times that
// after 3-sigma clipping, and removing the 1/12 ADU^2 rounding variance scales the relative
// error by var / (var - 1/12) = 1.04: 0.66 % or 0.030 e-. Clipping integer-valued data adds a
// systematic error of up to ~1 % (the clip bound falls between integers, so the truncation
// correction is approximate). Tolerance: 0.15 e- = 3.3 %, five standard errors.
TEST(Exposure, ReadNoiseFromBackground) {
  SyntheticFrame spec;
  spec.nx = spec.ny = 128;
  spec.spot_x_px = 60.4;
  spec.spot_y_px = 70.6;
  spec.seed = 5;
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader);
  EXPECT_NEAR(exposure.stamp.read_noise_e, spec.read_noise_e, 0.15);
  EXPECT_EQ(exposure.report.Source("read_noise_e"), exposure.report.Source("bias_adu"));
  // The measured rms (rounding included) is sqrt(RN^2 / g^2 + 1/12) = 1.480 ADU.
  EXPECT_NEAR(exposure.report.noise_rms_adu, BackgroundSigmaAdu(spec), 0.15 / spec.gain_e_per_adu);
}

TEST(Exposure, OptionsOverrideKeywords) {
  const Image frame = test_support::MakeSpotFrame(SyntheticFrame());
  const FitsHeader header = {{"GAIN", 3.1, ""},       {"RDNOISE", 4.5, ""},
                             {"BIASLVL", 1000.0, ""}, {"SATURATE", 65535.0, ""},
                             {"WAVELEN", 800.0, ""},  {"EXPTIME", 2.5, ""},
                             {"PIXSIZE", 12.0, ""},   {"FOCUSPOS", 1500.0, ""}};
  const Exposure from_keys = Calibrate(frame, header);
  EXPECT_EQ(from_keys.stamp.gain_e_per_adu, 3.1);
  EXPECT_EQ(from_keys.stamp.read_noise_e, 4.5);
  EXPECT_EQ(from_keys.stamp.bias_adu, 1000.0);
  EXPECT_EQ(from_keys.stamp.saturation_adu, 65535.0);
  EXPECT_EQ(from_keys.report.Source("gain_e_per_adu"), "keyword GAIN");
  EXPECT_EQ(from_keys.report.Source("read_noise_e"), "keyword RDNOISE");
  EXPECT_EQ(from_keys.report.Source("saturation_adu"), "keyword SATURATE");
  EXPECT_EQ(from_keys.stamp.info.wavelength_nm, 800.0);
  EXPECT_EQ(from_keys.stamp.info.exptime_s, 2.5);
  EXPECT_EQ(from_keys.stamp.info.pixel_um, 12.0);
  EXPECT_EQ(from_keys.stamp.info.focus_position_um, 1500.0);
  EXPECT_EQ(from_keys.stamp.info.source, "frame.fits");
  EXPECT_TRUE(std::isnan(from_keys.report.noise_rms_adu));  // nothing estimated

  CalibrationOptions options;
  options.Set("gain_e_per_adu", 2.0);
  options.Set("read_noise_e", 3.0);
  options.Set("bias_adu", 1001.0);
  options.Set("saturation_adu", 60000.0);
  options.Set("wavelength_nm", 700.0);
  options.Set("exptime_s", 1.0);
  options.Set("pixel_um", 10.0);
  options.Set("focus_position_um", -20.0);
  const Exposure from_options = Calibrate(frame, header, options);
  EXPECT_EQ(from_options.stamp.gain_e_per_adu, 2.0);
  EXPECT_EQ(from_options.stamp.read_noise_e, 3.0);
  EXPECT_EQ(from_options.stamp.bias_adu, 1001.0);
  EXPECT_EQ(from_options.stamp.saturation_adu, 60000.0);
  EXPECT_EQ(from_options.report.Source("gain_e_per_adu"), "option");
  EXPECT_EQ(from_options.report.Source("bias_adu"), "option");
  EXPECT_EQ(from_options.stamp.info.wavelength_nm, 700.0);
  EXPECT_EQ(from_options.stamp.info.exptime_s, 1.0);
  EXPECT_EQ(from_options.stamp.info.pixel_um, 10.0);
  EXPECT_EQ(from_options.stamp.info.focus_position_um, -20.0);

  // Without the keywords the metadata stay unknown, and the pixel size takes its default.
  const Exposure bare = Calibrate(frame, kGainHeader);
  EXPECT_TRUE(std::isnan(bare.stamp.info.wavelength_nm));
  EXPECT_TRUE(std::isnan(bare.stamp.info.focus_position_um));
  // Nothing physical is defaulted: without PIXSIZE or an option the pixel size is unknown.
  EXPECT_TRUE(std::isnan(bare.stamp.info.pixel_um));
  EXPECT_EQ(bare.report.Source("pixel_um"), "unknown");
  EXPECT_EQ(bare.report.Source("saturation_adu"), "unknown");
  EXPECT_TRUE(std::isinf(bare.stamp.saturation_adu));
}

// ------------------------------------------------------------------------------------------
// Spot finding, stamp and mask.

// The centroid error of a 5 x 5 first moment on this spot: photon noise
// sqrt((sigma^2 + 1/12) / N) = 0.002 px, read noise ~0.0002 px, the 5 x 5 truncation of a
// sigma = 0.8 px Gaussian whose centre is up to 0.5 px from the box centre (a shift of at most
// 0.8 x (phi(2.5) - phi(3.75)) / (Phi(2.5) - Phi(-3.75)) = 0.014 px toward the box centre), and
// pixelisation (the first moment of pixel integrals is E[round(X)], off from E[X] by
// ~ exp(-2 pi^2 sigma^2) / pi = 1e-6 px): well inside the required 0.05 px.
TEST(Exposure, FindsSpotCentroid) {
  SyntheticFrame spec;
  spec.nx = 80;
  spec.ny = 72;
  spec.spot_x_px = 40.37;
  spec.spot_y_px = 33.81;
  spec.seed = 3;
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader);
  EXPECT_NEAR(exposure.report.spot_x_px, spec.spot_x_px, 0.05);
  EXPECT_NEAR(exposure.report.spot_y_px, spec.spot_y_px, 0.05);
  EXPECT_EQ(exposure.report.spot_source, "found");
  EXPECT_GT(exposure.report.peak_snr, 100.0);
  // Peak pixel (40, 34) sits at the stamp centre index 10.
  EXPECT_EQ(exposure.report.peak_x_px, 40);
  EXPECT_EQ(exposure.report.peak_y_px, 34);
  EXPECT_EQ(exposure.stamp.origin_x, 30);
  EXPECT_EQ(exposure.stamp.origin_y, 24);
  EXPECT_EQ(exposure.stamp.nx(), 21);
  EXPECT_EQ(exposure.stamp.ny(), 21);
  EXPECT_EQ(exposure.stamp.NumValid(), 21 * 21);
  EXPECT_EQ(exposure.report.masked_pixels, 0);
  EXPECT_EQ(exposure.report.peak_adu, test_support::MakeSpotFrame(spec)(40, 34));

  // Every stamp pixel against the electrons put in: (adu - bias) x gain must match the
  // expected count within its noise, sqrt(expected + RN^2 + g^2 / 12) e- (photon, read and
  // rounding noise; the bias error, 0.02 ADU x 3.1 = 0.06 e-, is negligible). 441 pixels at
  // 5 sigma: a chance failure has probability 441 x 5.7e-7 = 2.5e-4.
  double sum_e = 0.0;
  const Stamp& stamp = exposure.stamp;
  for (int j = 0; j < stamp.ny(); ++j) {
    for (int i = 0; i < stamp.nx(); ++i) {
      const double expected =
          test_support::ExpectedElectrons(spec, stamp.origin_x + i, stamp.origin_y + j);
      const double sigma = std::sqrt(expected + spec.read_noise_e * spec.read_noise_e +
                                     spec.gain_e_per_adu * spec.gain_e_per_adu / 12.0);
      EXPECT_NEAR(stamp.electrons(i, j), expected, 5.0 * sigma) << i << ", " << j;
      sum_e += stamp.electrons(i, j);
    }
  }
  // The stamp holds the whole flux (the spot is 12 sigma from every edge): the sum's noise is
  // sqrt(2e5 + 441 x (4.5^2 + 3.1^2 / 12)) = 460 e-; tolerance 5 x that.
  EXPECT_NEAR(sum_e, spec.flux_e, 5.0 * 460.0);
}

TEST(Exposure, GivenPositionSkipsSpotFinding) {
  SyntheticFrame spec;
  spec.flux_e = 0.0;  // nothing to find: only the given position places the stamp
  CalibrationOptions options;
  options.Set("spot_x_px", 30.4);
  options.Set("spot_y_px", 20.6);
  const Exposure exposure = Calibrate(test_support::MakeSpotFrame(spec), kGainHeader, options);
  EXPECT_EQ(exposure.report.spot_source, "option");
  EXPECT_EQ(exposure.report.spot_x_px, 30.4);
  EXPECT_EQ(exposure.report.spot_y_px, 20.6);
  EXPECT_TRUE(std::isnan(exposure.report.peak_snr));
  EXPECT_EQ(exposure.stamp.origin_x, 30 - 10);
  EXPECT_EQ(exposure.stamp.origin_y, 21 - 10);
}

// Centre index c = (n - 1) / 2 = int(n / 2 - 0.5): 9 for a 20 x 20 stamp, 2 for 5 x 5.
TEST(Exposure, StampCentreConvention) {
  SyntheticFrame spec;
  spec.spot_x_px = 31.1;
  spec.spot_y_px = 29.9;
  const Image frame = test_support::MakeSpotFrame(spec);
  for (int size : {20, 5, 21}) {
    CalibrationOptions options;
    options.stamp_size = size;
    const Exposure exposure = Calibrate(frame, kGainHeader, options);
    const int c = static_cast<int>(size / 2.0 - 0.5);
    EXPECT_EQ(exposure.stamp.nx(), size);
    EXPECT_EQ(exposure.stamp.origin_x, 31 - c) << size;
    EXPECT_EQ(exposure.stamp.origin_y, 30 - c) << size;
  }
}

// A bright spot clipped at 65535 ADU by the converter, with SATURATE = 65535: exactly the
// clipped pixels (counted here from the frame) are censored (valid, "at or above" the
// level, holding the level in electrons), the NaN one is masked, and the verdict names the
// saturated core.
TEST(Exposure, SaturatedPixelsAreCensoredAndNonFiniteOnesMasked) {
  SyntheticFrame spec;
  spec.flux_e = 2.0e6;  // peak ~ 4e5 e- = 1.3e5 ADU
  spec.spot_x_px = 32.2;
  spec.spot_y_px = 31.7;
  Image frame = test_support::MakeSpotFrame(spec);
  int saturated = 0;
  for (double& v : frame.data) {
    if (v >= 65535.0) {
      v = 65535.0;
      ++saturated;
    }
  }
  ASSERT_GE(saturated, 2);
  frame(36, 28) = kNaN;  // inside any stamp around the spot
  FitsHeader header = kGainHeader;
  header.push_back({"SATURATE", 65535LL, "ADU"});

  const Exposure exposure = Calibrate(frame, header);
  const Stamp& stamp = exposure.stamp;
  EXPECT_LE(std::abs(stamp.origin_x + 10 - 32), 1);
  EXPECT_LE(std::abs(stamp.origin_y + 10 - 32), 1);
  int expected_censored = 0;
  for (int j = 0; j < stamp.ny(); ++j) {
    for (int i = 0; i < stamp.nx(); ++i) {
      const size_t q = static_cast<size_t>(j) * stamp.nx() + i;
      const double adu = frame(stamp.origin_x + i, stamp.origin_y + j);
      if (!std::isfinite(adu)) {
        EXPECT_EQ(stamp.valid[q], 0) << i << ", " << j;
        continue;
      }
      EXPECT_EQ(stamp.valid[q], 1) << i << ", " << j;
      const bool censored = adu >= 65535.0;
      expected_censored += censored;
      EXPECT_EQ(stamp.CensorAt(q), censored ? Censor::kAtOrAbove : Censor::kNone) << i << ", " << j;
      if (censored) {
        // The censoring level in electrons: (SATURATE - bias) x gain.
        EXPECT_NEAR(stamp.electrons.data[q], (65535.0 - stamp.bias_adu) * 3.1, 1e-6);
      }
    }
  }
  EXPECT_EQ(expected_censored, saturated);
  EXPECT_EQ(exposure.report.censored_high, saturated);
  EXPECT_EQ(exposure.report.masked_pixels, 1);
  EXPECT_TRUE(exposure.report.quality.Has("saturated_core"));
  EXPECT_EQ(exposure.report.quality.Verdict(), "suspect");

  // A lower saturation option censors more.
  CalibrationOptions options;
  options.Set("saturation_adu", 30000.0);
  const Exposure stricter = Calibrate(frame, header, options);
  EXPECT_GT(stricter.report.censored_high, exposure.report.censored_high);
}

TEST(Exposure, LoadsWrittenFrame) {
  // The whole path a user takes: simulate-like U16 file with keywords, then LoadExposure.
  ScopedTempDir dir;
  const std::string path = dir.File("exposure_000.fits");
  SyntheticFrame spec;
  const FitsHeader header = {{"GAIN", 3.1, ""},
                             {"RDNOISE", 4.5, ""},
                             {"WAVELEN", 800.0, ""},
                             {"BIASSEC", std::string("[1:10,1:64]"), ""}};
  std::string error;
  ASSERT_TRUE(WriteFitsImageU16(path, test_support::MakeSpotFrame(spec), header, &error)) << error;
  const std::optional<Exposure> exposure = LoadExposure(path, CalibrationOptions(), &error);
  ASSERT_TRUE(exposure.has_value()) << error;
  EXPECT_EQ(exposure->stamp.info.source, path);
  EXPECT_EQ(exposure->stamp.info.wavelength_nm, 800.0);
  EXPECT_NEAR(exposure->report.spot_x_px, spec.spot_x_px, 0.05);
  EXPECT_NEAR(exposure->report.spot_y_px, spec.spot_y_px, 0.05);
}

// ------------------------------------------------------------------------------------------
// Building blocks.

TEST(Exposure, ParsesIrafSections) {
  std::string error;
  std::optional<PixelRegion> region = ParseIrafSection("[1:10,1:64]", 64, 64, &error);
  ASSERT_TRUE(region.has_value()) << error;
  EXPECT_EQ(region->x_begin, 0);
  EXPECT_EQ(region->x_end, 10);
  EXPECT_EQ(region->y_begin, 0);
  EXPECT_EQ(region->y_end, 64);

  region = ParseIrafSection(" [ 20 : 11 , * ] ", 64, 32, &error);  // reversed, whole axis
  ASSERT_TRUE(region.has_value()) << error;
  EXPECT_EQ(region->x_begin, 10);
  EXPECT_EQ(region->x_end, 20);
  EXPECT_EQ(region->y_begin, 0);
  EXPECT_EQ(region->y_end, 32);

  region = ParseIrafSection("[3,4]", 8, 8, &error);  // one pixel
  ASSERT_TRUE(region.has_value()) << error;
  EXPECT_EQ(region->x_begin, 2);
  EXPECT_EQ(region->x_end, 3);
  EXPECT_EQ(region->y_begin, 3);
  EXPECT_EQ(region->y_end, 4);

  EXPECT_FALSE(ParseIrafSection("[1:10,1:64,1:2]", 64, 64, &error).has_value());
  EXPECT_TRUE(Contains(error, "is malformed")) << error;
  EXPECT_FALSE(ParseIrafSection("[1:64,1:65]", 64, 64, &error).has_value());
  EXPECT_EQ(error, "'[1:64,1:65]' is outside the 64x64 frame");
}

// 200000 draws from N(5, 2^2) plus 1000 outliers at +60. The clipped mean's standard error
// is 2 / sqrt(2e5) = 0.0045; the clipped standard deviation's is 2 / sqrt(4e5) x 1.1 =
// 0.0035 (0.17 %). Tolerances of ~5 standard errors (0.02 and 0.017) are well below the
// 1.5 % (0.03) by which an uncorrected 3-sigma-clipped deviation would fall short, so the
// test shows the truncation correction at work.
TEST(Exposure, SigmaClippedStatsRecoverTheParentNormal) {
  std::mt19937_64 rng(2024);
  std::normal_distribution<double> normal(5.0, 2.0);
  std::vector<double> values;
  for (int i = 0; i < 200000; ++i) values.push_back(normal(rng));
  for (int i = 0; i < 1000; ++i) values.push_back(60.0);
  values.push_back(kNaN);  // ignored
  const std::optional<ClippedStats> stats = SigmaClippedStats(values, 3.0);
  ASSERT_TRUE(stats.has_value());
  EXPECT_NEAR(stats->mean, 5.0, 0.02);
  EXPECT_NEAR(stats->median, 5.0, 0.02);
  EXPECT_NEAR(stats->stddev, 2.0, 0.017);
  EXPECT_LT(stats->num_used, 200000);  // outliers and the far tails dropped
  EXPECT_GT(stats->num_used, 199000);

  EXPECT_FALSE(SigmaClippedStats({kNaN, kNaN}).has_value());
  const std::optional<ClippedStats> constant = SigmaClippedStats({3.0, 3.0, 3.0});
  ASSERT_TRUE(constant.has_value());
  EXPECT_EQ(constant->mean, 3.0);
  EXPECT_EQ(constant->stddev, 0.0);
}

}  // namespace
}  // namespace ccdpsf
