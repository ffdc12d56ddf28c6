// Screening untrusted FITS files before CFITSIO parses them: see internal/fits_screen.h.
#include "internal/fits_screen.h"

#include <fitsio.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "internal/text.h"

// CFITSIO's own gzip front-ends to zlib (zcompress.c): exported by libcfitsio since 3.x but
// declared only in its private fitsio2.h. CFITSIO opens a .gz file with uncompress2mem and
// inflates GZIP_1 tiles with uncompress2mem_from_mem; calling them here, with a realloc that
// refuses to grow past a bound, caps the memory a decompression can take.
extern "C" {
int uncompress2mem(char* filename, std::FILE* diskfile, char** buffptr, size_t* buffsize,
                   void* (*mem_realloc)(void* p, size_t newsize), size_t* filesize, int* status);
int uncompress2mem_from_mem(char* inmemptr, size_t inmemsize, char** buffptr, size_t* buffsize,
                            void* (*mem_realloc)(void* p, size_t newsize), size_t* filesize,
                            int* status);
}

namespace ccdpsf {
namespace {
// The memory ceiling (SetMaxImageBytes) and what a pixel costs against it, shared by every
// thread.
std::atomic<long long> g_max_image_bytes{kDefaultMaxImageBytes};
std::atomic<double> g_bytes_per_pixel{kImageBytesPerPixel};
}  // namespace

void SetMaxImageBytes(long long bytes, double bytes_per_pixel) {
  g_max_image_bytes.store(std::max(bytes, 1LL));
  g_bytes_per_pixel.store(std::max(bytes_per_pixel, 1.0));
}

long long MaxImageBytes() { return g_max_image_bytes.load(); }
double ImageBytesPerPixel() { return g_bytes_per_pixel.load(); }

namespace internal {
namespace {

constexpr long long kBlock = 2880;  // FITS block [bytes]
constexpr long long kCard = 80;     // header card [bytes]
constexpr int kMaxCompressDim = 6;  // CFITSIO's MAX_COMPRESS_DIM


}  // namespace

// "1.9 GB", "64.0 MB", "300 bytes" in binary units (1 MB = 2^20 bytes), as --max_image_mb.
std::string FormatBytes(double bytes) {
  char text[64];
  if (bytes >= 0x1p30) {
    std::snprintf(text, sizeof(text), "%.1f GB", bytes / 0x1p30);
  } else if (bytes >= 0x1p20) {
    std::snprintf(text, sizeof(text), "%.1f MB", bytes / 0x1p20);
  } else if (bytes >= 0x1p10) {
    std::snprintf(text, sizeof(text), "%.1f KB", bytes / 0x1p10);
  } else {
    std::snprintf(text, sizeof(text), "%.0f bytes", bytes);
  }
  return text;
}

// Where a problem is, in messages: "'f.fits'" for the primary HDU, "'f.fits' HDU 2" for
// extension 2 (numbered as ReadFitsImage's selector, 0 = primary). `hdu` is 1-based.
std::string HduWhere(const std::string& path, int hdu) {
  return hdu == 1 ? Quoted(path) : Quoted(path) + " HDU " + std::to_string(hdu - 1);
}

// The memory-ceiling check for an image of the given axes, at ImageBytesPerPixel(). Empty if
// it fits.
std::string CheckImageSize(const std::string& where, const std::vector<long long>& axes) {
  const double per_pixel = ImageBytesPerPixel();
  double bytes = per_pixel;  // a double holds any product of axes without overflow
  std::string shape;
  for (long long n : axes) {
    bytes *= static_cast<double>(n);
    shape += (shape.empty() ? "" : " x ") + std::to_string(n);
  }
  const long long limit = MaxImageBytes();
  if (bytes <= static_cast<double>(limit)) return "";
  const std::string counted =
      per_pixel == kImageBytesPerPixel
          ? "as doubles"
          : "as the run holds it, " + FormatNumber(per_pixel) + " bytes a pixel";
  return where + ": the image is " + shape + " (" + FormatBytes(bytes) + " " + counted +
         "), above the " + FormatBytes(static_cast<double>(limit)) + " limit (--max_image_mb)";
}

namespace {

// a x b, or nullopt when the product of non-negative factors exceeds 2^62 (no FITS size can
// be that large; the bound leaves room for the sums the callers add).
std::optional<long long> CheckedProduct(long long a, long long b) {
  constexpr long long kMax = 1LL << 62;
  if (a < 0 || b < 0) return std::nullopt;
  if (a != 0 && b > kMax / a) return std::nullopt;
  return a * b;
}


// The growth allowed to the decompression running on this thread (CFITSIO's realloc
// callback takes no context). BoundedRealloc grows the block geometrically up to `limit`
// bytes and refuses beyond; since CFITSIO drops its pointer when realloc fails, a refused
// block is parked in `refused` for the caller to take back or free.
struct GrowthBudget {
  size_t limit = 0;
  size_t capacity = 0;
  void* refused = nullptr;
  bool hit_limit = false;
};
thread_local GrowthBudget t_budget;

void* BoundedRealloc(void* block, size_t wanted) {
  GrowthBudget& budget = t_budget;
  if (wanted <= budget.capacity) return block;  // grown ahead of CFITSIO's small steps
  if (wanted > budget.limit) {
    budget.hit_limit = true;
    budget.refused = block;
    return nullptr;
  }
  const size_t target = std::min(budget.limit, std::max(wanted, budget.capacity * 2));
  void* grown = std::realloc(block, target);
  if (grown == nullptr) {
    budget.refused = block;
    return nullptr;
  }
  budget.capacity = target;
  return grown;
}

}  // namespace

// Decompresses the gzip file at `path` into memory, at most `limit` bytes. *complete is
// false when the output reached the limit (the bytes so far are kept: their headers can
// still be screened). The size the gzip trailer claims is not used: it can lie. False with
// a one-line reason when the stream is corrupt or memory runs out.
bool Gunzip(const std::string& path, size_t limit, FileBytes* bytes, bool* complete,
            std::string* error) {
  std::FILE* stream = std::fopen(path.c_str(), "rb");
  if (stream == nullptr) {
    *error = "cannot open " + Quoted(path) + ": " + std::strerror(errno);
    return false;
  }
  size_t size = std::min<size_t>(limit, size_t{1} << 20);
  char* buffer = static_cast<char*>(std::malloc(std::max<size_t>(size, 1)));
  t_budget = GrowthBudget{limit, size, nullptr, false};
  size_t out = 0;
  int status = 0;
  if (buffer == nullptr) {
    status = MEMORY_ALLOCATION;
  } else {
    uncompress2mem(const_cast<char*>(path.c_str()), stream, &buffer, &size, BoundedRealloc, &out,
                   &status);
  }
  std::fclose(stream);
  if (buffer == nullptr) buffer = static_cast<char*>(t_budget.refused);
  const bool hit_limit = t_budget.hit_limit;
  t_budget = GrowthBudget{};
  if (status != 0 && hit_limit) {
    // uncompress2mem only grows a full buffer: its `size` bytes are all output.
    bytes->TakeMemory(buffer, size);
    *complete = false;
    return true;
  }
  if (status != 0) {
    std::free(buffer);
    *error = Quoted(path) + " is truncated or corrupt (its gzip stream does not decompress)";
    return false;
  }
  bytes->TakeMemory(buffer, out);
  *complete = true;
  return true;
}

namespace {

// A keyword value as the screen reads it from a card: the text after "= ", up to any
// comment, blanks trimmed; for a string, the text between the quotes.
struct CardValue {
  std::string text;
  bool quoted = false;
};

// The cards of one header that the screen looks at.
struct HeaderCards {
  std::string first_name;                   // SIMPLE or XTENSION in a valid header
  std::map<std::string, CardValue> values;  // upper-case name -> first value
  std::string conflict;                     // a name given twice with different values
  long long end = 0;                        // first byte after the header's last block
  bool complete = false;                    // false if the file ends before the END card
  // The header's first cards in order (up to 1010: the mandatory keywords of any header),
  // which CFITSIO reads by position.
  std::vector<std::pair<std::string, CardValue>> leading;
};

bool IsScreenedKeyword(const std::string& name) {
  static const std::set<std::string> kNames = {
      "SIMPLE", "XTENSION", "BITPIX", "NAXIS",  "PCOUNT",   "GCOUNT",   "GROUPS",
      "THEAP",  "TFIELDS",  "ZIMAGE", "ZCMPTYPE", "ZBITPIX", "ZNAXIS", "ZVAL1",
      "ZVAL2",  "ZDITHER0", "ZQUANTIZ", "BSCALE", "BZERO"};
  // Any TTYPE name: CFITSIO takes "TTYPE+1" and "TTYPE0001" for column 1 (it reads the index
  // with strtol), so the column-name check below must see them all.
  return kNames.count(name) > 0 || IsIndexed(name, "NAXIS") || IsIndexed(name, "TFORM") ||
         name.rfind("TTYPE", 0) == 0 || IsIndexed(name, "ZNAXIS") || IsIndexed(name, "ZTILE");
}

// The value of a card whose value starts at column `from` (0-based; 10 after "NAME    = ").
CardValue ParseCardText(const char* card, size_t from = 10) {
  CardValue value;
  std::string text(card + from, card + kCard);
  const size_t first = text.find_first_not_of(' ');
  if (first == std::string::npos) return value;
  if (text[first] == '\'') {
    value.quoted = true;
    for (size_t i = first + 1; i < text.size(); ++i) {
      if (text[i] == '\'') {
        if (i + 1 < text.size() && text[i + 1] == '\'') {
          value.text.push_back('\'');
          ++i;
          continue;
        }
        break;
      }
      value.text.push_back(text[i]);
    }
  } else {
    value.text = text.substr(first, text.find('/', first) - first);
  }
  while (!value.text.empty() && value.text.back() == ' ') value.text.pop_back();
  return value;
}

// Reads the header starting at byte `start`: every block up to the END card, or up to the
// end of the file (cards->complete false). False if not even the first block is there.
bool ReadHeaderCards(const FileBytes& bytes, long long start, HeaderCards* cards) {
  char block[kBlock];
  for (long long offset = start;; offset += kBlock) {
    if (!bytes.Read(offset, kBlock, block)) return offset > start;
    for (long long c = 0; c < kBlock; c += kCard) {
      const char* card = block + c;
      // The name as CFITSIO reads it: up to the first blank or '=' in columns 1-8. Only
      // "END" so read, in capitals, ends the header for CFITSIO ("END  ABC" and "END=" do,
      // "end" and "END-" do not); other names are matched in any case (stricter).
      const char* name_end = std::find_if(card, card + 8, [](char ch) {
        return ch == ' ' || ch == '=';
      });
      const std::string token(card, name_end);
      std::string name = ToUpper(token);
      if (offset == start && c == 0) cards->first_name = name;
      if (cards->leading.size() < 1010 && token != "END") {
        cards->leading.emplace_back(
            name, card[8] == '=' && card[9] == ' ' ? ParseCardText(card) : CardValue{});
      }
      if (token == "END") {
        cards->end = offset + kBlock;
        cards->complete = true;
        return true;
      }
      size_t value_from = 10;
      if (name == "HIERARCH") {
        // "HIERARCH ZTILE1 = 0": CFITSIO may find it when asked for ZTILE1, so it counts.
        const char* equals = static_cast<const char*>(std::memchr(card + 9, '=', kCard - 9));
        if (equals == nullptr) continue;
        name = ToUpper(internal::Trim(std::string(card + 9, equals)));
        value_from = static_cast<size_t>(equals - card) + 1;
      } else if (name_end == card + 8 && card[8] != ' ' && card[8] != '=') {
        // A name longer than 8 characters ("TTYPE0001= ..."), outside the standard: CFITSIO
        // reads the name up to the '=' and the value after it, and so does the screen.
        const char* equals = static_cast<const char*>(std::memchr(card + 8, '=', kCard - 8));
        if (equals == nullptr) continue;
        name = ToUpper(internal::Trim(std::string(card, equals)));
        value_from = static_cast<size_t>(equals - card) + 1;
      } else if (card[8] != '=' || card[9] != ' ') {
        continue;
      }
      if (!IsScreenedKeyword(name)) continue;
      const CardValue value = ParseCardText(card, value_from);
      const auto [it, inserted] = cards->values.emplace(name, value);
      if (!inserted && it->second.text != value.text && cards->conflict.empty()) {
        cards->conflict = name;
      }
    }
  }
}

// A plain integer ("64", "-32", "+7"): what every screened numeric keyword must be.
std::optional<long long> ParseStrictInteger(const CardValue& value) {
  const std::string& s = value.text;
  if (value.quoted || s.empty()) return std::nullopt;
  size_t i = (s[0] == '+' || s[0] == '-') ? 1 : 0;
  if (i == s.size() || s.size() - i > 18) return std::nullopt;  // 18 digits: no overflow
  for (size_t k = i; k < s.size(); ++k) {
    if (!std::isdigit(static_cast<unsigned char>(s[k]))) return std::nullopt;
  }
  return std::strtoll(s.c_str(), nullptr, 10);
}


// Bytes of one value of a FITS binary-table type (standard table 18); 0 if unknown.
// A real number as a FITS card writes it ("1.5", "-2E3", "1.0D0"), finite; none for
// anything else (quoted text, "NAN", "INF", a logical).
std::optional<double> ParseFiniteReal(const CardValue& value) {
  if (value.quoted || value.text.empty()) return std::nullopt;
  std::string s = value.text;
  for (char& c : s) {
    if (c == 'D' || c == 'd') c = 'E';  // the standard's double-precision exponent
  }
  for (const char c : s) {
    if (!std::isdigit(static_cast<unsigned char>(c)) && c != '+' && c != '-' && c != '.' &&
        c != 'E' && c != 'e') {
      return std::nullopt;
    }
  }
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

long long TypeBytes(char type) {
  switch (type) {
    case 'L': case 'B': case 'A': return 1;
    case 'I': return 2;
    case 'J': case 'E': case 'P': return 4 * (type == 'P' ? 2 : 1);
    case 'K': case 'D': case 'C': case 'Q': return type == 'Q' ? 16 : 8;
    case 'M': return 16;
    default: return 0;
  }
}

// Parses TFORMn ("1PB(43)", "8A", "1QB", "16X"). False if it is not a binary-table form.
bool ParseTform(const std::string& form, TableColumn* column) {
  std::string s = ToUpper(form);
  while (!s.empty() && s.front() == ' ') s.erase(s.begin());
  size_t i = 0;
  while (i < s.size() && std::isdigit(static_cast<unsigned char>(s[i]))) ++i;
  if (i > 12) return false;
  column->repeat = i == 0 ? 1 : std::strtoll(s.substr(0, i).c_str(), nullptr, 10);
  if (i == s.size()) return false;
  column->type = s[i];
  if (column->type == 'X') {
    column->width = (column->repeat + 7) / 8;
  } else {
    const long long bytes = TypeBytes(column->type);
    if (bytes == 0) return false;
    column->width = column->repeat * bytes;
  }
  if (column->type == 'P' || column->type == 'Q') {
    if (i + 1 >= s.size() || TypeBytes(s[i + 1]) == 0 || s[i + 1] == 'P' || s[i + 1] == 'Q') {
      return false;
    }
    column->element = s[i + 1];
  }
  return true;
}



// Reads the keywords of a tile-compressed image and refuses those CFITSIO could not parse
// safely (imcomp_get_compressed_image_par divides by the tile sizes and by the RICE block
// size, and sizes its buffers from the tiles).
bool ScreenTiledImage(const HeaderCards& cards, const std::string& where, HduLayout* hdu,
                      std::string* error) {
  TiledImage& image = hdu->image;
  auto fail = [&](const std::string& what) {
    *error = where + ": tile-compressed image: " + what;
    return false;
  };
  auto value = [&](const std::string& name) -> const CardValue* {
    const auto it = cards.values.find(name);
    return it == cards.values.end() ? nullptr : &it->second;
  };
  auto integer = [&](const std::string& name, std::optional<long long> fallback,
                     long long* out) -> bool {
    const CardValue* v = value(name);
    if (v == nullptr) {
      if (!fallback) return fail(name + " is missing");
      *out = *fallback;
      return true;
    }
    const std::optional<long long> n = ParseStrictInteger(*v);
    if (!n) return fail(name + " = '" + Printable(v->text) + "' is not an integer");
    *out = *n;
    return true;
  };

  const CardValue* type = value("ZCMPTYPE");
  if (type == nullptr) return fail("ZCMPTYPE is missing");
  image.compression = ToUpper(type->text);
  if (image.compression == "RICE_ONE") image.compression = "RICE_1";
  static const std::set<std::string> kKnown = {"RICE_1",  "GZIP_1", "GZIP_2",    "HCOMPRESS_1",
                                               "BZIP2_1", "PLIO_1", "NOCOMPRESS"};
  if (kKnown.count(image.compression) == 0) {
    return fail("unknown compression ZCMPTYPE = '" + Printable(type->text) + "'");
  }
  long long zbitpix = 0, zndim = 0;
  if (!integer("ZBITPIX", std::nullopt, &zbitpix) || !integer("ZNAXIS", std::nullopt, &zndim)) {
    return false;
  }
  if (zbitpix != 8 && zbitpix != 16 && zbitpix != 32 && zbitpix != 64 && zbitpix != -32 &&
      zbitpix != -64) {
    return fail("ZBITPIX = " + std::to_string(zbitpix) + " is not 8, 16, 32, 64, -32 or -64");
  }
  if (zndim < 1 || zndim > kMaxCompressDim) {
    return fail("ZNAXIS = " + std::to_string(zndim) + " is outside 1.." +
                std::to_string(kMaxCompressDim));
  }
  long long tiles = 1, tile_pixels = 1;
  for (int i = 1; i <= zndim; ++i) {
    const std::string n = std::to_string(i);
    long long axis = 0, tile = 0;
    if (!integer("ZNAXIS" + n, std::nullopt, &axis)) return false;
    if (axis < 1) return fail("ZNAXIS" + n + " = " + std::to_string(axis) + " is not positive");
    // CFITSIO's defaults: a tile is one row of the image.
    if (!integer("ZTILE" + n, i == 1 ? axis : 1, &tile)) return false;
    if (tile < 1 || tile > axis) {
      return fail("ZTILE" + n + " = " + std::to_string(tile) + " is outside 1..ZNAXIS" + n +
                  " (" + std::to_string(axis) + ")");
    }
    image.axes.push_back(axis);
    image.tile.push_back(tile);
    // Each factor is at most the axis: the products stay below the image's pixel count,
    // which the size check below bounds before any use (computed in double there).
    tiles = CheckedProduct(tiles, (axis - 1) / tile + 1).value_or(-1);
    tile_pixels = CheckedProduct(tile_pixels, tile).value_or(-1);
    if (tiles < 0 || tile_pixels < 0) return fail("the image's size overflows");
  }
  const std::string too_large = CheckImageSize(where, image.axes);
  if (!too_large.empty()) {
    *error = too_large;
    return false;
  }
  // CFITSIO keeps a tile's pixel count and its byte size (up to 8 bytes a pixel) in ints.
  if (tile_pixels > INT_MAX / 8) {
    return fail("a tile of " + std::to_string(tile_pixels) + " pixels is larger than " +
                std::to_string(INT_MAX / 8) + ", the most CFITSIO can decompress");
  }
  if (tiles != hdu->naxes[1]) {
    return fail("the table has " + std::to_string(hdu->naxes[1]) + " rows but the image " +
                std::to_string(tiles) + " tiles (ZNAXISn / ZTILEn)");
  }
  if (image.compression == "RICE_1") {
    // As CFITSIO reads them: ZVAL1 the block size (required), ZVAL2 the bytes per pixel
    // (default 4), swapped when a writer put them the other way round.
    long long block = 0, bytepix = 0;
    if (!integer("ZVAL1", std::nullopt, &block) || !integer("ZVAL2", 4, &bytepix)) return false;
    if (block < 16 && bytepix > 8) std::swap(block, bytepix);
    if (block < 1 || block > 65536) {
      return fail("RICE_1 block size " + std::to_string(block) + " (ZVAL1) is outside 1..65536");
    }
    if (bytepix != 1 && bytepix != 2 && bytepix != 4 && bytepix != 8) {
      return fail("RICE_1 bytes per pixel " + std::to_string(bytepix) +
                  " (ZVAL2) is not 1, 2, 4 or 8");
    }
    image.rice_block = static_cast<int>(block);
    image.rice_bytepix = static_cast<int>(bytepix);
  }
  // The dither offset indexes CFITSIO's table of 10000 random numbers.
  if (value("ZDITHER0") != nullptr) {
    long long dither = 0;
    if (!integer("ZDITHER0", std::nullopt, &dither)) return false;
    if (dither < 1 || dither > 10000) {
      return fail("ZDITHER0 = " + std::to_string(dither) + " is outside 1..10000");
    }
  }

  // The columns, for the tile checks made when the image is read.
  long long fields = 0;
  if (!integer("TFIELDS", std::nullopt, &fields)) return false;
  if (fields < 1 || fields > 999) {
    return fail("TFIELDS = " + std::to_string(fields) + " is outside 1..999");
  }
  long long offset = 0;
  for (int i = 1; i <= fields; ++i) {
    const std::string n = std::to_string(i);
    TableColumn column;
    const CardValue* form = value("TFORM" + n);
    if (form == nullptr || !ParseTform(form->text, &column)) {
      image.column_problem = "TFORM" + n + " is missing or unreadable";
      break;
    }
    column.form = form->text;
    if (const CardValue* name = value("TTYPE" + n)) column.name = ToUpper(name->text);
    column.offset = offset;
    offset += column.width;
    if (offset > hdu->naxes[0]) {
      image.column_problem = "its columns are wider than NAXIS1 = " + std::to_string(hdu->naxes[0]);
      break;
    }
    int* slot = column.name == "COMPRESSED_DATA"        ? &image.data_column
                : column.name == "GZIP_COMPRESSED_DATA" ? &image.gzip_column
                : column.name == "UNCOMPRESSED_DATA"    ? &image.raw_column
                                                        : nullptr;
    if (slot != nullptr) {
      if (*slot >= 0) {
        image.column_problem = "two columns are named " + column.name;
        break;
      }
      *slot = static_cast<int>(hdu->columns.size());
    }
    hdu->columns.push_back(column);
  }
  if (image.column_problem.empty() && image.data_column < 0) {
    image.column_problem = "it has no COMPRESSED_DATA column";
  }
  return true;
}

}  // namespace

// Walks every HDU of `bytes` as CFITSIO will (see above). False with a one-line reason if
// the file must not reach CFITSIO; *hdus receives the HDUs whose headers are complete.
bool ScreenFile(const FileBytes& bytes, const std::string& path, std::vector<HduLayout>* hdus,
                std::string* error) {
  hdus->clear();
  long long start = 0;
  for (int number = 1; start < bytes.size(); ++number) {
    HeaderCards cards;
    if (!ReadHeaderCards(bytes, start, &cards)) return true;  // truncated: CFITSIO says so
    // Past the first HDU, anything but an extension ends what CFITSIO will read.
    if (cards.first_name != (number == 1 ? "SIMPLE" : "XTENSION")) return true;
    const std::string where = HduWhere(path, number);
    auto corrupt = [&](const std::string& what) {
      *error = where + ": the header is corrupt (" + what + ")";
      return false;
    };
    if (!cards.conflict.empty()) {
      return corrupt(cards.conflict + " is given twice with different values");
    }
    // A column name must be a quoted string (standard section 7.2.2), which fits a card in at
    // most 68 characters. CFITSIO copies TTYPEn's value into a 70-byte field unchecked, so an
    // unquoted value of 70 characters overflowed it (found by the fuzzer, as "TTYPE1  = ",
    // "TTYPE+1 = " and "TTYPE0001=").
    for (const auto& [name, value] : cards.values) {
      if (name.rfind("TTYPE", 0) == 0 && !value.quoted) {
        return corrupt(name + " = '" + Printable(value.text) + "' is not a quoted string");
      }
    }
    // CFITSIO reads the mandatory keywords by position (standard section 4.4.1), and sizes
    // allocations from them even when it then fails: a NAXIS1 it could not parse, or a card
    // out of place, gave a calloc of 2^54 bytes from an unset variable. They must be where
    // the standard puts them, as plain integers, in headers cut short too.
    {
      std::vector<std::string> order = {"BITPIX", "NAXIS"};
      for (size_t i = 0; i < order.size(); ++i) {
        if (i + 1 >= cards.leading.size()) break;  // the file ends first
        const auto& [name, value] = cards.leading[i + 1];
        if (name != order[i]) return corrupt("card " + std::to_string(i + 2) + " is '" +
                                             Printable(name) + "', expected " + order[i]);
        const std::optional<long long> n = ParseStrictInteger(value);
        if (!n) return corrupt(name + " = '" + Printable(value.text) + "' is not an integer");
        if (name == "NAXIS") {
          if (*n < 0 || *n > 999) {
            return corrupt("NAXIS = " + std::to_string(*n) + " is outside 0..999");
          }
          for (long long k = 1; k <= *n; ++k) order.push_back("NAXIS" + std::to_string(k));
          if (number > 1) {
            order.push_back("PCOUNT");
            order.push_back("GCOUNT");
            const auto x = cards.values.find("XTENSION");
            const std::string type = x == cards.values.end() ? "" : ToUpper(x->second.text);
            if (type == "BINTABLE" || type == "A3DTABLE" || type == "TABLE") {
              order.push_back("TFIELDS");
            }
          }
        }
      }
    }
    if (!cards.complete) return true;  // CFITSIO reports the truncation itself
    // SIMPLE = F says the file does not conform to the standard (section 4.4.1.1): nothing
    // in it can be read as the standard says.
    if (number == 1) {
      const auto simple = cards.values.find("SIMPLE");
      if (simple == cards.values.end() || simple->second.text != "T") {
        return corrupt("SIMPLE = " +
                       Printable(simple == cards.values.end() ? "" : simple->second.text) +
                       ": the file does not claim to conform to the FITS standard");
      }
    }
    // The pixels' scaling: CFITSIO takes a BSCALE it cannot parse ("NAN") as 1 and goes on.
    for (const char* name : {"BSCALE", "BZERO"}) {
      const auto it = cards.values.find(name);
      if (it == cards.values.end()) continue;
      const std::optional<double> v = ParseFiniteReal(it->second);
      if (!v || (*v == 0.0 && std::strcmp(name, "BSCALE") == 0)) {
        return corrupt(std::string(name) + " = " + Printable(it->second.text) +
                       (v ? " scales every pixel to 0" : " is not a finite number"));
      }
    }
    auto integer = [&](const std::string& name, std::optional<long long> fallback,
                       long long* out) -> bool {
      const auto it = cards.values.find(name);
      if (it == cards.values.end()) {
        if (!fallback) return corrupt(name + " is missing");
        *out = *fallback;
        return true;
      }
      const std::optional<long long> n = ParseStrictInteger(it->second);
      if (!n) return corrupt(name + " = '" + Printable(it->second.text) + "' is not an integer");
      *out = *n;
      return true;
    };

    HduLayout hdu;
    hdu.number = number;
    hdu.data_start = cards.end;
    long long bitpix = 0, naxis = 0, gcount = 1;
    if (!integer("BITPIX", std::nullopt, &bitpix) || !integer("NAXIS", std::nullopt, &naxis) ||
        !integer("PCOUNT", 0, &hdu.pcount) || !integer("GCOUNT", 1, &gcount)) {
      return false;
    }
    if (bitpix != 8 && bitpix != 16 && bitpix != 32 && bitpix != 64 && bitpix != -32 &&
        bitpix != -64) {
      return corrupt("BITPIX = " + std::to_string(bitpix) + " is not 8, 16, 32, 64, -32 or -64");
    }
    if (naxis < 0 || naxis > 999) {
      return corrupt("NAXIS = " + std::to_string(naxis) + " is outside 0..999");
    }
    for (int i = 1; i <= naxis; ++i) {
      long long n = 0;
      if (!integer("NAXIS" + std::to_string(i), std::nullopt, &n)) return false;
      if (n < 0) return corrupt("NAXIS" + std::to_string(i) + " = " + std::to_string(n) + " is negative");
      hdu.naxes.push_back(n);
    }
    if (hdu.pcount < 0) return corrupt("PCOUNT = " + std::to_string(hdu.pcount) + " is negative");
    const auto groups = cards.values.find("GROUPS");
    const bool random_groups = number == 1 && naxis >= 1 && hdu.naxes[0] == 0 &&
                               groups != cards.values.end() && groups->second.text == "T";
    if (!random_groups && gcount != 1) {
      return corrupt("GCOUNT = " + std::to_string(gcount) + ", expected 1");
    }
    if (gcount < 0) return corrupt("GCOUNT = " + std::to_string(gcount) + " is negative");
    std::string extension;
    if (number > 1) {
      const auto it = cards.values.find("XTENSION");
      extension = it == cards.values.end() ? "" : ToUpper(it->second.text);
    }
    hdu.table = extension == "BINTABLE" || extension == "A3DTABLE" || extension == "TABLE";

    // The data unit: |BITPIX| / 8 x GCOUNT x (PCOUNT + NAXIS1 x ... x NAXISn), NAXIS1 left
    // out for random groups (standard section 4.4.1.1 and 6).
    std::optional<long long> elements = naxis == 0 ? 0 : 1;
    for (int i = random_groups ? 1 : 0; i < naxis && elements; ++i) {
      elements = CheckedProduct(*elements, hdu.naxes[i]);
    }
    std::optional<long long> data_bytes;
    if (elements && *elements <= (1LL << 62) - hdu.pcount) {
      data_bytes = CheckedProduct(*elements + hdu.pcount, gcount);
      if (data_bytes) data_bytes = CheckedProduct(*data_bytes, std::abs(bitpix) / 8);
    }
    if (!data_bytes || hdu.data_start > (1LL << 62) - *data_bytes - kBlock) {
      return corrupt("the data size overflows");
    }
    hdu.data_bytes = *data_bytes;

    if (!hdu.table && naxis > 0 && !random_groups) {
      const std::string too_large = CheckImageSize(where, hdu.naxes);
      if (!too_large.empty()) {
        *error = too_large;
        return false;
      }
    }
    if (extension == "BINTABLE" || extension == "A3DTABLE") {
      if (bitpix != 8 || naxis != 2) {
        return corrupt("a binary table needs BITPIX = 8 and NAXIS = 2");
      }
      const long long main_bytes = hdu.naxes[0] * hdu.naxes[1];  // bounded by data_bytes
      if (!integer("THEAP", main_bytes, &hdu.heap_offset)) return false;
      const auto zimage = cards.values.find("ZIMAGE");
      hdu.tiled = zimage != cards.values.end() && zimage->second.text != "F";
      if (hdu.tiled && !ScreenTiledImage(cards, where, &hdu, error)) return false;
    }
    hdus->push_back(std::move(hdu));
    start = hdus->back().data_start + (hdus->back().data_bytes + kBlock - 1) / kBlock * kBlock;
  }
  return true;
}

namespace {

// Walks a RICE_1 stream exactly as CFITSIO's decoder (fits_rdecomp, fits_rdecomp_short and
// fits_rdecomp_byte in ricecomp.c, CFITSIO 3.x-4.x) consumes it, without decoding, and
// says whether every byte it reads lies within the stream's `length` bytes. CFITSIO's own
// decoder checks the end only after each block and runs freely through zero bytes, so a
// corrupt stream makes it read beyond its buffer.
bool RiceStreamStaysInside(const unsigned char* stream, size_t length, long long pixels,
                           int block, int bytepix) {
  // Bits of the split-level code, its largest value (direct coding), bits of a direct
  // value, and the raw bytes of the first pixel, per pixel size.
  int fsbits = 5, fsmax = 25, bbits = 32, first = 4;
  if (bytepix == 1) {
    fsbits = 3, fsmax = 6, bbits = 8, first = 1;
  } else if (bytepix == 2) {
    fsbits = 4, fsmax = 14, bbits = 16, first = 2;
  }
  size_t at = static_cast<size_t>(first);
  auto next = [&](unsigned int* byte) {
    if (at >= length) return false;
    *byte = stream[at++];
    return true;
  };
  unsigned int b = 0, byte = 0;
  if (!next(&b)) return false;
  int nbits = 8;
  for (long long i = 0; i < pixels;) {
    nbits -= fsbits;
    while (nbits < 0) {
      if (!next(&byte)) return false;
      b = (b << 8) | byte;
      nbits += 8;
    }
    const int fs = static_cast<int>(b >> nbits) - 1;
    b &= (1u << nbits) - 1;
    const long long end = std::min(pixels, i + block);
    if (fs < 0) {
      i = end;  // all differences zero: nothing more to read
    } else if (fs == fsmax) {
      for (; i < end; ++i) {  // direct coding: bbits bits a pixel
        for (int k = bbits - nbits - 8; k >= 0; k -= 8) {
          if (!next(&b)) return false;
        }
        if (nbits > 0) {
          if (!next(&b)) return false;
          b &= (1u << nbits) - 1;
        } else {
          b = 0;
        }
      }
    } else {
      for (; i < end; ++i) {  // Rice coding: a unary part, then fs bits
        while (b == 0) {
          nbits += 8;
          if (!next(&b)) return false;
        }
        int top = 0;  // bits of b below and including its leading one
        for (unsigned int v = b; v != 0; v >>= 1) ++top;
        nbits = top - 1;
        b ^= 1u << nbits;
        nbits -= fs;
        while (nbits < 0) {
          if (!next(&byte)) return false;
          b = (b << 8) | byte;
          nbits += 8;
        }
        b &= (1u << nbits) - 1;
      }
    }
  }
  return true;
}

// The (element count, heap offset) descriptor of `row` (0-based) in a P or Q column.
bool ReadDescriptor(const FileBytes& bytes, const HduLayout& hdu, const TableColumn& column,
                    long long row, long long* count, long long* offset) {
  unsigned char raw[16];
  const size_t size = column.type == 'Q' ? 16 : 8;
  if (!bytes.Read(hdu.data_start + row * hdu.naxes[0] + column.offset, size, raw)) return false;
  auto big_endian = [&](int from, int n) {
    unsigned long long v = 0;
    for (int k = 0; k < n; ++k) v = (v << 8) | raw[from + k];
    // Signed, as the standard stores them (a negative value is then refused).
    return n == 4 ? static_cast<long long>(static_cast<int32_t>(v)) : static_cast<long long>(v);
  };
  const int half = static_cast<int>(size / 2);
  *count = big_endian(0, half);
  *offset = big_endian(half, half);
  return true;
}

}  // namespace

// Checks every tile of the tile-compressed image `hdu` before CFITSIO decompresses it:
// each descriptor must point inside the heap; a RICE_1 stream must stay inside its bytes;
// a GZIP stream must inflate to at most the tile's pixels at 8 bytes each. Compression
// types whose decoders cannot be checked so (HCOMPRESS_1, PLIO_1, BZIP2_1, NOCOMPRESS) are
// refused. False with a one-line reason.
bool CheckTiles(const FileBytes& bytes, const HduLayout& hdu, const std::string& where,
                std::string* error) {
  const TiledImage& image = hdu.image;
  auto fail = [&](const std::string& what) {
    *error = where + ": tile-compressed image: " + what;
    return false;
  };
  const bool rice = image.compression == "RICE_1";
  if (!rice && image.compression != "GZIP_1" && image.compression != "GZIP_2") {
    return fail("compression " + image.compression +
                " is not supported (RICE_1, GZIP_1 and GZIP_2 are)");
  }
  if (!image.column_problem.empty()) return fail(image.column_problem);
  auto byte_stream_column = [&](int index) {
    const TableColumn& c = hdu.columns[index];
    return (c.type == 'P' || c.type == 'Q') && c.element == 'B' && c.repeat <= 1;
  };
  for (int index : {image.data_column, image.gzip_column}) {
    if (index >= 0 && !byte_stream_column(index)) {
      return fail("column " + hdu.columns[index].name + " has TFORM '" +
                  Printable(hdu.columns[index].form) + "', expected 1PB or 1QB");
    }
  }
  if (image.raw_column >= 0) {
    const TableColumn& c = hdu.columns[image.raw_column];
    if ((c.type != 'P' && c.type != 'Q') || c.repeat > 1) {
      return fail("column UNCOMPRESSED_DATA has TFORM '" + Printable(c.form) + "'");
    }
  }
  const long long main_bytes = hdu.naxes[0] * hdu.naxes[1];
  const long long heap_end = main_bytes + hdu.pcount;  // within the data unit
  if (hdu.heap_offset < main_bytes || hdu.heap_offset > heap_end) {
    return fail("THEAP = " + std::to_string(hdu.heap_offset) + " is outside the data unit");
  }
  if (hdu.data_start + hdu.data_bytes > bytes.size()) {
    return fail("the file is truncated (the table needs " +
                std::to_string(hdu.data_start + hdu.data_bytes) + " bytes, the file has " +
                std::to_string(bytes.size()) + ")");
  }

  // The tiles' pixel counts: tiles at the image's far edges are cut short.
  const size_t ndim = image.axes.size();
  std::vector<long long> per_axis(ndim);
  long long largest_tile = 1;
  for (size_t d = 0; d < ndim; ++d) {
    per_axis[d] = (image.axes[d] - 1) / image.tile[d] + 1;
    largest_tile *= image.tile[d];
  }
  // A GZIP tile may inflate to at most a tile's pixels x 8 bytes (CFITSIO accepts 1, 2, 4
  // or 8), with 64 bytes to spare so that a stream of exactly that size ends. One scratch
  // block, grown as a stream needs it (never beyond the limit) and reused.
  const size_t inflate_limit = static_cast<size_t>(largest_tile) * 8 + 64;
  struct Scratch {
    char* block = nullptr;
    size_t capacity = 0;
    ~Scratch() { std::free(block); }
  } scratch;
  std::vector<unsigned char> stream;

  for (long long row = 0; row < hdu.naxes[1]; ++row) {
    long long pixels = 1, rest = row;
    for (size_t d = 0; d < ndim; ++d) {
      const long long index = rest % per_axis[d];
      rest /= per_axis[d];
      pixels *= std::min(image.tile[d], image.axes[d] - index * image.tile[d]);
    }
    const std::string tile = "tile " + std::to_string(row + 1);
    // The column holding this tile: COMPRESSED_DATA; for an empty descriptor, as CFITSIO
    // falls back, UNCOMPRESSED_DATA if the table has it, else GZIP_COMPRESSED_DATA.
    long long count = 0, offset = 0;
    int column_index = image.data_column;
    if (!ReadDescriptor(bytes, hdu, hdu.columns[column_index], row, &count, &offset)) {
      return fail(tile + "'s descriptor lies beyond the end of the file");
    }
    if (count == 0) {
      column_index = image.raw_column >= 0 ? image.raw_column : image.gzip_column;
      if (column_index < 0) return fail(tile + " holds no data");
      if (!ReadDescriptor(bytes, hdu, hdu.columns[column_index], row, &count, &offset)) {
        return fail(tile + "'s descriptor lies beyond the end of the file");
      }
      if (count == 0 && column_index == image.raw_column) continue;  // CFITSIO reads nothing
      if (count == 0) return fail(tile + " holds no data");
    }
    const TableColumn& column = hdu.columns[column_index];
    const long long element = TypeBytes(column.element);
    const std::optional<long long> span = CheckedProduct(count, element);
    if (count < 0 || offset < 0 || !span || count > INT_MAX ||
        offset > heap_end - hdu.heap_offset || *span > heap_end - hdu.heap_offset - offset) {
      return fail(tile + "'s data (" + std::to_string(count) + " x " + std::to_string(element) +
                  " bytes at heap offset " + std::to_string(offset) +
                  ") lie outside the heap of " + std::to_string(heap_end - hdu.heap_offset) +
                  " bytes");
    }
    if (column_index == image.raw_column) {
      if (count > pixels) {
        return fail(tile + " holds " + std::to_string(count) + " uncompressed values for " +
                    std::to_string(pixels) + " pixels");
      }
      continue;
    }
    stream.resize(static_cast<size_t>(count));
    if (!bytes.Read(hdu.data_start + hdu.heap_offset + offset, stream.size(), stream.data())) {
      return fail(tile + "'s data lie beyond the end of the file");
    }
    if (rice && column_index == image.data_column) {
      if (!RiceStreamStaysInside(stream.data(), stream.size(), pixels, image.rice_block,
                                 image.rice_bytepix)) {
        return fail(tile + "'s RICE_1 stream is corrupt (it ends before its " +
                    std::to_string(pixels) + " pixels)");
      }
      continue;
    }
    // GZIP_1 / GZIP_2 tiles, and the gzip fallback column.
    if (scratch.block == nullptr) {
      scratch.capacity = std::min(inflate_limit, size_t{1} << 16);
      scratch.block = static_cast<char*>(std::malloc(scratch.capacity));
      if (scratch.block == nullptr) return fail("out of memory");
    }
    char* buffer = scratch.block;
    size_t buffer_size = scratch.capacity;
    size_t out = 0;
    int status = 0;
    t_budget = GrowthBudget{inflate_limit, scratch.capacity, nullptr, false};
    uncompress2mem_from_mem(reinterpret_cast<char*>(stream.data()), stream.size(), &buffer,
                            &buffer_size, BoundedRealloc, &out, &status);
    // The block may have grown (moved), or been refused (parked in the budget).
    scratch.block = buffer != nullptr ? buffer : static_cast<char*>(t_budget.refused);
    scratch.capacity = t_budget.capacity;
    const bool hit_limit = t_budget.hit_limit;
    t_budget = GrowthBudget{};
    if (status != 0) {
      return fail(tile + (hit_limit ? "'s gzip stream inflates to more than its " +
                                          std::to_string(pixels) + " pixels"
                                    : "'s gzip stream is corrupt"));
    }
  }
  return true;
}

}  // namespace internal
}  // namespace ccdpsf
