// Tests of FITS reading and writing (fits_io.h) and of atomic writes (atomic_file.h).
//
// Files read by the reader tests are written directly with CFITSIO by the fixtures (not by
// the library's writers), and files written by the writer tests are read back directly with
// CFITSIO, so that neither half only checks itself. Every fixture lives in a fresh temporary
// folder.
#include "ccdpsf/fits_io.h"

#include <fitsio.h>
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <cmath>
#include <csignal>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "ccdpsf/atomic_file.h"
#include "support/fits_fixtures.h"

namespace ccdpsf {
namespace {

using test_support::RawImageSpec;
using test_support::ScopedTempDir;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Errors must be one line and name the file.
void ExpectOneLineNaming(const std::string& error, const std::string& path) {
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_NE(error.find("'" + path + "'"), std::string::npos) << error;
}

// Reads an image expected to fail and returns the error.
std::string ReadError(const std::string& path) {
  std::string error;
  EXPECT_FALSE(ReadFitsImage(path, &error).has_value());
  EXPECT_FALSE(error.empty());
  ExpectOneLineNaming(error, path);
  return error;
}

RawImageSpec Simple2d(int nx, int ny) {
  RawImageSpec spec;
  spec.bitpix = -64;
  spec.naxes = {nx, ny};
  for (int i = 0; i < nx * ny; ++i) spec.raw.push_back(i);
  return spec;
}

// Opens a file with CFITSIO for the checks of written files; closes it on destruction.
class CfitsioReader {
 public:
  explicit CfitsioReader(const std::string& path) {
    fits_open_diskfile(&file_, path.c_str(), READONLY, &status_);
    EXPECT_EQ(status_, 0) << "cannot open " << path;
  }
  ~CfitsioReader() {
    int status = 0;
    if (file_ != nullptr) fits_close_file(file_, &status);
  }
  fitsfile* get() { return file_; }
  int* status() { return &status_; }

  std::string KeyString(const char* name) {
    char value[FLEN_VALUE] = {0};
    fits_read_key(file_, TSTRING, name, value, nullptr, &status_);
    return value;
  }
  double KeyDouble(const char* name) {
    double value = kNaN;
    fits_read_key(file_, TDOUBLE, name, &value, nullptr, &status_);
    return value;
  }
  bool HasKey(const char* name) {
    char card[FLEN_CARD] = {0};
    int status = 0;
    fits_read_card(file_, name, card, &status);
    fits_clear_errmsg();
    return status == 0;
  }

 private:
  fitsfile* file_ = nullptr;
  int status_ = 0;
};

// ------------------------------------------------------------------------------------------
// Reading: bad input.

TEST(FitsIo, MissingFileIsReported) {
  ScopedTempDir dir;
  const std::string path = dir.File("absent.fits");
  const std::string error = ReadError(path);
  EXPECT_EQ(error, "cannot open '" + path + "': no such file");
}

TEST(FitsIo, DirectoryIsReported) {
  ScopedTempDir dir;
  const std::string error = ReadError(dir.path());
  EXPECT_NE(error.find("directory"), std::string::npos) << error;
}

TEST(FitsIo, NonFitsFileIsReported) {
  ScopedTempDir dir;
  const std::string text = dir.File("notes.fits");
  ASSERT_TRUE(test_support::WriteBytes(text, "this is a text file, not FITS\n"));
  EXPECT_EQ(ReadError(text), "'" + text + "' is not a FITS file");

  const std::string empty = dir.File("empty.fits");
  ASSERT_TRUE(test_support::WriteBytes(empty, ""));
  EXPECT_NE(ReadError(empty).find("is not a FITS file"), std::string::npos);
}

TEST(FitsIo, TruncatedHeaderIsReported) {
  ScopedTempDir dir;
  const std::string whole = dir.File("whole.fits");
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(whole, Simple2d(16, 16), &error)) << error;
  const std::string bytes = test_support::ReadBytes(whole);
  ASSERT_EQ(bytes.size(), 2u * 2880u);  // one header block, one data block

  // Cut inside the header block (no END card), and inside the first card.
  for (size_t keep : {size_t{1000}, size_t{5}}) {
    const std::string cut = dir.File("cut" + std::to_string(keep) + ".fits");
    ASSERT_TRUE(test_support::WriteBytes(cut, bytes.substr(0, keep)));
    EXPECT_NE(ReadError(cut).find("is truncated or corrupt"), std::string::npos) << keep;
  }
}

TEST(FitsIo, TruncatedDataIsReported) {
  ScopedTempDir dir;
  const std::string whole = dir.File("whole.fits");
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(whole, Simple2d(64, 64), &error)) << error;
  const std::string bytes = test_support::ReadBytes(whole);
  // Header, then only part of the 64 * 64 * 8 = 32768 data bytes.
  const std::string cut = dir.File("cut.fits");
  ASSERT_TRUE(test_support::WriteBytes(cut, bytes.substr(0, 2880 + 10000)));
  EXPECT_NE(ReadError(cut).find("is truncated or corrupt"), std::string::npos);
}

TEST(FitsIo, EmptyImageIsReported) {
  ScopedTempDir dir;
  std::string error;
  const std::string zero_axis = dir.File("zero_axis.fits");
  RawImageSpec spec;
  spec.bitpix = 16;
  spec.naxes = {0, 10};
  ASSERT_TRUE(test_support::WriteRawFits(zero_axis, spec, &error)) << error;
  EXPECT_NE(ReadError(zero_axis).find(": image is empty"), std::string::npos);

  // NAXIS = 0 and nothing after it: there is no image at all.
  const std::string no_axes = dir.File("no_axes.fits");
  spec.naxes = {};
  ASSERT_TRUE(test_support::WriteRawFits(no_axes, spec, &error)) << error;
  EXPECT_NE(ReadError(no_axes).find("has no image"), std::string::npos);
}

TEST(FitsIo, OneDimensionalImageIsReported) {
  ScopedTempDir dir;
  const std::string path = dir.File("spectrum.fits");
  RawImageSpec spec;
  spec.naxes = {50};
  spec.raw.assign(50, 1.0);
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  EXPECT_EQ(ReadError(path), "'" + path + "': image is 1-D, expected 2-D");
}

TEST(FitsIo, ThreeDimensionalImageIsReported) {
  ScopedTempDir dir;
  const std::string path = dir.File("cube.fits");
  RawImageSpec spec;
  spec.naxes = {8, 8, 2};
  spec.raw.assign(128, 1.0);
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  EXPECT_EQ(ReadError(path), "'" + path + "': image is 3-D, expected 2-D");
}

TEST(FitsIo, TableInsteadOfImageIsReported) {
  ScopedTempDir dir;
  const std::string path = dir.File("table.fits");
  std::string error;
  ASSERT_TRUE(test_support::WriteTableOnlyFits(path, &error)) << error;
  EXPECT_EQ(ReadError(path), "'" + path + "' has no image (first extension is a table)");
}

// ------------------------------------------------------------------------------------------
// Reading: good input.

TEST(FitsIo, ReadsImageFromFirstExtensionWhenPrimaryIsEmpty) {
  ScopedTempDir dir;
  const std::string path = dir.File("ext.fits");
  RawImageSpec spec = Simple2d(5, 3);
  spec.in_extension = true;
  spec.keys = {{"GAIN", 2.5, "e-/ADU"}};
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;

  const std::optional<FitsImage> image = ReadFitsImage(path, &error);
  ASSERT_TRUE(image.has_value()) << error;
  EXPECT_EQ(image->hdu, 2);
  EXPECT_EQ(image->pixels.nx, 5);
  EXPECT_EQ(image->pixels.ny, 3);
  // Row-major with x = NAXIS1: the stored sequence 0, 1, 2, ... fills rows first.
  EXPECT_EQ(image->pixels(4, 0), 4.0);
  EXPECT_EQ(image->pixels(0, 1), 5.0);
  EXPECT_EQ(image->pixels(4, 2), 14.0);
  EXPECT_EQ(FindString(image->header, "EXTNAME"), std::optional<std::string>("SCI"));
  EXPECT_EQ(FindNumber(image->header, "GAIN"), std::optional<double>(2.5));
}

// Every BITPIX with BSCALE/BZERO: the physical value is raw * BSCALE + BZERO (FITS standard
// 4.0, eq. 3), and BLANK (integers) or NaN (floats) becomes NaN. Expected values are computed
// here from the stored raw values; the scaling is one multiply-add in double precision in
// both places, so agreement is to the last bit (EXPECT_DOUBLE_EQ allows 4 ulp).
TEST(FitsIo, ReadsEveryBitpixWithScaling) {
  struct Case {
    int bitpix;
    std::vector<double> raw;  // 6 values; the last is replaced by BLANK / NaN
    double bscale;
    double bzero;
  };
  const std::vector<Case> cases = {
      {8, {0, 1, 127, 128, 255, 0}, 0.5, -10.0},
      {16, {-32768, -1, 0, 1, 32767, 0}, 2.0, 100.0},
      {32, {-2147483647.0, -5, 0, 7, 2147483647.0, 0}, 1e-3, 5.0},
      {64, {-9.0e15, -3, 0, 3, 9.0e15, 0}, 1.0, -1.0},
      {-32, {-1.5, 0.25, 0, 1.0e6 + 0.5, 3.0e38, 0}, 4.0, -1.0},
      {-64, {-0.1, 1.0 / 3.0, 0, 1e-300, 1e300, 0}, 1.0, 0.0},
      {-64, {-0.1, 1.0 / 3.0, 0, 2.5, -7.0, 0}, 2.0, 0.5},
  };
  ScopedTempDir dir;
  for (const Case& c : cases) {
    SCOPED_TRACE("BITPIX " + std::to_string(c.bitpix) + ", BSCALE " + std::to_string(c.bscale));
    RawImageSpec spec;
    spec.bitpix = c.bitpix;
    spec.naxes = {3, 2};
    spec.raw = c.raw;
    spec.bscale = c.bscale;
    spec.bzero = c.bzero;
    if (c.bitpix > 0) {
      // The stored null value: a raw value that occurs nowhere else.
      const long long blank = c.bitpix == 8 ? 200 : 12345;
      spec.blank = blank;
      spec.raw.back() = static_cast<double>(blank);
    } else {
      spec.raw.back() = kNaN;
    }
    const std::string path = dir.File("bitpix" + std::to_string(c.bitpix) + ".fits");
    std::string error;
    ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;

    const std::optional<FitsImage> image = ReadFitsImage(path, &error);
    ASSERT_TRUE(image.has_value()) << error;
    EXPECT_EQ(image->bitpix, c.bitpix);
    EXPECT_EQ(image->hdu, 1);
    ASSERT_EQ(image->pixels.size(), 6u);
    for (size_t i = 0; i + 1 < 6; ++i) {
      // -32 stores floats: the raw value is what a float holds.
      const double raw =
          c.bitpix == -32 ? static_cast<double>(static_cast<float>(c.raw[i])) : c.raw[i];
      EXPECT_DOUBLE_EQ(image->pixels.data[i], raw * c.bscale + c.bzero) << "pixel " << i;
    }
    EXPECT_TRUE(std::isnan(image->pixels.data[5]));
    // Scaling keywords are structural: applied, not passed on.
    EXPECT_FALSE(FindNumber(image->header, "BSCALE").has_value());
    EXPECT_FALSE(FindNumber(image->header, "BZERO").has_value());
    EXPECT_FALSE(FindNumber(image->header, "BLANK").has_value());
  }
}

TEST(FitsIo, HeaderHoldsUserKeywordsOnly) {
  ScopedTempDir dir;
  const std::string path = dir.File("keys.fits");
  RawImageSpec spec = Simple2d(4, 4);
  spec.bzero = 0.0;
  spec.keys = {{"GAIN", 3.1, "e-/ADU"},
               {"NREAD", 7LL, ""},
               {"OBJECT", std::string("pinhole 'A'"), ""},
               {"SHUTTER", true, ""},
               {"BIASSEC", std::string("[1:2,1:4]"), "overscan"}};
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(path, spec, &error)) << error;
  {  // Commentary cards, which the reader must skip.
    fitsfile* file = nullptr;
    int status = 0;
    fits_open_diskfile(&file, path.c_str(), READWRITE, &status);
    fits_write_comment(file, "a comment", &status);
    fits_write_history(file, "a history entry", &status);
    fits_close_file(file, &status);
    ASSERT_EQ(status, 0);
  }

  const std::optional<FitsImage> image = ReadFitsImage(path, &error);
  ASSERT_TRUE(image.has_value()) << error;
  std::vector<std::string> names;
  for (const FitsKey& key : image->header) names.push_back(key.name);
  EXPECT_EQ(names, (std::vector<std::string>{"GAIN", "NREAD", "OBJECT", "SHUTTER", "BIASSEC"}));

  const FitsHeader& header = image->header;
  EXPECT_EQ(std::get<double>(header[0].value), 3.1);
  EXPECT_EQ(header[0].comment, "e-/ADU");
  EXPECT_EQ(std::get<long long>(header[1].value), 7);
  EXPECT_EQ(std::get<std::string>(header[2].value), "pinhole 'A'");
  EXPECT_EQ(std::get<bool>(header[3].value), true);
  EXPECT_EQ(std::get<std::string>(header[4].value), "[1:2,1:4]");
}

TEST(FitsIo, FindNumberAndFindString) {
  const FitsHeader header = {{"GAIN", 3.1, ""},
                             {"NREAD", 7LL, ""},
                             {"WAVELEN", std::string(" 800.5 "), ""},
                             {"OBJECT", std::string("spot"), ""},
                             {"FLAG", true, ""},
                             {"GAIN", 9.9, "second copy"}};
  EXPECT_EQ(FindNumber(header, "gain"), std::optional<double>(3.1));  // first match, any case
  EXPECT_EQ(FindNumber(header, "NREAD"), std::optional<double>(7.0));
  EXPECT_EQ(FindNumber(header, "WAVELEN"), std::optional<double>(800.5));
  EXPECT_FALSE(FindNumber(header, "OBJECT").has_value());  // not numeric text
  EXPECT_FALSE(FindNumber(header, "FLAG").has_value());    // a logical is not a number
  EXPECT_FALSE(FindNumber(header, "ABSENT").has_value());
  EXPECT_EQ(FindString(header, "object"), std::optional<std::string>("spot"));
  EXPECT_FALSE(FindString(header, "GAIN").has_value());
  EXPECT_FALSE(FindString(header, "ABSENT").has_value());
}

TEST(FitsIo, FileNamesAreTakenLiterally) {
  // CFITSIO's extended syntax would read these as "extension 1 of run" and "clobber".
  ScopedTempDir dir;
  for (const std::string name : {"run[1].fits", "!bang.fits", "a+b(2).fits"}) {
    const std::string path = dir.File(name);
    Image image(3, 2, 7.0);
    std::string error;
    ASSERT_TRUE(WriteFitsImageF64(path, image, {}, &error)) << error;
    const std::optional<FitsImage> read = ReadFitsImage(path, &error);
    ASSERT_TRUE(read.has_value()) << error;
    EXPECT_EQ(read->pixels.data, image.data);
  }
  EXPECT_EQ(dir.List().size(), 3u);
}

// ------------------------------------------------------------------------------------------
// Writing.

TEST(FitsIo, U16RoundTripIsExact) {
  ScopedTempDir dir;
  const std::string path = dir.File("u16.fits");
  Image image(4, 2);
  image.data = {0, 1, 32767, 32768, 65534, 65535, 1000, 12345};
  const FitsHeader header = {{"GAIN", 3.1, "e-/ADU"}, {"RDNOISE", 4.5, "e-"},
                             {"EXPTIME", 2.5, "s"},   {"NEXP", 12LL, ""},
                             {"SHUTTER", false, ""},  {"BIASSEC", std::string("[1:2,1:2]"), ""}};
  std::string error;
  ASSERT_TRUE(WriteFitsImageU16(path, image, header, &error)) << error;
  EXPECT_EQ(dir.List(), std::vector<std::string>{"u16.fits"});  // no temporary left

  {  // The file as CFITSIO sees it: BITPIX 16 with BZERO 32768, raw = value - 32768.
    CfitsioReader reader(path);
    int bitpix = 0, equivalent = 0;
    fits_get_img_type(reader.get(), &bitpix, reader.status());
    fits_get_img_equivtype(reader.get(), &equivalent, reader.status());
    EXPECT_EQ(bitpix, 16);
    EXPECT_EQ(equivalent, USHORT_IMG);
    EXPECT_EQ(reader.KeyDouble("BZERO"), 32768.0);
    EXPECT_EQ(reader.KeyDouble("BSCALE"), 1.0);
    fits_set_bscale(reader.get(), 1.0, 0.0, reader.status());
    std::vector<short> raw(8);
    short null = 0;
    int any_null = 0;
    fits_read_img(reader.get(), TSHORT, 1, 8, &null, raw.data(), &any_null, reader.status());
    ASSERT_EQ(*reader.status(), 0);
    for (size_t i = 0; i < raw.size(); ++i) {
      EXPECT_EQ(raw[i], static_cast<int>(image.data[i]) - 32768) << i;
    }
  }

  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(read->bitpix, 16);
  EXPECT_EQ(read->pixels.nx, 4);
  EXPECT_EQ(read->pixels.ny, 2);
  EXPECT_EQ(read->pixels.data, image.data);  // exact
  ASSERT_EQ(read->header.size(), header.size());
  for (size_t i = 0; i < header.size(); ++i) {
    EXPECT_EQ(read->header[i].name, header[i].name);
    EXPECT_EQ(read->header[i].value, header[i].value) << header[i].name;
  }
}

TEST(FitsIo, U16RejectsValuesItCannotStore) {
  ScopedTempDir dir;
  const std::string path = dir.File("bad.fits");
  for (double bad : {70000.0, 65536.0, -1.0, 0.5, kNaN}) {
    Image image(3, 3, 100.0);
    image(2, 1) = bad;
    std::string error;
    EXPECT_FALSE(WriteFitsImageU16(path, image, {}, &error)) << bad;
    ExpectOneLineNaming(error, path);
    EXPECT_NE(error.find("pixel (2, 1)"), std::string::npos) << error;
    EXPECT_TRUE(dir.List().empty()) << "a failed write left a file behind";
  }
}

TEST(FitsIo, F64RoundTripIsExact) {
  ScopedTempDir dir;
  const std::string path = dir.File("f64.fits");
  Image image(3, 2);
  image.data = {0.1, -1.0 / 3.0, 1e-300, 1e300, M_PI, kNaN};
  std::string error;
  ASSERT_TRUE(WriteFitsImageF64(path, image, {{"SEED", 7LL, "rng seed"}}, &error)) << error;
  {
    CfitsioReader reader(path);
    int bitpix = 0;
    fits_get_img_type(reader.get(), &bitpix, reader.status());
    EXPECT_EQ(bitpix, -64);
    EXPECT_FALSE(reader.HasKey("BZERO"));
  }
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(read->bitpix, -64);
  for (size_t i = 0; i < 5; ++i) EXPECT_EQ(read->pixels.data[i], image.data[i]) << i;
  EXPECT_TRUE(std::isnan(read->pixels.data[5]));
  EXPECT_EQ(FindNumber(read->header, "SEED"), std::optional<double>(7.0));
}

TEST(FitsIo, KeywordDoublesKeepFifteenDigits) {
  ScopedTempDir dir;
  const std::string path = dir.File("digits.fits");
  const double value = 1.23456789012345e-7;  // 15 significant digits
  std::string error;
  ASSERT_TRUE(WriteFitsImageF64(path, Image(2, 2), {{"SMALL", value, ""}}, &error)) << error;
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  // 15 significant digits round-trip any 15-digit decimal exactly (DBL_DIG = 15).
  EXPECT_EQ(FindNumber(read->header, "SMALL"), std::optional<double>(value));
}

TEST(FitsIo, LongStringKeywordsRoundTrip) {
  // Longer than the 68 characters one card holds: written with CONTINUE cards.
  ScopedTempDir dir;
  const std::string path = dir.File("long.fits");
  const std::string long_text = std::string(150, 'x') + " it's the end";
  std::string error;
  ASSERT_TRUE(WriteFitsImageF64(
      path, Image(2, 2), {{"OPTIONS", long_text, "resolved options"}, {"AFTER", 1LL, ""}}, &error))
      << error;
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(FindString(read->header, "OPTIONS"), std::optional<std::string>(long_text));
  EXPECT_EQ(FindNumber(read->header, "AFTER"), std::optional<double>(1.0));
  ASSERT_EQ(read->header.size(), 2u);  // the CONTINUE cards are not keywords of their own
}

TEST(FitsIo, ImagesF64WritesNamedExtensions) {
  ScopedTempDir dir;
  const std::string path = dir.File("residuals.fits");
  Image data(3, 2, 5.0), model(3, 2, 4.5);
  std::string error;
  ASSERT_TRUE(WriteFitsImagesF64(path, {{"NEXP", 1LL, ""}},
                                 {{"DATA", data, {{"EXPOSURE", 0LL, ""}}}, {"MODEL", model, {}}},
                                 &error))
      << error;
  {
    CfitsioReader reader(path);
    int num_hdus = 0, type = 0, naxis = -1;
    fits_get_num_hdus(reader.get(), &num_hdus, reader.status());
    EXPECT_EQ(num_hdus, 3);
    fits_get_img_dim(reader.get(), &naxis, reader.status());
    EXPECT_EQ(naxis, 0);
    fits_movabs_hdu(reader.get(), 3, &type, reader.status());
    EXPECT_EQ(type, IMAGE_HDU);
    EXPECT_EQ(reader.KeyString("EXTNAME"), "MODEL");
    double values[6] = {0};
    double null = 0;
    int any_null = 0;
    fits_read_img(reader.get(), TDOUBLE, 1, 6, &null, values, &any_null, reader.status());
    for (double v : values) EXPECT_EQ(v, 4.5);
    EXPECT_EQ(*reader.status(), 0);
  }
  // The reader takes the first image extension.
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(read->hdu, 2);
  EXPECT_EQ(read->pixels.data, data.data);
  EXPECT_EQ(FindString(read->header, "EXTNAME"), std::optional<std::string>("DATA"));
  EXPECT_EQ(FindNumber(read->header, "EXPOSURE"), std::optional<double>(0.0));
}

TEST(FitsIo, TableRoundTrip) {
  ScopedTempDir dir;
  const std::string path = dir.File("chain.fits");
  const std::vector<FitsColumn> columns = {
      {"walker", "", {0, 1, 2, 3}, true, {}},
      {"step", "", {0, 0, 1, 1}, true, {}},
      {"log_prob", "", {-1.5, -2.25, -0.125, -1e-9}, false, {}},
      {"flux_e", "electron", {5.0e5, 5.1e5, 4.9e5, 0.1}, false, {}},
  };
  std::string error;
  ASSERT_TRUE(WriteFitsTable(path, {{"SEED", 7LL, ""}}, "CHAIN", columns,
                             {{"BURNIN", 1LL, "steps to discard"}}, &error))
      << error;

  CfitsioReader reader(path);
  EXPECT_DOUBLE_EQ(reader.KeyDouble("SEED"), 7.0);
  int type = 0;
  fits_movabs_hdu(reader.get(), 2, &type, reader.status());
  ASSERT_EQ(type, BINARY_TBL);
  EXPECT_EQ(reader.KeyString("EXTNAME"), "CHAIN");
  EXPECT_DOUBLE_EQ(reader.KeyDouble("BURNIN"), 1.0);  // the table's own keywords
  long num_rows = 0;
  int num_columns = 0;
  fits_get_num_rows(reader.get(), &num_rows, reader.status());
  fits_get_num_cols(reader.get(), &num_columns, reader.status());
  EXPECT_EQ(num_rows, 4);
  ASSERT_EQ(num_columns, 4);
  EXPECT_EQ(reader.KeyString("TTYPE1"), "walker");
  EXPECT_EQ(reader.KeyString("TFORM1"), "1K");
  EXPECT_EQ(reader.KeyString("TFORM3"), "1D");
  EXPECT_EQ(reader.KeyString("TUNIT4"), "electron");
  EXPECT_FALSE(reader.HasKey("TUNIT1"));  // no unit, no card
  ASSERT_EQ(*reader.status(), 0);

  std::vector<LONGLONG> walkers(4);
  fits_read_col(reader.get(), TLONGLONG, 1, 1, 1, 4, nullptr, walkers.data(), nullptr,
                reader.status());
  EXPECT_EQ(walkers, (std::vector<LONGLONG>{0, 1, 2, 3}));
  for (int column : {3, 4}) {
    std::vector<double> values(4);
    fits_read_col(reader.get(), TDOUBLE, column, 1, 1, 4, nullptr, values.data(), nullptr,
                  reader.status());
    EXPECT_EQ(values, columns[column - 1].values) << "column " << column;
  }
  EXPECT_EQ(*reader.status(), 0);
  // No CHECKSUM card: CFITSIO dates its comment, which would break byte-identical reruns.
  char value[FLEN_VALUE];
  int status = 0;
  fits_read_keyword(reader.get(), "CHECKSUM", value, nullptr, &status);
  EXPECT_EQ(status, KEY_NO_EXIST);
}

// Text columns: TFORM nA with n the longest text, each value NUL-padded (a NUL ends a FITS
// string: astropy's Table.read would keep CFITSIO's blank padding), numbers beside them intact.
TEST(FitsIo, TableTextColumnsRoundTrip) {
  ScopedTempDir dir;
  const std::string path = dir.File("texts.fits");
  FitsColumn verdict{"verdict", "", {}, false, {"ok", "suspect", ""}};
  FitsColumn spot{"spot", "", {0, 1, 2}, true, {}};
  FitsColumn fwhm{"fwhm_um", "um", {8.5, 9.25, -1e-3}, false, {}};
  std::string error;
  ASSERT_TRUE(WriteFitsTable(path, {}, "MAP", {spot, verdict, fwhm}, {}, &error)) << error;
  CfitsioReader reader(path);
  int type = 0;
  fits_movabs_hdu(reader.get(), 2, &type, reader.status());
  EXPECT_EQ(reader.KeyString("TFORM2"), "7A");  // "suspect"
  std::vector<char> row(8 + 7 + 8);
  for (int r = 0; r < 3; ++r) {
    fits_read_tblbytes(reader.get(), r + 1, 1, static_cast<LONGLONG>(row.size()),
                       reinterpret_cast<unsigned char*>(row.data()), reader.status());
    ASSERT_EQ(*reader.status(), 0);
    const std::string field(row.begin() + 8, row.begin() + 15);
    std::string expected = verdict.texts[r];
    expected.resize(7, '\0');
    EXPECT_EQ(field, expected) << "row " << r;
  }
  std::vector<double> values(3);
  fits_read_col(reader.get(), TDOUBLE, 3, 1, 1, 3, nullptr, values.data(), nullptr,
                reader.status());
  EXPECT_EQ(values, fwhm.values);
  std::vector<LONGLONG> spots(3);
  fits_read_col(reader.get(), TLONGLONG, 1, 1, 1, 3, nullptr, spots.data(), nullptr,
                reader.status());
  EXPECT_EQ(spots, (std::vector<LONGLONG>{0, 1, 2}));
  EXPECT_EQ(*reader.status(), 0);
  // Not ASCII: refused, not written.
  FitsColumn bad{"name", "", {}, false, {"caf\xc3\xa9"}};
  EXPECT_FALSE(WriteFitsTable(dir.File("bad.fits"), {}, "T", {bad}, {}, &error));
  ExpectOneLineNaming(error, dir.File("bad.fits"));
}

// A frame read a few rows at a time holds exactly the pixels read whole, with the same
// header, BITPIX, HDU and ADC range.
TEST(FitsIo, ImageStreamRowsEqualTheWholeImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("frame.fits");
  Image image(37, 23);
  for (size_t i = 0; i < image.data.size(); ++i) image.data[i] = (i * 7919) % 65536;
  std::string error;
  ASSERT_TRUE(WriteFitsImageU16(path, image, {{"WAVELEN", 800.0, "nm"}}, &error)) << error;
  const std::optional<FitsImage> whole = ReadFitsImage(path, &error);
  ASSERT_TRUE(whole) << error;
  std::unique_ptr<FitsImageStream> stream = FitsImageStream::Open(path, "", &error);
  ASSERT_TRUE(stream) << error;
  EXPECT_EQ(stream->nx(), 37);
  EXPECT_EQ(stream->ny(), 23);
  EXPECT_TRUE(stream->image().pixels.empty());
  EXPECT_EQ(stream->image().bitpix, whole->bitpix);
  EXPECT_EQ(stream->image().adc_max, whole->adc_max);
  EXPECT_EQ(FindNumber(stream->image().header, "WAVELEN"), std::optional<double>(800.0));
  std::vector<double> rows;
  for (int y = 0; y < 23; y += 5) {  // strips of 5 rows, the last of 3
    const int n = std::min(5, 23 - y);
    std::vector<double> strip(static_cast<size_t>(37) * n);
    ASSERT_TRUE(stream->ReadRows(y, n, strip.data(), &error)) << error;
    rows.insert(rows.end(), strip.begin(), strip.end());
  }
  EXPECT_EQ(rows, whole->pixels.data);
  std::vector<double> one(37);
  EXPECT_FALSE(stream->ReadRows(22, 2, one.data(), &error));  // past the last row
  ExpectOneLineNaming(error, path);
  EXPECT_FALSE(FitsImageStream::Open(dir.File("missing.fits"), "", &error));
  ExpectOneLineNaming(error, dir.File("missing.fits"));
}

TEST(FitsIo, TableRejectsInconsistentColumns) {
  ScopedTempDir dir;
  const std::string path = dir.File("bad_table.fits");
  std::string error;
  EXPECT_FALSE(WriteFitsTable(
      path, {}, "T", {{"a", "", {1, 2}, false, {}}, {"b", "", {1}, false, {}}}, {}, &error));
  ExpectOneLineNaming(error, path);
  EXPECT_FALSE(WriteFitsTable(
      path, {}, "T", {{"a", "", {1, 2}, false, {}}, {"A", "", {1, 2}, false, {}}}, {}, &error));
  EXPECT_FALSE(WriteFitsTable(path, {}, "T", {{"n", "", {1, kNaN}, true, {}}}, {}, &error));
  EXPECT_FALSE(WriteFitsTable(path, {}, "T", {}, {}, &error));
  // A name FITS readers treat unevenly (fitsverify warns on '.') is refused, not written.
  EXPECT_FALSE(WriteFitsTable(path, {}, "T", {{"x_px.0", "pix", {1, 2}, false, {}}}, {}, &error));
  EXPECT_NE(error.find("x_px.0"), std::string::npos) << error;
  EXPECT_TRUE(dir.List().empty());
}

TEST(FitsIo, FailedWriteLeavesNoFile) {
  ScopedTempDir dir;
  const Image image(4, 4, 1.0);
  std::string error;

  // A folder that does not exist.
  const std::string nowhere = dir.File("no_such_folder/out.fits");
  EXPECT_FALSE(WriteFitsImageF64(nowhere, image, {}, &error));
  ExpectOneLineNaming(error, nowhere);
  EXPECT_NE(error.find("does not exist"), std::string::npos) << error;
  EXPECT_FALSE(WriteFitsTable(nowhere, {}, "T", {{"a", "", {1.0}, false, {}}}, {}, &error));
  EXPECT_TRUE(dir.List().empty());

  // A value 16 bits cannot hold.
  const std::string target = dir.File("u16.fits");
  Image bad = image;
  bad(1, 1) = 70000.0;
  EXPECT_FALSE(WriteFitsImageU16(target, bad, {}, &error));

  // A keyword the writer sets itself is rejected before anything is written.
  EXPECT_FALSE(WriteFitsImageF64(target, image, {{"BZERO", 0.0, ""}}, &error));
  EXPECT_NE(error.find("BZERO"), std::string::npos) << error;
  // A keyword value FITS cannot represent.
  EXPECT_FALSE(WriteFitsImageF64(target, image, {{"GAIN", kNaN, ""}}, &error));
  EXPECT_TRUE(dir.List().empty());
}

TEST(FitsIo, WriterRejectsKeywordsFitsCannotHold) {
  ScopedTempDir dir;
  const std::string path = dir.File("out.fits");
  std::string error;
  EXPECT_FALSE(WriteFitsImageF64(path, Image(2, 2), {{"BAD*KEY", 1.0, ""}}, &error));
  EXPECT_NE(error.find("invalid keyword name"), std::string::npos) << error;
  EXPECT_FALSE(
      WriteFitsImageF64(path, Image(2, 2), {{"UNIT", std::string("\xc2\xb5m"), ""}}, &error));
  EXPECT_NE(error.find("printable ASCII"), std::string::npos) << error;
  EXPECT_TRUE(dir.List().empty());
  // Long names are fine (HIERARCH), lower case is upper-cased by CFITSIO.
  ASSERT_TRUE(
      WriteFitsImageF64(path, Image(2, 2), {{"LONGKEYNAME", 1.5, ""}, {"gain", 2.0, ""}}, &error))
      << error;
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(FindNumber(read->header, "LONGKEYNAME"), std::optional<double>(1.5));
  EXPECT_EQ(FindNumber(read->header, "GAIN"), std::optional<double>(2.0));
}

// A write that fails half-way (here: the file-size limit, as a full disk would) must leave
// neither the target nor the temporary file. Assertions wait until the limit is lifted,
// because the test's own output could otherwise hit it.
TEST(FitsIo, FailureDuringWriteRemovesTemporary) {
  ScopedTempDir dir;
  const std::string path = dir.File("big.fits");
  const Image image(64, 64, 1.0);  // 32768 bytes of data
  struct rlimit old_limit;
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  struct rlimit small_limit = old_limit;
  small_limit.rlim_cur = 8 * 2880;
  auto old_handler = std::signal(SIGXFSZ, SIG_IGN);  // EFBIG instead of a signal
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small_limit), 0);
  std::string error;
  const bool ok = WriteFitsImageF64(path, image, {}, &error);
  setrlimit(RLIMIT_FSIZE, &old_limit);
  std::signal(SIGXFSZ, old_handler);

  EXPECT_FALSE(ok);
  ExpectOneLineNaming(error, path);
  EXPECT_TRUE(dir.List().empty()) << error;
}

TEST(FitsIo, FailedWriteKeepsThePreviousFile) {
  ScopedTempDir dir;
  const std::string path = dir.File("keep.fits");
  std::string error;
  ASSERT_TRUE(WriteFitsImageU16(path, Image(4, 4, 10.0), {}, &error)) << error;
  const std::string before = test_support::ReadBytes(path);
  Image bad(4, 4, 10.0);
  bad(0, 0) = 70000.0;
  EXPECT_FALSE(WriteFitsImageU16(path, bad, {}, &error));
  EXPECT_EQ(test_support::ReadBytes(path), before);
  EXPECT_EQ(dir.List(), std::vector<std::string>{"keep.fits"});
}

TEST(FitsIo, WritersOverwriteAnExistingFile) {
  ScopedTempDir dir;
  const std::string path = dir.File("again.fits");
  std::string error;
  ASSERT_TRUE(WriteFitsImageF64(path, Image(2, 2, 1.0), {}, &error)) << error;
  ASSERT_TRUE(WriteFitsImageF64(path, Image(3, 1, 2.0), {}, &error)) << error;
  const std::optional<FitsImage> read = ReadFitsImage(path, &error);
  ASSERT_TRUE(read.has_value()) << error;
  EXPECT_EQ(read->pixels.nx, 3);
  EXPECT_EQ(read->pixels.data, std::vector<double>(3, 2.0));
  EXPECT_EQ(dir.List(), std::vector<std::string>{"again.fits"});
}

TEST(FitsIo, WriterRejectsEmptyOrInconsistentImage) {
  ScopedTempDir dir;
  const std::string path = dir.File("empty.fits");
  std::string error;
  EXPECT_FALSE(WriteFitsImageF64(path, Image(), {}, &error));
  ExpectOneLineNaming(error, path);
  Image inconsistent(3, 3);
  inconsistent.data.pop_back();
  EXPECT_FALSE(WriteFitsImageU16(path, inconsistent, {}, &error));
  EXPECT_TRUE(dir.List().empty());
}

// ------------------------------------------------------------------------------------------
// Atomic files (atomic_file.h).

TEST(FitsIoAtomicFile, TextFileIsWrittenWhole) {
  ScopedTempDir dir;
  const std::string path = dir.File("fit.json");
  std::string error;
  ASSERT_TRUE(WriteTextFileAtomically(path, "{\"a\": 1}\n", &error)) << error;
  ASSERT_TRUE(WriteTextFileAtomically(path, "{\"a\": 2}\n", &error)) << error;
  EXPECT_EQ(test_support::ReadBytes(path), "{\"a\": 2}\n");
  EXPECT_EQ(dir.List(), std::vector<std::string>{"fit.json"});
}

TEST(FitsIoAtomicFile, FailingWriterLeavesNothing) {
  ScopedTempDir dir;
  const std::string path = dir.File("out.txt");
  std::string seen_temp;
  std::string error;
  const bool ok = WriteAtomically(
      path,
      [&](const std::string& temp_path, std::string* write_error) {
        seen_temp = temp_path;
        test_support::WriteBytes(temp_path, "half a fi");
        *write_error = "simulated failure";
        return false;
      },
      &error);
  EXPECT_FALSE(ok);
  EXPECT_EQ(error, "simulated failure");
  // The temporary sits beside the target, so that the rename stays on one file system.
  EXPECT_EQ(seen_temp.rfind(path + ".tmp.", 0), 0u) << seen_temp;
  EXPECT_TRUE(dir.List().empty());
}

TEST(FitsIoAtomicFile, TextIntoMissingFolderFails) {
  ScopedTempDir dir;
  const std::string path = dir.File("missing/out.txt");
  std::string error;
  EXPECT_FALSE(WriteTextFileAtomically(path, "x", &error));
  ExpectOneLineNaming(error, path);
  EXPECT_TRUE(dir.List().empty());
}

TEST(FitsIoAtomicFile, MakeDirectoriesCreatesParents) {
  ScopedTempDir dir;
  const std::string nested = dir.File("a/b/c");
  std::string error;
  ASSERT_TRUE(MakeDirectories(nested, &error)) << error;
  ASSERT_TRUE(MakeDirectories(nested + "/", &error)) << error;  // exists already: fine
  ASSERT_TRUE(WriteTextFileAtomically(nested + "/x.txt", "x", &error)) << error;

  ASSERT_TRUE(test_support::WriteBytes(dir.File("file"), "x"));
  EXPECT_FALSE(MakeDirectories(dir.File("file/sub"), &error));
  EXPECT_NE(error.find("not a directory"), std::string::npos) << error;
  EXPECT_EQ(error.find('\n'), std::string::npos);
}


// ------------------------------------------------------------------------------------------
// Untrusted input: the reader's screen (fits_io.h) and the fuzzer's regressions. Each file
// below once crashed CFITSIO (SIGFPE, or a read past a buffer) or made the reader allocate
// gigabytes; each must now fail with a one-line reason, in this process (a crash kills the
// test).

// Restores the memory ceiling when a test is done with it.
class ScopedMaxImageBytes {
 public:
  explicit ScopedMaxImageBytes(long long bytes) : old_(MaxImageBytes()) {
    SetMaxImageBytes(bytes);
  }
  ~ScopedMaxImageBytes() { SetMaxImageBytes(old_); }

 private:
  long long old_;
};

// The values of a 64 x 40 test image, and the bytes of it tile-compressed in 16 x 16 tiles
// (4 x 3 tiles; the top row of tiles is 8 pixels high, so its tiles are cut short).
constexpr int kTiledNx = 64, kTiledNy = 40, kTile = 16;
std::vector<double> TiledValues() {
  std::vector<double> values;
  for (int i = 0; i < kTiledNx * kTiledNy; ++i) values.push_back((i * 37) % 500 - 100);
  return values;
}
std::string TiledBytes(const ScopedTempDir& dir, int compression) {
  const std::string path = dir.File("tiled_source.fits");
  std::string error;
  EXPECT_TRUE(test_support::WriteTiledFits(path, compression, kTiledNx, kTiledNy, kTile, kTile,
                                           TiledValues(), &error))
      << error;
  return test_support::ReadBytes(path);
}

// Writes `bytes` as `name` and reads it, expecting a one-line error naming the file; lists
// its HDUs too (which must not crash either). Returns the reader's error.
std::string ScreenError(const ScopedTempDir& dir, const std::string& name,
                        const std::string& bytes) {
  const std::string path = dir.File(name);
  EXPECT_TRUE(test_support::WriteBytes(path, bytes));
  std::string list_error;
  (void)ListFitsImageHdus(path, &list_error);
  return ReadError(path);
}

int64_t MaxRssKb() {
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss;
}

TEST(FitsIoScreen, TileCompressedImagesReadExactly) {
  // The screen walks every RICE_1 stream and inflates every GZIP tile before CFITSIO
  // decodes them: valid files, edge tiles included, must pass untouched.
  ScopedTempDir dir;
  for (int compression : {RICE_1, GZIP_1, GZIP_2}) {
    SCOPED_TRACE("compression " + std::to_string(compression));
    const std::string path = dir.File("tiled.fits");
    ASSERT_TRUE(test_support::WriteBytes(path, TiledBytes(dir, compression)));
    std::string error;
    const std::optional<FitsImage> image = ReadFitsImage(path, &error);
    ASSERT_TRUE(image.has_value()) << error;
    EXPECT_EQ(image->pixels.nx, kTiledNx);
    EXPECT_EQ(image->pixels.ny, kTiledNy);
    EXPECT_EQ(image->pixels.data, TiledValues());
    const std::vector<FitsHduInfo> hdus = ListFitsImageHdus(path, &error);
    ASSERT_EQ(hdus.size(), 1u) << error;
    EXPECT_EQ(hdus[0].index, 1);
  }
}

TEST(FitsIoScreen, ZeroTileSizeIsRefusedNotACrash) {
  // CFITSIO divides by ZTILE1 while merely moving to the HDU: fit, trend and diagnose died
  // of SIGFPE with no message.
  ScopedTempDir dir;
  std::string bytes = TiledBytes(dir, RICE_1);
  ASSERT_TRUE(test_support::ReplaceCard(&bytes, "ZTILE1", test_support::Card("ZTILE1", "0")));
  const std::string path = dir.File("ztile0.fits");
  EXPECT_EQ(ScreenError(dir, "ztile0.fits", bytes),
            "'" + path + "' HDU 1: tile-compressed image: ZTILE1 = 0 is outside 1..ZNAXIS1 (64)");
  std::string error;
  EXPECT_TRUE(ListFitsImageHdus(path, &error).empty());
  EXPECT_NE(error.find("ZTILE1 = 0"), std::string::npos) << error;
  // By number and by name too (the selectors move through the HDUs with CFITSIO).
  EXPECT_FALSE(ReadFitsImage(path, "1", &error).has_value());
  EXPECT_NE(error.find("ZTILE1 = 0"), std::string::npos) << error;
  EXPECT_FALSE(ReadFitsImage(path, "AMP1", &error).has_value());
  EXPECT_NE(error.find("ZTILE1 = 0"), std::string::npos) << error;
}

TEST(FitsIoScreen, TileKeywordsCfitsioWouldMisreadAreRefused) {
  struct Case {
    std::string card;   // name of the card to replace
    std::string name;   // the new card's name and value
    std::string value;
    std::string expected;  // in the error
  };
  const std::vector<Case> cases = {
      // CFITSIO reads these as 0 and divides by them.
      {"ZTILE1", "ZTILE1", "0.5", "ZTILE1 = '0.5' is not an integer"},
      {"ZTILE1", "ZTILE1", "F", "ZTILE1 = 'F' is not an integer"},
      {"ZVAL1", "ZVAL1", "0", "RICE_1 block size 0 (ZVAL1) is outside 1..65536"},
      {"ZNAXIS1", "ZNAXIS1", "0", "ZNAXIS1 = 0 is not positive"},
      // Tiles larger than the image (CFITSIO sizes its buffers from them), too many axes.
      {"ZTILE2", "ZTILE2", "99", "ZTILE2 = 99 is outside 1..ZNAXIS2 (40)"},
      {"ZNAXIS", "ZNAXIS", "7", "ZNAXIS = 7 is outside 1..6"},
      {"ZBITPIX", "ZBITPIX", "12", "ZBITPIX = 12 is not 8, 16, 32, 64, -32 or -64"},
      // A tile count that the table's rows do not hold.
      {"ZTILE2", "ZTILE2", "8", "the table has 12 rows but the image 20 tiles (ZNAXISn / ZTILEn)"},
      {"ZCMPTYPE", "ZCMPTYPE", "'LZMA_1  '", "unknown compression ZCMPTYPE = 'LZMA_1'"},
      // The dither offset indexes a table of 10000 random numbers.
      {"ZNAME1", "ZDITHER0", "-5000000", "ZDITHER0 = -5000000 is outside 1..10000"},
      // A second ZTILE1 that CFITSIO might find instead of the first.
      {"ZNAME1", "ZTILE1", "1", "ZTILE1 is given twice with different values"},
  };
  ScopedTempDir dir;
  const std::string original = TiledBytes(dir, RICE_1);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name + " = " + c.value);
    std::string bytes = original;
    ASSERT_TRUE(test_support::ReplaceCard(&bytes, c.card, test_support::Card(c.name, c.value)));
    const std::string error = ScreenError(dir, "bad.fits", bytes);
    EXPECT_NE(error.find(c.expected), std::string::npos) << error;
  }
}

TEST(FitsIoScreen, UncheckableCompressionIsRefused) {
  ScopedTempDir dir;
  for (const char* type : {"'HCOMPRESS_1'", "'PLIO_1  '", "'BZIP2_1 '", "'NOCOMPRESS'"}) {
    std::string bytes = TiledBytes(dir, RICE_1);
    ASSERT_TRUE(test_support::ReplaceCard(&bytes, "ZCMPTYPE", test_support::Card("ZCMPTYPE", type)));
    const std::string error = ScreenError(dir, "other.fits", bytes);
    EXPECT_NE(error.find("is not supported (RICE_1, GZIP_1 and GZIP_2 are)"), std::string::npos)
        << error;
  }
}

TEST(FitsIoScreen, TileOutsideTheHeapIsRefused) {
  ScopedTempDir dir;
  const std::string original = TiledBytes(dir, RICE_1);
  const std::optional<test_support::TileBytes> tile = test_support::FindTile(original, 4);
  ASSERT_TRUE(tile.has_value());
  for (const std::string& descriptor : {std::string("\x00\x00\x00\x40\x7f\xff\x00\x00", 8),
                                        std::string("\xff\xff\xff\xf0\x00\x00\x00\x00", 8),
                                        std::string("\x00\x00\x00\x40\xff\xff\xff\x00", 8)}) {
    std::string bytes = original;
    bytes.replace(tile->descriptor, 8, descriptor);
    const std::string error = ScreenError(dir, "heap.fits", bytes);
    EXPECT_NE(error.find("tile 5's data"), std::string::npos) << error;
    EXPECT_NE(error.find("lie outside the heap"), std::string::npos) << error;
  }
}

TEST(FitsIoScreen, CorruptRiceStreamIsRefused) {
  // A RICE_1 block coded with split level 0 (the code byte 0x10 for 16-bit pixels) whose
  // unary parts are all zero bytes: CFITSIO's decoder runs through zeros without looking at
  // the end of its buffer (ASan saw it read past it).
  ScopedTempDir dir;
  const std::string original = TiledBytes(dir, RICE_1);
  const std::optional<test_support::TileBytes> tile = test_support::FindTile(original, 1);
  ASSERT_TRUE(tile.has_value());
  ASSERT_GT(tile->length, 8u);
  std::string bytes = original;
  bytes.replace(tile->stream + 2, tile->length - 2, std::string(tile->length - 2, '\0'));
  bytes[tile->stream + 2] = '\x10';
  const std::string path = dir.File("zeros.fits");
  EXPECT_EQ(ScreenError(dir, "zeros.fits", bytes),
            "'" + path + "' HDU 1: tile-compressed image: tile 2's RICE_1 stream is corrupt (it "
            "ends before its 256 pixels)");

  // Deterministic mutations of every tile's stream: an image or a one-line error, never a
  // crash (the fuzzer does this at scale).
  std::mt19937 rng(7);
  for (int round = 0; round < 300; ++round) {
    std::string mutated = original;
    const std::optional<test_support::TileBytes> t = test_support::FindTile(mutated, round % 12);
    ASSERT_TRUE(t.has_value());
    for (int k = 0; k < 1 + round % 4; ++k) {
      mutated[t->stream + rng() % t->length] = static_cast<char>(rng() % 256);
    }
    const std::string mutated_path = dir.File("mutated.fits");
    ASSERT_TRUE(test_support::WriteBytes(mutated_path, mutated));
    std::string error;
    if (!ReadFitsImage(mutated_path, &error)) ExpectOneLineNaming(error, mutated_path);
  }
}

TEST(FitsIoScreen, GzipTileInflatingBeyondItsPixelsIsRefused) {
  // A GZIP_1 tile may inflate to at most 8 bytes a pixel; CFITSIO would grow its buffer for
  // as long as the stream goes on (a tile bomb).
  ScopedTempDir dir;
  std::string bytes = TiledBytes(dir, GZIP_1);
  const std::optional<test_support::TileBytes> tile = test_support::FindTile(bytes, 0);
  ASSERT_TRUE(tile.has_value());
  const std::string bomb = test_support::Gzip(std::string(16 * 16 * 8 + 4000, '\0'));
  ASSERT_LE(bomb.size(), tile->length);
  bytes.replace(tile->stream, bomb.size(), bomb);
  const char count[4] = {0, 0, static_cast<char>(bomb.size() >> 8),
                         static_cast<char>(bomb.size() & 0xff)};
  bytes.replace(tile->descriptor, 4, count, 4);
  const std::string error = ScreenError(dir, "tilebomb.fits", bytes);
  EXPECT_NE(error.find("tile 1's gzip stream inflates to more than its 256 pixels"),
            std::string::npos)
      << error;
}

TEST(FitsIoScreen, HugeImageIsRefusedBeforeAllocation) {
  ScopedTempDir dir;
  // 46000 x 46000 pixels claimed by a 2880-byte header: 15.8 GB as doubles.
  const std::string header = test_support::HeaderBlock(
      {test_support::Card("SIMPLE", "T"), test_support::Card("BITPIX", "16"),
       test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", "46000"),
       test_support::Card("NAXIS2", "46000")});
  const std::string path = dir.File("huge.fits");
  EXPECT_EQ(ScreenError(dir, "huge.fits", header + std::string(2880, '\0')),
            "'" + path + "': the image is 46000 x 46000 (15.8 GB as doubles), above the 2.0 GB "
            "limit (--max_image_mb)");
  // In an extension, and with a lower ceiling.
  ScopedMaxImageBytes ceiling(1LL << 20);
  RawImageSpec spec = Simple2d(400, 400);
  spec.in_extension = true;
  const std::string ext_path = dir.File("ext.fits");
  std::string error;
  ASSERT_TRUE(test_support::WriteRawFits(ext_path, spec, &error)) << error;
  EXPECT_EQ(ReadError(ext_path), "'" + ext_path + "' HDU 1: the image is 400 x 400 (1.2 MB as "
                                 "doubles), above the 1.0 MB limit (--max_image_mb)");
}

TEST(FitsIoScreen, GzipMemoryBombFailsFastWithLittleMemory) {
  ScopedTempDir dir;
  const std::string header_16k = test_support::HeaderBlock(
      {test_support::Card("SIMPLE", "T"), test_support::Card("BITPIX", "-64"),
       test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", "16000"),
       test_support::Card("NAXIS2", "16000")});
  const std::string bomb = test_support::Gzip(header_16k + std::string(2880, '\0'));
  ASSERT_LT(bomb.size(), 2500u);  // as small as the one that took 2.0 GB and 73 s
  const std::string path = dir.File("bomb.fits.gz");
  ASSERT_TRUE(test_support::WriteBytes(path, bomb));

  const int64_t rss_before_kb = MaxRssKb();
  {
    // Under the default ceiling (1.9 GB fits in 2 GB): the data are not there.
    std::string error;
    EXPECT_FALSE(ReadFitsImage(path, &error).has_value());
    EXPECT_EQ(error, "'" + path + "' is truncated or corrupt (the image needs 2048002880 bytes, "
                     "the file has 5760)");
    // Under a 1 GB ceiling: refused for its size.
    ScopedMaxImageBytes ceiling(1LL << 30);
    EXPECT_EQ(ReadError(path), "'" + path + "': the image is 16000 x 16000 (1.9 GB as doubles), "
                               "above the 1.0 GB limit (--max_image_mb)");
    // A trailer claiming 4 GB (CFITSIO allocated what it said) is not believed.
    const std::string liar = dir.File("liar.fits.gz");
    ASSERT_TRUE(test_support::WriteBytes(
        liar, test_support::Gzip(header_16k + std::string(2880, '\0'), 0xfffffff0u)));
    EXPECT_NE(ReadError(liar).find("is truncated or corrupt"), std::string::npos);
  }
  // The memory it took is the test (not the time: speed is for benchmarks): nothing near the
  // 2 GB the claimed image would need, so nothing was allocated from the header's word.
  EXPECT_LT(MaxRssKb() - rss_before_kb, 64 * 1024);  // KB
}

TEST(FitsIoScreen, GzipDecompressionStopsAtTheCeiling) {
  // Real bombs: megabytes of zeros that inflate past a 4 MB ceiling.
  ScopedTempDir dir;
  ScopedMaxImageBytes ceiling(4LL << 20);
  const std::string big_image = dir.File("big_image.fits.gz");
  const std::string trailing = dir.File("trailing.fits.gz");
  {
    // A 1024 x 1024 image of doubles (8 MB as read): refused from its header.
    ASSERT_TRUE(test_support::WriteBytes(
        big_image, test_support::Gzip(
                       test_support::HeaderBlock(
                           {test_support::Card("SIMPLE", "T"), test_support::Card("BITPIX", "-64"),
                            test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", "1024"),
                            test_support::Card("NAXIS2", "1024")}) +
                       std::string(1024 * 1024 * 8, '\0'))));
    // A small image followed by 12 MB of zeros.
    ASSERT_TRUE(test_support::WriteBytes(
        trailing, test_support::Gzip(
                      test_support::HeaderBlock(
                          {test_support::Card("SIMPLE", "T"), test_support::Card("BITPIX", "8"),
                           test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", "10"),
                           test_support::Card("NAXIS2", "10")}) +
                      std::string(12 << 20, '\0'))));
  }
  const int64_t rss_before_kb = MaxRssKb();
  EXPECT_EQ(ReadError(big_image), "'" + big_image + "': the image is 1024 x 1024 (8.0 MB as "
                                  "doubles), above the 4.0 MB limit (--max_image_mb)");
  EXPECT_EQ(ReadError(trailing), "'" + trailing + "' decompresses to more than 4.0 MB, the "
                                 "limit (--max_image_mb)");
  EXPECT_LT(MaxRssKb() - rss_before_kb, 64 * 1024);  // KB: the ceiling held
}

TEST(FitsIoScreen, MalformedHeadersAreRefusedWithTheirReason) {
  ScopedTempDir dir;
  auto header = [](const std::string& naxis1, const std::string& bitpix) {
    return test_support::HeaderBlock(
               {test_support::Card("SIMPLE", "T"), test_support::Card("BITPIX", bitpix),
                test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", naxis1),
                test_support::Card("NAXIS2", "4")}) +
           std::string(2880, '\0');
  };
  EXPECT_NE(ScreenError(dir, "a.fits", header("8.0", "16"))
                .find(": the header is corrupt (NAXIS1 = '8.0' is not an integer)"),
            std::string::npos);
  EXPECT_NE(ScreenError(dir, "b.fits", header("8", "7"))
                .find(": the header is corrupt (BITPIX = 7 is not 8, 16, 32, 64, -32 or -64)"),
            std::string::npos);
  EXPECT_NE(ScreenError(dir, "c.fits", header("-8", "16"))
                .find(": the header is corrupt (NAXIS1 = -8 is negative)"),
            std::string::npos);
  EXPECT_NE(ScreenError(dir, "d.fits", header("999999999999999999", "16"))
                .find(": the header is corrupt (the data size overflows)"),
            std::string::npos);
}

// Fuzzer regression: a binary table whose TTYPE1 is an unquoted 70-character value made
// CFITSIO overflow its 70-byte column-name field (abort under _FORTIFY_SOURCE) while it
// counted the HDUs. The screen refuses it; a quoted name of the longest length a card holds
// (68 characters) is read as before. CFITSIO also takes "TTYPE+1 = " and "TTYPE0001=" (a
// name longer than 8 characters, read up to the '=') for column 1: the fuzzer found both.
TEST(FitsIoScreen, UnquotedColumnNameIsRefusedNotACrash) {
  ScopedTempDir dir;
  auto file = [](const std::string& ttype, const std::string& name = "TTYPE1  = ") {
    const std::string primary =
        test_support::HeaderBlock({test_support::Card("SIMPLE", "T"),
                                   test_support::Card("BITPIX", "16"),
                                   test_support::Card("NAXIS", "2"),
                                   test_support::Card("NAXIS1", "4"),
                                   test_support::Card("NAXIS2", "4"),
                                   test_support::Card("EXTEND", "T")}) +
        std::string(2880, '\0');
    const std::string table =
        test_support::HeaderBlock(
            {test_support::Card("XTENSION", "'BINTABLE'"), test_support::Card("BITPIX", "8"),
             test_support::Card("NAXIS", "2"), test_support::Card("NAXIS1", "8"),
             test_support::Card("NAXIS2", "1"), test_support::Card("PCOUNT", "0"),
             test_support::Card("GCOUNT", "1"), test_support::Card("TFIELDS", "1"), name + ttype,
             test_support::Card("TFORM1", "'1D'")}) +
        std::string(2880, '\0');
    return primary + table;
  };
  EXPECT_NE(ScreenError(dir, "unquoted.fits", file(std::string(70, 'X')))
                .find(": the header is corrupt (TTYPE1 = '" + std::string(70, 'X') +
                      "' is not a quoted string)"),
            std::string::npos);
  EXPECT_NE(ScreenError(dir, "signed.fits", file(std::string(70, 'X'), "TTYPE+1 = "))
                .find(": the header is corrupt (TTYPE+1 = '"),
            std::string::npos);
  EXPECT_NE(ScreenError(dir, "long.fits", file(std::string(70, 'X'), "TTYPE0001="))
                .find(": the header is corrupt (TTYPE0001 = '"),
            std::string::npos);
  const std::string quoted = dir.File("quoted.fits");
  ASSERT_TRUE(test_support::WriteBytes(quoted, file("'" + std::string(68, 'X') + "'")));
  std::string error;
  EXPECT_TRUE(ReadFitsImage(quoted, &error).has_value()) << error;
}

// The position of the card named `name` in the header of extension 1 (after the first
// 2880-byte block, the empty primary header), or npos.
size_t ExtensionCard(const std::string& bytes, const std::string& name) {
  std::string padded = name;
  padded.resize(8, ' ');
  for (size_t at = 2880; at + 80 <= bytes.size(); at += 80) {
    if (bytes.compare(at, 8, padded) == 0) return at;
  }
  return std::string::npos;
}

TEST(FitsIoScreen, EndCardAsCfitsioReadsIt) {
  // Found by the fuzzer: CFITSIO ends a header at any card whose name, read up to a blank or
  // '=', is END ("END   TFORM1 ...", "END="). The screen took such a card for something
  // else, never saw the header's end, and let CFITSIO divide by ZTILE1 = 0 (SIGFPE).
  ScopedTempDir dir;
  std::string ztile0 = TiledBytes(dir, RICE_1);
  ASSERT_TRUE(test_support::ReplaceCard(&ztile0, "ZTILE1", test_support::Card("ZTILE1", "0")));
  for (const std::string& end : {std::string("END   TFORM1  = '1PB(43) '"), std::string("END="),
                                 std::string("END  ABC")}) {
    SCOPED_TRACE(end);
    std::string bytes = ztile0;
    const size_t at = ExtensionCard(bytes, "END");
    ASSERT_NE(at, std::string::npos);
    std::string card = end;
    card.resize(80, ' ');
    bytes.replace(at, 80, card);
    const std::string path = dir.File("end.fits");
    EXPECT_EQ(ScreenError(dir, "end.fits", bytes),
              "'" + path + "' HDU 1: tile-compressed image: ZTILE1 = 0 is outside 1..ZNAXIS1 (64)");
  }
}

TEST(FitsIoScreen, MandatoryKeywordsMustBeWhereCfitsioReadsThem) {
  // Found by the fuzzer: CFITSIO reads BITPIX, NAXIS, NAXISn, PCOUNT, GCOUNT and TFIELDS by
  // position, and sized a calloc from an unset variable (2^54 bytes; AddressSanitizer
  // aborts) when one was unreadable or out of place - also in a header the file cuts short.
  ScopedTempDir dir;
  const std::string original = TiledBytes(dir, RICE_1);
  const size_t end = ExtensionCard(original, "END");
  ASSERT_NE(end, std::string::npos);
  struct Case {
    std::string card;
    std::string replacement;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"NAXIS1", test_support::Card("NAXIS1", ":"), "(NAXIS1 = ':' is not an integer)"},
      {"NAXIS", test_support::Card("FOO", "2"), "(card 3 is 'FOO', expected NAXIS)"},
      {"GCOUNT", std::string(80, '\xff'),
       "(card 7 is '" + std::string(8, '?') + "', expected GCOUNT)"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.card);
    std::string whole = original;
    const size_t at = ExtensionCard(whole, c.card);
    ASSERT_NE(at, std::string::npos);
    whole.replace(at, 80, c.replacement);
    // With its END card, and cut short inside the header (no END before the file ends).
    std::string cut = whole.substr(0, 2 * 2880);
    ASSERT_LT(end, cut.size());
    cut.replace(end, 80, std::string(80, ' '));
    for (const std::string& bytes : {whole, cut}) {
      const std::string error = ScreenError(dir, "mandatory.fits", bytes);
      EXPECT_NE(error.find("HDU 1: the header is corrupt " + c.expected), std::string::npos)
          << error;
    }
  }
}

}  // namespace
}  // namespace ccdpsf
