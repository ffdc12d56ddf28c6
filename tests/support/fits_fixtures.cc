#include "support/fits_fixtures.h"

#include <fitsio.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <variant>

namespace ccdpsf::test_support {

ScopedTempDir::ScopedTempDir() {
  std::string base = ::testing::TempDir();
  if (base.empty()) base = "/tmp/";
  if (base.back() != '/') base += '/';
  std::string pattern = base + "ccdpsf_fits_XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  if (::mkdtemp(buffer.data()) != nullptr) path_ = buffer.data();
  EXPECT_FALSE(path_.empty()) << "mkdtemp failed for " << pattern;
}

ScopedTempDir::~ScopedTempDir() {
  if (path_.empty()) return;
  std::error_code ignored;
  std::filesystem::remove_all(path_, ignored);
}

std::string ScopedTempDir::File(const std::string& name) const { return path_ + "/" + name; }

std::vector<std::string> ScopedTempDir::List() const {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(path_, ec)) {
    names.push_back(entry.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

namespace {

std::string StatusText(int status) {
  char text[FLEN_STATUS] = {0};
  fits_get_errstatus(status, text);
  fits_clear_errmsg();
  return "cfitsio status " + std::to_string(status) + ": " + text;
}

// Closes `file` (if open) and reports the first CFITSIO error of the write or the close.
bool Close(fitsfile* file, int status, std::string* error) {
  int close_status = 0;
  if (file != nullptr) fits_close_file(file, &close_status);
  if (status == 0) status = close_status;
  if (status != 0) {
    *error = StatusText(status);
    return false;
  }
  return true;
}

void WriteKeys(fitsfile* file, const FitsHeader& keys, int* status) {
  for (const FitsKey& key : keys) {
    if (const double* v = std::get_if<double>(&key.value)) {
      fits_update_key_dbl(file, key.name.c_str(), *v, -15, key.comment.c_str(), status);
    } else if (const long long* v = std::get_if<long long>(&key.value)) {
      fits_update_key_lng(file, key.name.c_str(), *v, key.comment.c_str(), status);
    } else if (const bool* v = std::get_if<bool>(&key.value)) {
      fits_update_key_log(file, key.name.c_str(), *v ? 1 : 0, key.comment.c_str(), status);
    } else {
      fits_update_key_str(file, key.name.c_str(), std::get<std::string>(key.value).c_str(),
                          key.comment.c_str(), status);
    }
  }
}

}  // namespace

bool WriteRawFits(const std::string& path, const RawImageSpec& spec, std::string* error) {
  ::unlink(path.c_str());
  fitsfile* file = nullptr;
  int status = 0;
  fits_create_diskfile(&file, path.c_str(), &status);
  if (status == 0 && spec.in_extension) {
    fits_create_img(file, BYTE_IMG, 0, nullptr, &status);
  }
  std::vector<long> naxes = spec.naxes;
  fits_create_img(file, spec.bitpix, static_cast<int>(naxes.size()),
                  naxes.empty() ? nullptr : naxes.data(), &status);
  if (spec.in_extension) {
    fits_update_key_str(file, "EXTNAME", "SCI", "", &status);
  }
  if (spec.bscale) fits_update_key_dbl(file, "BSCALE", *spec.bscale, -15, "", &status);
  if (spec.bzero) fits_update_key_dbl(file, "BZERO", *spec.bzero, -15, "", &status);
  if (spec.blank) fits_update_key_lng(file, "BLANK", *spec.blank, "", &status);
  WriteKeys(file, spec.keys, &status);
  // Store the raw values as given: no scaling, no null substitution. (fits_set_bscale does
  // not check the status it is given, so it must not run after a failure.)
  if (status == 0 && !spec.raw.empty()) {
    fits_set_bscale(file, 1.0, 0.0, &status);
    std::vector<double> raw = spec.raw;
    fits_write_img(file, TDOUBLE, 1, static_cast<LONGLONG>(raw.size()), raw.data(), &status);
  }
  return Close(file, status, error);
}

bool WriteTableOnlyFits(const std::string& path, std::string* error) {
  ::unlink(path.c_str());
  fitsfile* file = nullptr;
  int status = 0;
  fits_create_diskfile(&file, path.c_str(), &status);
  fits_create_img(file, BYTE_IMG, 0, nullptr, &status);
  char name[] = "FLUX";
  char form[] = "1D";
  char unit[] = "e-";
  char* ttype[] = {name};
  char* tform[] = {form};
  char* tunit[] = {unit};
  fits_create_tbl(file, BINARY_TBL, 3, 1, ttype, tform, tunit, "SPOTS", &status);
  double values[3] = {1.0, 2.0, 3.0};
  fits_write_col(file, TDOUBLE, 1, 1, 1, 3, values, &status);
  return Close(file, status, error);
}

bool WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  return static_cast<bool>(out);
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream contents;
  contents << in.rdbuf();
  return contents.str();
}

// ------------------------------------------------------------------------------------------
// Byte-level writers.

std::string Card(const std::string& name, const std::string& value) {
  std::string card = name;
  card.resize(8, ' ');
  card += "= ";
  if (!value.empty() && value[0] == '\'') {
    card += value;
  } else {
    card += std::string(value.size() < 20 ? 20 - value.size() : 0, ' ') + value;
  }
  card.resize(80, ' ');
  return card;
}

std::string HeaderBlock(const std::vector<std::string>& cards) {
  std::string header;
  for (std::string card : cards) {
    card.resize(80, ' ');
    header += card;
  }
  header += std::string("END").append(77, ' ');
  header.resize((header.size() + 2879) / 2880 * 2880, ' ');
  return header;
}

bool ReplaceCard(std::string* fits, const std::string& name, const std::string& card) {
  std::string padded_name = name;
  padded_name.resize(8, ' ');
  for (size_t at = 0; at + 80 <= fits->size(); at += 80) {
    if (fits->compare(at, 8, padded_name) != 0) continue;
    std::string replacement = card;
    replacement.resize(80, ' ');
    fits->replace(at, 80, replacement);
    return true;
  }
  return false;
}

namespace {

// CRC-32 of RFC 1952 (polynomial 0xEDB88320), bit by bit: slow but short.
uint32_t Crc32(const std::string& data) {
  uint32_t crc = 0xffffffffu;
  for (unsigned char byte : data) {
    crc ^= byte;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

// Writes bits least significant first, as deflate packs them.
class BitWriter {
 public:
  void Bits(uint32_t value, int count) {
    for (int k = 0; k < count; ++k) Bit((value >> k) & 1u);
  }
  // A Huffman code goes most significant bit first (RFC 1951, 3.1.1).
  void Code(uint32_t code, int length) {
    for (int k = length - 1; k >= 0; --k) Bit((code >> k) & 1u);
  }
  std::string Finish() {
    if (used_ > 0) out_.push_back(static_cast<char>(current_));
    return out_;
  }

 private:
  void Bit(uint32_t bit) {
    current_ |= bit << used_;
    if (++used_ == 8) {
      out_.push_back(static_cast<char>(current_));
      current_ = 0;
      used_ = 0;
    }
  }
  std::string out_;
  uint32_t current_ = 0;
  int used_ = 0;
};

// A literal byte in the fixed Huffman code (RFC 1951, 3.2.6).
void FixedLiteral(BitWriter* bits, unsigned char byte) {
  if (byte < 144) {
    bits->Code(0x30u + byte, 8);
  } else {
    bits->Code(0x190u + (byte - 144u), 9);
  }
}

}  // namespace

std::string Gzip(const std::string& data, std::optional<uint32_t> claimed_size) {
  BitWriter bits;
  bits.Bits(1, 1);  // BFINAL
  bits.Bits(1, 2);  // BTYPE 01: fixed Huffman codes
  size_t i = 0;
  while (i < data.size()) {
    // A run of 258 bytes equal to the previous one: length code 285 (8 bits, 11000101,
    // no extra bits) and distance code 0 (5 bits: distance 1).
    if (i > 0 && i + 258 <= data.size() &&
        data.compare(i, 258, std::string(258, data[i - 1])) == 0) {
      bits.Code(0xc5u, 8);
      bits.Code(0u, 5);
      i += 258;
      continue;
    }
    FixedLiteral(&bits, static_cast<unsigned char>(data[i]));
    ++i;
  }
  bits.Code(0u, 7);  // end of block (256)
  std::string out = std::string("\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff", 10);
  out += bits.Finish();
  auto little_endian = [&](uint32_t v) {
    for (int k = 0; k < 4; ++k) out.push_back(static_cast<char>((v >> (8 * k)) & 0xffu));
  };
  little_endian(Crc32(data));
  little_endian(claimed_size.value_or(static_cast<uint32_t>(data.size())));
  return out;
}

bool WriteTiledFits(const std::string& path, int compression, int nx, int ny, int tile_nx,
                    int tile_ny, const std::vector<double>& values, std::string* error) {
  ::unlink(path.c_str());
  fitsfile* file = nullptr;
  int status = 0;
  fits_create_diskfile(&file, path.c_str(), &status);
  fits_create_img(file, BYTE_IMG, 0, nullptr, &status);
  fits_set_compression_type(file, compression, &status);
  long tile[2] = {tile_nx, tile_ny};
  fits_set_tile_dim(file, 2, tile, &status);
  long naxes[2] = {nx, ny};
  fits_create_img(file, SHORT_IMG, 2, naxes, &status);
  // As shorts: CFITSIO compresses only values of the image's own type.
  std::vector<short> copy(values.begin(), values.end());
  fits_write_img(file, TSHORT, 1, static_cast<LONGLONG>(copy.size()), copy.data(), &status);
  return Close(file, status, error);
}

namespace {

// The end of the header starting at `start` (the byte after its last block), and the
// integer values of its cards; nullopt if there is no END card.
std::optional<size_t> ParseHeader(const std::string& fits, size_t start,
                                  std::map<std::string, long long>* values) {
  for (size_t at = start; at + 80 <= fits.size(); at += 80) {
    std::string name = fits.substr(at, 8);
    name.erase(name.find_last_not_of(' ') + 1);
    if (name == "END") return (at + 80 + 2879) / 2880 * 2880;
    if (fits.compare(at + 8, 2, "= ") == 0) {
      (*values)[name] = std::strtoll(fits.substr(at + 10, 20).c_str(), nullptr, 10);
    }
  }
  return std::nullopt;
}

}  // namespace

std::optional<TileBytes> FindTile(const std::string& fits, long long row) {
  std::map<std::string, long long> primary, table;
  const std::optional<size_t> extension = ParseHeader(fits, 0, &primary);
  if (!extension || primary["NAXIS"] != 0) return std::nullopt;
  const std::optional<size_t> data = ParseHeader(fits, *extension, &table);
  if (!data) return std::nullopt;
  TileBytes tile;
  tile.descriptor = *data + static_cast<size_t>(row * table["NAXIS1"]);
  if (tile.descriptor + 8 > fits.size()) return std::nullopt;
  auto big_endian = [&](size_t at) {
    uint32_t v = 0;
    for (int k = 0; k < 4; ++k) v = (v << 8) | static_cast<unsigned char>(fits[at + k]);
    return v;
  };
  const long long heap =
      table.count("THEAP") ? table["THEAP"] : table["NAXIS1"] * table["NAXIS2"];
  tile.length = big_endian(tile.descriptor);
  tile.stream = *data + static_cast<size_t>(heap) + big_endian(tile.descriptor + 4);
  return tile;
}

namespace {

// Fraction of a unit 1-D Gaussian (centre mu, width sigma) falling in [a, b].
double GaussianFraction(double a, double b, double mu, double sigma) {
  const double s = sigma * std::sqrt(2.0);
  return 0.5 * (std::erf((b - mu) / s) - std::erf((a - mu) / s));
}

}  // namespace

double ExpectedElectrons(const SyntheticFrame& spec, int x, int y) {
  return spec.flux_e * GaussianFraction(x - 0.5, x + 0.5, spec.spot_x_px, spec.sigma_px) *
         GaussianFraction(y - 0.5, y + 0.5, spec.spot_y_px, spec.sigma_px);
}

Image MakeSpotFrame(const SyntheticFrame& spec) {
  std::mt19937_64 rng(spec.seed);
  std::normal_distribution<double> read_noise(0.0, spec.read_noise_e);
  Image frame(spec.nx, spec.ny);
  for (int y = 0; y < spec.ny; ++y) {
    for (int x = 0; x < spec.nx; ++x) {
      double electrons = ExpectedElectrons(spec, x, y);
      if (spec.noise) {
        if (electrons > 0.0) {
          std::poisson_distribution<long long> shot(electrons);
          electrons = static_cast<double>(shot(rng));
        }
        electrons += read_noise(rng);
      }
      double adu = spec.bias_adu + electrons / spec.gain_e_per_adu;
      if (spec.round) adu = std::round(adu);
      frame(x, y) = adu;
    }
  }
  return frame;
}

}  // namespace ccdpsf::test_support
