// FITS input and output through CFITSIO, behind RAII, with atomic writes.
//
// Every writer here writes to a temporary file beside the target and renames it into place
// only when the whole file has been written and closed, so a failed or interrupted run never
// leaves a half-written file under the final name. Writers overwrite an existing target.
// Fallible calls return false (or an empty optional) and put a one-line reason in *error.
#ifndef CCDPSF_FITS_IO_H_
#define CCDPSF_FITS_IO_H_

#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "ccdpsf/image.h"

namespace ccdpsf {

// One header card. Strings are written as FITS strings, bools as T/F, integers as integers.
struct FitsKey {
  std::string name;
  std::variant<double, long long, std::string, bool> value;
  std::string comment;
};
using FitsHeader = std::vector<FitsKey>;

// Looks a keyword up (case-insensitive, first match). Integers convert to double; a string
// that parses as a number does too.
std::optional<double> FindNumber(const FitsHeader& header, const std::string& name);
std::optional<std::string> FindString(const FitsHeader& header, const std::string& name);

// A 2-D image as read: pixel values with BZERO/BSCALE applied (CFITSIO does this), as
// doubles; non-finite values are kept as NaN. header holds the user keywords of the HDU the
// image came from (structural keywords such as SIMPLE, BITPIX, NAXIS* are not included).
struct FitsImage {
  Image pixels;
  FitsHeader header;
  int bitpix = 0;    // BITPIX of the stored data
  int hdu = 1;       // 1-based HDU number the image came from (1 = primary)
  std::string extname;  // EXTNAME of that HDU ("" if none)
  // The range the stored integers can represent, in physical units (BZERO + BSCALE x raw):
  // an ADC cannot record beyond it (8-bit: [0, 255]; 16-bit with BZERO 32768: [0, 65535]).
  // Infinite for floating-point and 64-bit data.
  double adc_min = -std::numeric_limits<double>::infinity();
  double adc_max = std::numeric_limits<double>::infinity();
};

// Reading untrusted files. Before CFITSIO reads anything, the reader walks the headers of
// every HDU itself and refuses, with a one-line reason, what CFITSIO could not survive
// (tile-compression parameters such as ZTILE1 = 0, on which CFITSIO divides by zero; header
// values it would read differently) and any image above the memory ceiling below. Before a
// tile-compressed image is decompressed, every tile must lie inside the table's heap and,
// for RICE_1, its stream must hold all its pixels; GZIP_1 / GZIP_2 tiles must inflate to at
// most 8 bytes a pixel. HCOMPRESS_1, PLIO_1, BZIP2_1 and NOCOMPRESS images are refused
// (CFITSIO's decoders for them cannot be checked so). A gzip file is decompressed into
// memory, at most the ceiling's size, before its headers are screened.
//
// The memory ceiling: the most memory one image may take [bytes], counted as bytes_per_pixel
// times its pixels: by default 8, the image as doubles. A command that holds a whole image
// with its working copies counts what it holds: kWholeImageBytesPerPixel (fit, trend,
// diagnose, gain and ptc: the image as doubles, a smoothed copy and masks; ccdpsf grid streams
// its frames in strips and keeps the default). An image above it is refused before any
// allocation: "'f.fits': the image is 16000 x 16000 (1.9 GB as doubles), above the 1.0 GB limit
// (--max_image_mb)", or "(4.3 GB as the run holds it, 18 bytes a pixel)". For every thread;
// bytes >= 1, bytes_per_pixel >= 1.
constexpr long long kDefaultMaxImageBytes = 2LL << 30;  // 2 GiB
constexpr double kImageBytesPerPixel = sizeof(double);
// Measured: the peak resident memory of `ccdpsf fit` on 2000^2, 4000^2 and 6000^2 frames
// grows by 18.0 bytes a pixel (91, 302 and 654 MB).
constexpr double kWholeImageBytesPerPixel = 18.0;
void SetMaxImageBytes(long long bytes, double bytes_per_pixel = kImageBytesPerPixel);
long long MaxImageBytes();
double ImageBytesPerPixel();

// Reads the 2-D image in the primary HDU, or in the first image extension when the primary
// HDU is empty. Fails with a one-line reason for a missing file, a file that is not FITS, a
// truncated file, no image HDU, an image that is not 2-D or is empty, or a table where the
// image should be.
std::optional<FitsImage> ReadFitsImage(const std::string& path, std::string* error);

// Reads the image of one HDU: `hdu` is an extension number (0 = primary, 1 = first
// extension: astropy's and DS9's count) or an EXTNAME (case-insensitive); "" is the default
// choice above. Fails with a one-line reason if there is no such HDU, or it is a table or
// empty.
std::optional<FitsImage> ReadFitsImage(const std::string& path, const std::string& hdu,
                                       std::string* error);

// A 2-D image read a few rows at a time, for frames too large to keep whole (a 4096 x 4096
// frame is 128 MiB as doubles): the same screen, HDU choice and checks as ReadFitsImage, the
// header, BITPIX, HDU, EXTNAME and ADC range at once, the pixels only as asked.
//
//   std::unique_ptr<FitsImageStream> stream = FitsImageStream::Open(path, "", &error);
//   if (!stream) { ... }                                   // one line, names the file
//   std::vector<double> rows(static_cast<size_t>(stream->nx()) * 64);
//   stream->ReadRows(0, 64, rows.data(), &error);          // rows 0..63, row after row
class FitsImageStream {
 public:
  // `hdu_selector` as for ReadFitsImage. Null with a one-line reason in *error.
  static std::unique_ptr<FitsImageStream> Open(const std::string& path,
                                               const std::string& hdu_selector, std::string* error);
  ~FitsImageStream();
  FitsImageStream(const FitsImageStream&) = delete;
  FitsImageStream& operator=(const FitsImageStream&) = delete;

  int nx() const { return nx_; }
  int ny() const { return ny_; }
  // Everything ReadFitsImage returns but the pixels (image().pixels is empty).
  const FitsImage& image() const { return image_; }
  // Rows [y_begin, y_begin + rows) into out (rows x nx values, row after row; BZERO/BSCALE
  // applied, BLANK and NaN pixels NaN). False with a reason for rows outside the image or a
  // read that fails (a file truncated after it was opened).
  bool ReadRows(int y_begin, int rows, double* out, std::string* error);

 private:
  FitsImageStream();
  struct Opened;
  std::unique_ptr<Opened> opened_;
  std::string path_;
  FitsImage image_;
  int nx_ = 0, ny_ = 0;
};

// The HDUs of a file that hold a 2-D image, for picking an amplifier segment.
struct FitsHduInfo {
  int index = 0;         // 0 = primary, as above
  std::string extname;
  long long nx = 0, ny = 0;
};
// Empty (with *error set) if the file cannot be read.
std::vector<FitsHduInfo> ListFitsImageHdus(const std::string& path, std::string* error);

// A FITS file opened once to read several of its images (a multi-extension file's
// segments). ReadFitsImage and ListFitsImageHdus open and screen the whole file at each
// call, so reading each of N segments through them costs O(N^2); through this, O(N).
class FitsImageFile {
 public:
  // Null with a one-line reason in *error.
  static std::unique_ptr<FitsImageFile> Open(const std::string& path, std::string* error);
  ~FitsImageFile();
  FitsImageFile(const FitsImageFile&) = delete;
  FitsImageFile& operator=(const FitsImageFile&) = delete;

  // The HDUs holding a 2-D image, as ListFitsImageHdus gives them.
  const std::vector<FitsHduInfo>& images() const { return images_; }
  // The image `hdu_selector` names, as ReadFitsImage(path, hdu_selector) reads it.
  std::optional<FitsImage> Read(const std::string& hdu_selector, std::string* error);

 private:
  FitsImageFile();
  struct Opened;
  std::unique_ptr<Opened> opened_;
  std::string path_;
  std::vector<FitsHduInfo> images_;
};

// Writes `image` as 16-bit unsigned integers (BITPIX = 16, BZERO = 32768). Every value must
// be an integer in [0, 65535]; anything else is an error (the caller rounds and clips).
bool WriteFitsImageU16(const std::string& path, const Image& image, const FitsHeader& header,
                       std::string* error);

// Writes `image` as 64-bit floats (BITPIX = -64) in the primary HDU.
bool WriteFitsImageF64(const std::string& path, const Image& image, const FitsHeader& header,
                       std::string* error);

// One image extension of a multi-extension file.
struct FitsImageHdu {
  std::string extname;
  Image image;
  FitsHeader header;
};

// Writes an empty primary HDU carrying primary_header, then each image as a 64-bit float
// IMAGE extension with EXTNAME set.
bool WriteFitsImagesF64(const std::string& path, const FitsHeader& primary_header,
                        const std::vector<FitsImageHdu>& images, std::string* error);

// One column of a binary table: doubles (TFORM 1D) or, when is_integer, 64-bit integers
// (TFORM 1K, values rounded); or, when `texts` is not empty, strings (TFORM nA, n the longest
// text, at least 1; printable ASCII) and `values` is ignored. All columns of a table have the
// same length.
struct FitsColumn {
  std::string name;
  std::string unit;
  std::vector<double> values;
  bool is_integer = false;
  std::vector<std::string> texts;
  size_t Rows() const { return texts.empty() ? values.size() : texts.size(); }
};

// Writes an empty primary HDU carrying primary_header and one BINTABLE extension named
// extname with the given columns (readable by astropy.table.Table.read and TOPCAT) and
// table_header's keywords (Table.read keeps those of the table's HDU, not the primary's).
// Column names must be letters, digits and '_' (FitsColumnName in column_units.h makes them);
// a column's unit becomes its TUNITn.
bool WriteFitsTable(const std::string& path, const FitsHeader& primary_header,
                    const std::string& extname, const std::vector<FitsColumn>& columns,
                    const FitsHeader& table_header, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_FITS_IO_H_
