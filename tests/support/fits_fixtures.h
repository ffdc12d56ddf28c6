// Fixture builders for the FITS I/O and exposure tests: a self-removing temporary folder,
// FITS files written directly with CFITSIO (independently of the library's writers, so that
// the reader is checked against files it did not make), and synthetic spot frames with known
// bias, gain, read noise and spot position.
#ifndef CCDPSF_TESTS_SUPPORT_FITS_FIXTURES_H_
#define CCDPSF_TESTS_SUPPORT_FITS_FIXTURES_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/image.h"

namespace ccdpsf::test_support {

// A fresh folder under ::testing::TempDir(), removed with its contents on destruction.
class ScopedTempDir {
 public:
  ScopedTempDir();
  ~ScopedTempDir();
  ScopedTempDir(const ScopedTempDir&) = delete;
  ScopedTempDir& operator=(const ScopedTempDir&) = delete;

  const std::string& path() const { return path_; }
  // path() + "/" + name.
  std::string File(const std::string& name) const;
  // Names of the entries in the folder, sorted.
  std::vector<std::string> List() const;

 private:
  std::string path_;
};

// A FITS image HDU described by its stored (raw) values, written with CFITSIO's scaling
// switched off so that the file holds exactly `raw`, with BSCALE/BZERO/BLANK cards as given.
struct RawImageSpec {
  int bitpix = -64;         // 8, 16, 32, 64, -32 or -64
  std::vector<long> naxes;  // NAXIS1, NAXIS2, ... (empty: NAXIS = 0)
  std::vector<double> raw;  // stored values in FITS order (NAXIS1 fastest)
  std::optional<double> bscale;
  std::optional<double> bzero;
  std::optional<long long> blank;
  FitsHeader keys;            // further cards, written with CFITSIO's own calls
  bool in_extension = false;  // empty primary HDU, image in extension 1 (EXTNAME = 'SCI')
};

// Writes `spec` to a new file at `path` (removing any file there). Returns false with
// CFITSIO's reason on failure.
bool WriteRawFits(const std::string& path, const RawImageSpec& spec, std::string* error);

// Writes an empty primary HDU followed by a one-column binary table and no image.
bool WriteTableOnlyFits(const std::string& path, std::string* error);

// Writes `bytes` to `path` verbatim (not-FITS files, truncated copies).
bool WriteBytes(const std::string& path, const std::string& bytes);
std::string ReadBytes(const std::string& path);

// ------------------------------------------------------------------------------------------
// Byte-level writers for malformed files (the reader's screen and the fuzzer's regressions).

// One 80-character header card: "NAME    = value", the value right-aligned in columns 11-30
// (where FITS puts numbers and logicals); a string value is given with its quotes.
std::string Card(const std::string& name, const std::string& value);
// A header: the cards, the END card, blanks to a whole 2880-byte block.
std::string HeaderBlock(const std::vector<std::string>& cards);
// Replaces the whole first card whose name is `name` by `card` (80 characters or fewer).
// False if no card has that name.
bool ReplaceCard(std::string* fits, const std::string& name, const std::string& card);

// A gzip member (RFC 1952) holding `data`, deflated (RFC 1951) with the fixed Huffman code:
// runs of a repeated byte become length-258 back-references, so that zeros shrink ~150:1 (a
// memory bomb in a few hundred KB) while anything else is stored as literals. Independent
// of zlib and CFITSIO; `claimed_size` overrides the trailer's ISIZE (it can lie).
std::string Gzip(const std::string& data, std::optional<uint32_t> claimed_size = std::nullopt);

// A tile-compressed image (empty primary HDU, the image in extension 1), written by CFITSIO:
// `compression` is CFITSIO's code (RICE_1, GZIP_1, ...), the tiles `tile_nx` x `tile_ny`
// pixels, the values (integers in the 16-bit range) stored as 16-bit integers.
bool WriteTiledFits(const std::string& path, int compression, int nx, int ny, int tile_nx,
                    int tile_ny, const std::vector<double>& values, std::string* error);

// Where tile `row` (0-based) of the tile-compressed image in extension 1 of `fits` lies:
// byte offset in the file and length of its compressed stream, and of its descriptor.
struct TileBytes {
  size_t descriptor = 0;  // offset of the (count, heap offset) pair, two big-endian int32
  size_t stream = 0;      // offset of the compressed bytes
  size_t length = 0;      // their number
};
std::optional<TileBytes> FindTile(const std::string& fits, long long row);

// A frame with one pixel-integrated circular Gaussian spot, in ADU:
//   adu = bias_adu + (Poisson(expected electrons) + Normal(0, read_noise_e)) / gain,
// rounded to whole ADU when `round` is set. expected(x, y) = flux_e * Px * Py with
// Px = integral of the unit Gaussian (centre spot_x_px, sigma_px) over [x - 0.5, x + 0.5]
// (a difference of erf), likewise Py: exact pixel integration, independent of the library's
// renderers.
struct SyntheticFrame {
  int nx = 64;
  int ny = 64;
  double bias_adu = 1000.0;
  double gain_e_per_adu = 3.1;
  double read_noise_e = 4.5;
  double flux_e = 2.0e5;
  double spot_x_px = 31.3;
  double spot_y_px = 30.8;
  double sigma_px = 0.8;
  bool noise = true;
  bool round = true;
  uint64_t seed = 1;
};
Image MakeSpotFrame(const SyntheticFrame& spec);

// Expected electrons of the spot of `spec` in frame pixel (x, y) (no bias, no noise).
double ExpectedElectrons(const SyntheticFrame& spec, int x, int y);

}  // namespace ccdpsf::test_support

#endif  // CCDPSF_TESTS_SUPPORT_FITS_FIXTURES_H_
