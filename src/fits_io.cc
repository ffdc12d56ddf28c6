// FITS input and output through CFITSIO.
//
// Files are opened and created with the "diskfile" entry points (fits_open_diskfile,
// fits_create_diskfile), which take the name literally: CFITSIO's extended filename syntax
// would otherwise read "run[1].fits" as "extension 1 of run" and "!out.fits" as "overwrite
// out.fits". Every fitsfile* lives in a FitsFile, which closes it on every path.
#include "ccdpsf/fits_io.h"

#include <fitsio.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "internal/fits_screen.h"
#include "internal/text.h"

namespace ccdpsf {
namespace {

using internal::CheckImageSize;
using internal::CheckTiles;
using internal::FileBytes;
using internal::FormatBytes;
using internal::Gunzip;
using internal::HduLayout;
using internal::HduWhere;
using internal::IsIndexed;
using internal::Printable;
using internal::Quoted;
using internal::ScreenFile;
using internal::ToUpper;

// Owns an open fitsfile*. The destructor closes the file and ignores any error (it must not
// throw and has nobody to tell); writers call Close() themselves to learn whether the final
// flush succeeded.
class FitsFile {
 public:
  FitsFile() = default;
  ~FitsFile() {
    int status = 0;
    Close(&status);
  }
  FitsFile(const FitsFile&) = delete;
  FitsFile& operator=(const FitsFile&) = delete;

  fitsfile* get() const { return file_; }
  // For the CFITSIO calls that open or create a file.
  fitsfile** out() { return &file_; }

  // Closes the file (flushing buffers). Returns false and sets *status on failure; the
  // handle is released either way.
  bool Close(int* status) {
    if (file_ == nullptr) return true;
    fits_close_file(file_, status);
    file_ = nullptr;
    return *status == 0;
  }

 private:
  fitsfile* file_ = nullptr;
};

// The short CFITSIO description of `status`, as "cfitsio status N: text". Clears CFITSIO's
// message stack so that messages of one failure do not leak into the next.
std::string CfitsioText(int status) {
  char text[FLEN_STATUS] = {0};
  fits_get_errstatus(status, text);
  fits_clear_errmsg();
  return "cfitsio status " + std::to_string(status) + ": " + text;
}




// Keywords that describe the layout of the HDU (or are commentary) rather than the exposure.
// They are neither returned by the reader nor accepted from callers by the writers, because
// CFITSIO writes them itself and a second copy would contradict the data.
bool IsStructuralKeyword(const std::string& upper_name) {
  static const std::set<std::string> kNames = {
      "SIMPLE", "BITPIX",  "NAXIS",    "EXTEND",   "BZERO",   "BSCALE",  "BLANK",
      "PCOUNT", "GCOUNT",  "XTENSION", "END",      "COMMENT", "HISTORY", "CONTINUE",
      "",       "TFIELDS", "THEAP",    "CHECKSUM", "DATASUM", "LONGSTRN"};
  return kNames.count(upper_name) > 0 || IsIndexed(upper_name, "NAXIS");
}

// Keywords of the binary table that holds a tile-compressed image; CFITSIO presents the
// image transparently, but header reads see the table's cards.
bool IsCompressionKeyword(const std::string& upper_name) {
  static const char* const kIndexed[] = {"TTYPE", "TFORM",  "TUNIT", "TDIM",  "TSCAL", "TZERO",
                                         "TNULL", "ZNAXIS", "ZTILE", "ZNAME", "ZVAL"};
  for (const char* prefix : kIndexed) {
    if (IsIndexed(upper_name, prefix)) return true;
  }
  static const std::set<std::string> kNames = {
      "ZIMAGE",   "ZBITPIX",  "ZNAXIS",   "ZCMPTYPE", "ZQUANTIZ", "ZDITHER0",
      "ZSIMPLE",  "ZEXTEND",  "ZBLOCKED", "ZTENSION", "ZPCOUNT",  "ZGCOUNT",
      "ZHECKSUM", "ZDATASUM", "ZBLANK",   "ZSCALE",   "ZZERO"};
  return kNames.count(upper_name) > 0;
}

// Parses a number the way FITS writes it (Fortran 'D' exponents allowed). The whole text,
// surrounding blanks aside, must be the number.
std::optional<double> ParseNumber(const std::string& text) {
  std::string s = text;
  const size_t first = s.find_first_not_of(" \t");
  if (first == std::string::npos) return std::nullopt;
  const size_t last = s.find_last_not_of(" \t");
  s = s.substr(first, last - first + 1);
  for (char& c : s) {
    if (c == 'D' || c == 'd') c = 'E';
  }
  errno = 0;
  char* end = nullptr;
  const double value = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0') return std::nullopt;
  // ERANGE on underflow still yields a usable (tiny or zero) value; on overflow, +-HUGE_VAL
  // is the honest answer for "larger than a double".
  return value;
}

// The text of a FITS string value: 'It''s here  ' -> "It's here" (quotes doubled inside,
// trailing blanks not significant; FITS standard 4.0, section 4.2.1).
std::string UnquoteFitsString(const char* value_text) {
  std::string text = value_text;
  const size_t open = text.find('\'');
  if (open == std::string::npos) return text;
  std::string result;
  for (size_t i = open + 1; i < text.size(); ++i) {
    if (text[i] == '\'') {
      if (i + 1 < text.size() && text[i + 1] == '\'') {
        result.push_back('\'');
        ++i;
        continue;
      }
      break;  // closing quote
    }
    result.push_back(text[i]);
  }
  const size_t last = result.find_last_not_of(' ');
  result.erase(last == std::string::npos ? 0 : last + 1);
  return result;
}

// Converts one header card's value text (as CFITSIO returns it) to a FitsKey value.
// Returns false for cards without a value.
bool ParseCardValue(fitsfile* file, const char* name, const char* value_text, int card,
                    int num_cards, FitsKey* key) {
  int status = 0;
  char type = 0;
  if (value_text[0] == '\0' || fits_get_keytype(value_text, &type, &status)) {
    fits_clear_errmsg();
    return false;
  }
  switch (type) {
    case 'C': {
      std::string value = UnquoteFitsString(value_text);
      // A long string continued on CONTINUE cards ends in '&'; let CFITSIO assemble it.
      if (!value.empty() && value.back() == '&' && card < num_cards) {
        char next_name[FLEN_KEYWORD] = {0};
        char next_value[FLEN_VALUE] = {0};
        char next_comment[FLEN_COMMENT] = {0};
        fits_read_keyn(file, card + 1, next_name, next_value, next_comment, &status);
        if (status == 0 && std::strcmp(next_name, "CONTINUE") == 0) {
          char* long_value = nullptr;
          char long_comment[FLEN_COMMENT] = {0};
          fits_read_key_longstr(file, name, &long_value, long_comment, &status);
          if (status == 0 && long_value != nullptr) value = long_value;
          if (long_value != nullptr) fits_free_memory(long_value, &status);
        }
        if (status != 0) fits_clear_errmsg();
      }
      key->value = value;
      return true;
    }
    case 'L':
      key->value = value_text[0] == 'T';
      return true;
    case 'I': {
      errno = 0;
      char* end = nullptr;
      const long long value = std::strtoll(value_text, &end, 10);
      if (errno == 0 && end != value_text) {
        key->value = value;
        return true;
      }
      // Too large for 64 bits: keep it as a double.
      const std::optional<double> number = ParseNumber(value_text);
      if (!number) return false;
      key->value = *number;
      return true;
    }
    case 'F': {
      const std::optional<double> number = ParseNumber(value_text);
      if (!number) return false;
      key->value = *number;
      return true;
    }
    default:
      // Complex numbers and anything else: keep the text.
      key->value = std::string(value_text);
      return true;
  }
}

// Collects the user keywords of the current HDU.
bool ReadHeader(fitsfile* file, bool compressed, FitsHeader* header, int* status) {
  int num_cards = 0;
  if (fits_get_hdrspace(file, &num_cards, nullptr, status)) return false;
  for (int card = 1; card <= num_cards; ++card) {
    char name[FLEN_KEYWORD] = {0};
    char value[FLEN_VALUE] = {0};
    char comment[FLEN_COMMENT] = {0};
    if (fits_read_keyn(file, card, name, value, comment, status)) return false;
    const std::string upper_name = ToUpper(name);
    if (IsStructuralKeyword(upper_name)) continue;
    if (compressed && IsCompressionKeyword(upper_name)) continue;
    FitsKey key;
    key.name = name;
    key.comment = comment;
    if (ParseCardValue(file, name, value, card, num_cards, &key)) {
      header->push_back(std::move(key));
    }
  }
  return true;
}

// True if every character is printable ASCII, the only characters a header card may hold
// (FITS standard 4.0, section 4.1.2). CFITSIO would silently turn others into blanks.
bool IsPrintableAscii(const std::string& text) {
  return std::all_of(text.begin(), text.end(), [](char c) { return c >= 0x20 && c <= 0x7e; });
}

// Keyword names: digits, letters, '-' and '_' (section 4.1.2.1; CFITSIO upper-cases them).
// Names longer than 8 characters are written with the HIERARCH convention.
bool IsValidKeywordName(const std::string& name) {
  if (name.empty() || name.size() > 60) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_';
  });
}

// Checks a header before writing it: valid names that are not structural, printable text,
// finite doubles (FITS has no representation for NaN or infinity in a card).
bool ValidateHeader(const std::string& path, const FitsHeader& header, std::string* error) {
  for (const FitsKey& key : header) {
    const std::string upper_name = ToUpper(key.name);
    if (!IsValidKeywordName(key.name)) {
      *error = "cannot write " + Quoted(path) + ": invalid keyword name '" + key.name + "'";
      return false;
    }
    const std::string* text = std::get_if<std::string>(&key.value);
    if (!IsPrintableAscii(key.comment) || (text != nullptr && !IsPrintableAscii(*text))) {
      *error = "cannot write " + Quoted(path) + ": keyword " + upper_name +
               " holds characters other than printable ASCII";
      return false;
    }
    if (IsStructuralKeyword(upper_name)) {
      *error = "cannot write " + Quoted(path) + ": keyword " + upper_name +
               " is reserved (the writer sets it)";
      return false;
    }
    if (const double* value = std::get_if<double>(&key.value); value && !std::isfinite(*value)) {
      *error =
          "cannot write " + Quoted(path) + ": keyword " + upper_name + " has a non-finite value";
      return false;
    }
  }
  return true;
}

// Writes the cards of `header` into the current HDU, replacing cards of the same name.
bool WriteHeader(fitsfile* file, const FitsHeader& header, int* status, std::string* failed) {
  for (const FitsKey& key : header) {
    char* comment = key.comment.empty() ? nullptr : const_cast<char*>(key.comment.c_str());
    char* name = const_cast<char*>(key.name.c_str());
    if (const double* value = std::get_if<double>(&key.value)) {
      // 15 significant digits: exact for every decimal a person typed, and as many as a
      // double carries reliably.
      fits_update_key_dbl(file, name, *value, -15, comment, status);
    } else if (const long long* value = std::get_if<long long>(&key.value)) {
      fits_update_key_lng(file, name, *value, comment, status);
    } else if (const bool* value = std::get_if<bool>(&key.value)) {
      fits_update_key_log(file, name, *value ? 1 : 0, comment, status);
    } else {
      const std::string& text = std::get<std::string>(key.value);
      // Strings longer than a card holds go out with the CONTINUE convention.
      if (text.size() > 68) {
        fits_update_key_longstr(file, name, const_cast<char*>(text.c_str()), comment, status);
      } else {
        fits_update_key_str(file, name, const_cast<char*>(text.c_str()), comment, status);
      }
    }
    if (*status != 0) {
      *failed = key.name;
      return false;
    }
  }
  return true;
}

bool ValidateImage(const std::string& path, const Image& image, std::string* error) {
  if (image.nx <= 0 || image.ny <= 0) {
    *error = "cannot write " + Quoted(path) + ": image is empty (" + std::to_string(image.nx) +
             " x " + std::to_string(image.ny) + ")";
    return false;
  }
  if (image.data.size() != static_cast<size_t>(image.nx) * static_cast<size_t>(image.ny)) {
    *error = "cannot write " + Quoted(path) + ": image holds " + std::to_string(image.data.size()) +
             " values, expected " + std::to_string(image.nx) + " x " + std::to_string(image.ny);
    return false;
  }
  return true;
}

// A name CFITSIO can take for `path`. CFITSIO keeps file names in buffers of FLEN_FILENAME
// (1025) bytes and cannot open a longer path ("could not open the named file"), which Linux
// allows up to 4096 bytes. A long path is handed over as /proc/self/fd/N/NAME, N an open
// descriptor of its folder; CFITSIO opens the file while this object lives and keeps its own
// handle after.
class CfitsioName {
 public:
  explicit CfitsioName(const std::string& path) : name_(path) {
    if (path.size() < FLEN_FILENAME - 1) return;
    const size_t slash = path.find_last_of('/');
    if (slash == std::string::npos) return;  // a 1 KB file name: the OS refuses it anyway
    const std::string folder = slash == 0 ? "/" : path.substr(0, slash);
    folder_fd_ = ::open(folder.c_str(), O_PATH | O_DIRECTORY | O_CLOEXEC);
    if (folder_fd_ >= 0) {
      name_ = "/proc/self/fd/" + std::to_string(folder_fd_) + "/" + path.substr(slash + 1);
    }
  }
  ~CfitsioName() {
    if (folder_fd_ >= 0) ::close(folder_fd_);
  }
  CfitsioName(const CfitsioName&) = delete;
  CfitsioName& operator=(const CfitsioName&) = delete;
  const char* c_str() const { return name_.c_str(); }

 private:
  std::string name_;
  int folder_fd_ = -1;
};

// Creates a new FITS file at temp_path. The name is fresh (WriteAtomically removes any stale
// file of that name first), so CFITSIO's refusal to overwrite never applies.
bool CreateFile(const std::string& temp_path, FitsFile* file, int* status) {
  const CfitsioName name(temp_path);
  fits_create_diskfile(file->out(), name.c_str(), status);
  return *status == 0;
}

// Formats the reason a write failed: the target (not the temporary) path, what was being
// done and CFITSIO's reason.
std::string WriteError(const std::string& path, const std::string& what, int status) {
  return "cannot write " + Quoted(path) + ": " + what + " (" + CfitsioText(status) + ")";
}

// Writes one 2-D image HDU (primary if the file is new, else an extension): the header
// cards and then the pixels. bitpix is DOUBLE_IMG or USHORT_IMG.
bool WriteImageHdu(fitsfile* file, const std::string& path, int bitpix, const Image& image,
                   const std::string& extname, const FitsHeader& header, std::string* error) {
  int status = 0;
  long naxes[2] = {image.nx, image.ny};
  if (fits_create_img(file, bitpix, 2, naxes, &status)) {
    *error = WriteError(path, "cannot create image HDU", status);
    return false;
  }
  if (!extname.empty()) {
    fits_update_key_str(file, const_cast<char*>("EXTNAME"), const_cast<char*>(extname.c_str()),
                        const_cast<char*>("extension name"), &status);
  }
  std::string failed_key;
  if (status != 0 || !WriteHeader(file, header, &status, &failed_key)) {
    *error = WriteError(
        path, "cannot write keyword " + (failed_key.empty() ? "EXTNAME" : failed_key), status);
    return false;
  }
  const LONGLONG n = static_cast<LONGLONG>(image.data.size());
  if (bitpix == USHORT_IMG) {
    // Values were checked by the caller to be integers in [0, 65535]; TUSHORT lets CFITSIO
    // apply BZERO = 32768 itself.
    std::vector<unsigned short> values(image.data.size());
    for (size_t i = 0; i < values.size(); ++i) {
      values[i] = static_cast<unsigned short>(image.data[i]);
    }
    fits_write_img(file, TUSHORT, 1, n, values.data(), &status);
  } else {
    // CFITSIO takes a non-const pointer; a copy keeps the caller's image untouched whatever
    // CFITSIO does with its buffer (it byte-swaps in place on little-endian machines for some
    // paths).
    std::vector<double> values = image.data;
    fits_write_img(file, TDOUBLE, 1, n, values.data(), &status);
  }
  if (status != 0) {
    *error = WriteError(path, "cannot write pixels", status);
    return false;
  }
  // No CHECKSUM/DATASUM cards: CFITSIO stamps the current date into their comments, and the
  // same inputs and seed must give the same bytes. Truncation is still caught on reading.
  return true;
}

// Writes an HDU with no data carrying `header` as the primary HDU.
bool WriteEmptyPrimary(fitsfile* file, const std::string& path, const FitsHeader& header,
                       std::string* error) {
  int status = 0;
  if (fits_create_img(file, BYTE_IMG, 0, nullptr, &status)) {
    *error = WriteError(path, "cannot create primary HDU", status);
    return false;
  }
  std::string failed_key;
  if (!WriteHeader(file, header, &status, &failed_key)) {
    *error = WriteError(path, "cannot write keyword " + failed_key, status);
    return false;
  }
  return true;
}

// Closes a file being written, reporting a failed final flush (a full disk shows up here).
bool CloseWritten(FitsFile* file, const std::string& path, std::string* error) {
  int status = 0;
  if (!file->Close(&status)) {
    *error = WriteError(path, "cannot close file", status);
    return false;
  }
  return true;
}

// Opening checks done before CFITSIO sees the file, so that the common mistakes get a plain
// message: no such file, a directory, an empty file, something that is not FITS. Sets
// *gzip for gzip-compressed files (decompressed by OpenForReading: their size on disk says
// nothing about the size of the data). Returns the file size in bytes, or -1 if it is not
// known.
std::optional<long long> CheckReadable(const std::string& path, bool* gzip, std::string* error) {
  // A regular file only: a FIFO or a device would block or never end (input_file.h).
  const int fd = OpenRegularFile(path, "", error);
  if (fd < 0) {
    if (error->rfind("cannot read ", 0) == 0) *error = "cannot open " + error->substr(12);
    return std::nullopt;
  }
  struct stat st;
  const bool have_size = ::fstat(fd, &st) == 0;
  std::FILE* stream = ::fdopen(fd, "rb");
  if (stream == nullptr) {
    *error = "cannot open " + Quoted(path) + ": " + std::strerror(errno);
    ::close(fd);
    return std::nullopt;
  }
  char start[10] = {0};
  const size_t got = std::fread(start, 1, sizeof(start), stream);
  std::fclose(stream);
  if (got == 0) {
    *error = Quoted(path) + " is not a FITS file (it is empty)";
    return std::nullopt;
  }
  *gzip = got >= 2 && static_cast<unsigned char>(start[0]) == 0x1f &&
          static_cast<unsigned char>(start[1]) == 0x8b;
  // Every FITS file starts with the card "SIMPLE  =" (FITS standard 4.0, section 4.4.1.1).
  // A file that starts so but is cut short is a truncated FITS file, not "not FITS".
  static const char kSimple[] = "SIMPLE  =";
  const size_t n = std::min(got, sizeof(kSimple) - 1);
  if (!*gzip && std::memcmp(start, kSimple, n) != 0) {
    *error = Quoted(path) + " is not a FITS file";
    return std::nullopt;
  }
  if (!*gzip && got < sizeof(kSimple) - 1) {
    *error = Quoted(path) + " is truncated or corrupt";
    return std::nullopt;
  }
  return have_size ? static_cast<long long>(st.st_size) : -1LL;
}

std::string Corrupt(const std::string& path, int status) {
  return Quoted(path) + " is truncated or corrupt (" + CfitsioText(status) + ")";
}

}  // namespace

std::optional<double> FindNumber(const FitsHeader& header, const std::string& name) {
  const std::string wanted = ToUpper(name);
  for (const FitsKey& key : header) {
    if (ToUpper(key.name) != wanted) continue;
    if (const double* value = std::get_if<double>(&key.value)) return *value;
    if (const long long* value = std::get_if<long long>(&key.value)) {
      return static_cast<double>(*value);
    }
    if (const std::string* value = std::get_if<std::string>(&key.value)) {
      return ParseNumber(*value);
    }
    return std::nullopt;  // a logical is not a number
  }
  return std::nullopt;
}

std::optional<std::string> FindString(const FitsHeader& header, const std::string& name) {
  const std::string wanted = ToUpper(name);
  for (const FitsKey& key : header) {
    if (ToUpper(key.name) != wanted) continue;
    if (const std::string* value = std::get_if<std::string>(&key.value)) return *value;
    return std::nullopt;
  }
  return std::nullopt;
}

namespace {

// The physical range of the stored integers (BZERO + BSCALE x raw, raw over BITPIX's range):
// an ADC cannot record values outside it, so a pixel at either end may be clipped there.
// Floating-point data have no such range.
void AdcRange(fitsfile* file, int bitpix, double* low, double* high) {
  *low = -std::numeric_limits<double>::infinity();
  *high = std::numeric_limits<double>::infinity();
  double raw_low = 0, raw_high = 0;
  switch (bitpix) {
    case BYTE_IMG: raw_low = 0; raw_high = 255; break;
    case SHORT_IMG: raw_low = -32768; raw_high = 32767; break;
    case LONG_IMG: raw_low = -2147483648.0; raw_high = 2147483647.0; break;
    default: return;  // 64-bit integers and floats: no useful range
  }
  int status = 0;
  double zero = 0.0, scale = 1.0;
  if (fits_read_key_dbl(file, "BZERO", &zero, nullptr, &status)) {
    zero = 0.0;
    status = 0;
  }
  if (fits_read_key_dbl(file, "BSCALE", &scale, nullptr, &status)) {
    scale = 1.0;
    status = 0;
  }
  fits_clear_errmsg();
  if (!std::isfinite(zero) || !std::isfinite(scale) || scale == 0.0) return;
  *low = std::min(zero + scale * raw_low, zero + scale * raw_high);
  *high = std::max(zero + scale * raw_low, zero + scale * raw_high);
}

// EXTNAME of the current HDU ("" if none).
std::string ExtName(fitsfile* file) {
  int status = 0;
  char value[FLEN_VALUE] = {0};
  if (fits_read_key_str(file, "EXTNAME", value, nullptr, &status)) {
    fits_clear_errmsg();
    return "";
  }
  std::string name = value;
  while (!name.empty() && name.back() == ' ') name.pop_back();
  return name;
}

// A file opened for reading: its bytes, the screen's view of its HDUs and CFITSIO's handle.
// Members are destroyed in reverse order, so CFITSIO lets go before the bytes it may be
// reading from memory are freed.
struct OpenedFits {
  FileBytes bytes;
  std::vector<HduLayout> hdus;
  FitsFile file;
  // CFITSIO's count of HDUs, taken once: fits_get_num_hdus walks every header from the
  // current HDU to the end at each call, which made reading each of N segments O(N^2).
  int num_hdus = 0;
};

// Checks the 2-D image of the current HDU (number `hdu`, 1-based absolute) before any pixel
// is read, and fills everything of *image but its pixels (header, BITPIX, HDU, EXTNAME, ADC
// range); *nx, *ny are its size.
bool DescribeCurrentImage(const OpenedFits& opened, const std::string& path, int hdu,
                          FitsImage* image, int* nx, int* ny, std::string* error) {
  fitsfile* file = opened.file.get();
  int status = 0;
  int naxis = 0;
  if (fits_get_img_dim(file, &naxis, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  const std::string where = HduWhere(path, hdu);
  if (naxis != 2) {
    *error = where + ": image is " + std::to_string(naxis) + "-D, expected 2-D";
    return false;
  }
  LONGLONG naxes[2] = {0, 0};
  int bitpix = 0;
  int compressed = 0;
  if (fits_get_img_sizell(file, 2, naxes, &status) ||
      fits_get_img_type(file, &bitpix, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  compressed = fits_is_compressed_image(file, &status);
  if (naxes[0] <= 0 || naxes[1] <= 0) {
    *error = where + ": image is empty (" + std::to_string(naxes[0]) + " x " +
             std::to_string(naxes[1]) + ")";
    return false;
  }
  // The screen has checked this already; CFITSIO's view of the size is checked again here,
  // where the memory is about to be allocated.
  const std::string too_large = CheckImageSize(where, {naxes[0], naxes[1]});
  if (!too_large.empty() || naxes[0] > INT_MAX || naxes[1] > INT_MAX) {
    *error = !too_large.empty() ? too_large
                                : where + ": image is too large (" + std::to_string(naxes[0]) +
                                      " x " + std::to_string(naxes[1]) + ")";
    return false;
  }
  if (hdu < 1 || hdu > static_cast<int>(opened.hdus.size()) ||
      opened.hdus[hdu - 1].tiled != (compressed != 0)) {
    *error = Quoted(path) + " is truncated or corrupt (CFITSIO and the reader's screen disagree "
             "about HDU " + std::to_string(hdu - 1) + ")";
    return false;
  }
  const HduLayout& layout = opened.hdus[hdu - 1];
  if (!compressed && layout.data_start + layout.data_bytes > opened.bytes.size()) {
    // The data must fit in the file: checking before reading gives a clear message and
    // avoids allocating for data that are not there.
    *error = Quoted(path) + " is truncated or corrupt (the image needs " +
             std::to_string(layout.data_start + layout.data_bytes) + " bytes, the file has " +
             std::to_string(opened.bytes.size()) + ")";
    return false;
  }
  // CHECKSUM and DATASUM, where the HDU has them (FITS standard 4.0, section 4.4.2.7): a file
  // damaged since they were written is refused, not fitted, since nothing says which of its
  // pixels changed (one flipped bit in a compressed tile changes a whole tile). Checked
  // before the tiles, so that damage is named as such. CFITSIO reads the HDU only when it
  // has either card.
  int data_sum = 0, hdu_sum = 0;
  if (fits_verify_chksum(file, &data_sum, &hdu_sum, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  if (data_sum < 0) {
    *error = where + " is damaged: its data do not match their DATASUM";
    return false;
  }
  if (hdu_sum < 0) {
    *error = where + " is damaged or was edited: its HDU does not match its CHECKSUM (after an "
             "edit, update CHECKSUM or remove it)";
    return false;
  }
  // Every tile is checked before CFITSIO decompresses any.
  if (compressed && !CheckTiles(opened.bytes, layout, where, error)) return false;
  image->bitpix = bitpix;
  image->hdu = hdu;
  image->extname = ExtName(file);
  AdcRange(file, bitpix, &image->adc_min, &image->adc_max);
  if (!ReadHeader(file, compressed != 0, &image->header, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  *nx = static_cast<int>(naxes[0]);
  *ny = static_cast<int>(naxes[1]);
  return true;
}

// Reads rows [y_begin, y_begin + rows) of the current HDU's nx-wide image into `out` as
// doubles. Reading as TDOUBLE makes CFITSIO apply BSCALE/BZERO; a NaN null value turns
// BLANK pixels of integer images (and NaNs of float images) into NaN.
bool ReadCurrentRows(fitsfile* file, const std::string& path, int nx, int y_begin, int rows,
                     double* out, std::string* error) {
  int status = 0;
  double null_value = std::numeric_limits<double>::quiet_NaN();
  int any_null = 0;
  LONGLONG first[2] = {1, static_cast<LONGLONG>(y_begin) + 1};
  if (fits_read_pixll(file, TDOUBLE, first, static_cast<LONGLONG>(nx) * rows, &null_value, out,
                      &any_null, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  return true;
}

// Reads the 2-D image of the current HDU (number `hdu`, 1-based absolute).
std::optional<FitsImage> ReadCurrentImage(const OpenedFits& opened, const std::string& path,
                                          int hdu, std::string* error) {
  FitsImage result;
  int nx = 0, ny = 0;
  if (!DescribeCurrentImage(opened, path, hdu, &result, &nx, &ny, error)) return std::nullopt;
  result.pixels = Image(nx, ny);
  if (!ReadCurrentRows(opened.file.get(), path, nx, 0, ny, result.pixels.data.data(), error)) {
    return std::nullopt;
  }
  return result;
}

// Whether `text` is a non-negative decimal number (an HDU index), and its value.
bool ParseHduIndex(const std::string& text, int* index) {
  if (text.empty() || text.size() > 6) return false;
  for (char c : text) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return false;
  }
  *index = std::atoi(text.c_str());
  return true;
}

// Opens a file for reading: the plain checks of CheckReadable; a gzip file decompressed
// here, within the memory ceiling; the screen (ScreenFile) on every HDU; then CFITSIO.
bool OpenForReading(const std::string& path, OpenedFits* opened, std::string* error) {
  bool gzip = false;
  if (!CheckReadable(path, &gzip, error)) return false;
  if (gzip) {
    const size_t limit = static_cast<size_t>(MaxImageBytes());
    // First at most 16 MB: a header claiming a huge image is refused without inflating the
    // rest (a few KB of gzip can hold a header that claims gigabytes, and a few MB can
    // inflate to gigabytes).
    const size_t probe = std::min(limit, size_t{16} << 20);
    bool complete = false;
    if (!Gunzip(path, probe, &opened->bytes, &complete, error)) return false;
    if (!complete && probe < limit) {
      if (!ScreenFile(opened->bytes, path, &opened->hdus, error)) return false;
      opened->bytes.Reset();
      if (!Gunzip(path, limit, &opened->bytes, &complete, error)) return false;
    }
    if (!complete) {
      if (!ScreenFile(opened->bytes, path, &opened->hdus, error)) return false;
      *error = Quoted(path) + " decompresses to more than " +
               FormatBytes(static_cast<double>(limit)) + ", the limit (--max_image_mb)";
      return false;
    }
  } else if (!opened->bytes.OpenDisk(path)) {
    *error = "cannot read " + Quoted(path) + ": " + std::strerror(errno);
    return false;
  }
  if (!ScreenFile(opened->bytes, path, &opened->hdus, error)) return false;
  int status = 0;
  if (opened->bytes.in_memory()) {
    // A neutral name: fits_open_memfile parses it, and "[1]" in a file name would move to
    // extension 1. Messages name `path`.
    fits_open_memfile(opened->file.out(), "decompressed.fits", READONLY,
                      opened->bytes.memory_slot(), opened->bytes.memory_size_slot(), 0, nullptr,
                      &status);
  } else {
    const CfitsioName name(path);
    fits_open_diskfile(opened->file.out(), name.c_str(), READONLY, &status);
  }
  if (status != 0 || fits_get_num_hdus(opened->file.get(), &opened->num_hdus, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  return true;
}

}  // namespace

std::optional<FitsImage> ReadFitsImage(const std::string& path, std::string* error) {
  return ReadFitsImage(path, "", error);
}

namespace {

// Moves to the image HDU that `hdu_selector` names (ReadFitsImage's choice when empty) and
// sets *hdu to its 1-based absolute number.
bool SelectImageHdu(const OpenedFits& opened, const std::string& path,
                    const std::string& hdu_selector, int* hdu_number, std::string* error) {
  const FitsFile& file = opened.file;
  int status = 0;
  const int num_hdus = opened.num_hdus;

  if (!hdu_selector.empty()) {
    // An extension by number (0 = primary, as astropy and DS9 count) or by EXTNAME.
    int index = -1;
    int type = 0;
    if (ParseHduIndex(hdu_selector, &index)) {
      if (index + 1 > num_hdus) {
        *error = Quoted(path) + " has no HDU " + hdu_selector + " (it has " +
                 std::to_string(num_hdus) + ": 0 = primary .. " + std::to_string(num_hdus - 1) +
                 ")";
        return false;
      }
      if (fits_movabs_hdu(file.get(), index + 1, &type, &status)) {
        *error = Corrupt(path, status);
        return false;
      }
    } else {
      std::string wanted = ToUpper(hdu_selector);
      index = -1;
      for (int h = 1; h <= num_hdus && index < 0; ++h) {
        if (fits_movabs_hdu(file.get(), h, &type, &status)) {
          *error = Corrupt(path, status);
          return false;
        }
        if (ToUpper(ExtName(file.get())) == wanted) index = h - 1;
      }
      if (index < 0) {
        std::string names;
        for (const FitsHduInfo& info : ListFitsImageHdus(path, error)) {
          names += (names.empty() ? "" : ", ") + (info.extname.empty() ? std::to_string(info.index)
                                                                       : info.extname);
        }
        *error = Quoted(path) + " has no extension named '" + hdu_selector + "'" +
                 (names.empty() ? "" : " (images: " + names + ")");
        return false;
      }
    }
    int naxis = 0;
    if (fits_get_img_dim(file.get(), &naxis, &status)) {
      *error = Corrupt(path, status);
      return false;
    }
    if (type != IMAGE_HDU && !fits_is_compressed_image(file.get(), &status)) {
      *error = Quoted(path) + " HDU " + hdu_selector + " is a table, not an image";
      return false;
    }
    if (naxis == 0) {
      *error = Quoted(path) + " HDU " + hdu_selector + " holds no image (NAXIS = 0)";
      return false;
    }
    *hdu_number = index + 1;
    return true;
  }

  // The primary HDU, or the first image extension with data when the primary is empty. The
  // file may be at another HDU (FitsImageFile lists them all first).
  int naxis = 0;
  if (fits_movabs_hdu(file.get(), 1, nullptr, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  if (fits_get_img_dim(file.get(), &naxis, &status)) {
    *error = Corrupt(path, status);
    return false;
  }
  int hdu = 1;
  if (naxis == 0) {
    std::string first_extension;  // what the first extension was, for the message
    hdu = 0;
    for (int h = 2; h <= num_hdus; ++h) {
      int type = 0;
      if (fits_movabs_hdu(file.get(), h, &type, &status)) {
        *error = Corrupt(path, status);
        return false;
      }
      if (type != IMAGE_HDU) {
        if (first_extension.empty()) first_extension = "a table";
        continue;
      }
      if (fits_get_img_dim(file.get(), &naxis, &status)) {
        *error = Corrupt(path, status);
        return false;
      }
      if (naxis > 0) {
        hdu = h;
        break;
      }
      if (first_extension.empty()) first_extension = "an empty image";
    }
    if (hdu == 0) {
      if (num_hdus <= 1) {
        *error = Quoted(path) +
                 " has no image (the primary HDU is empty and there are no "
                 "extensions)";
      } else {
        *error = Quoted(path) + " has no image (first extension is " + first_extension + ")";
      }
      return false;
    }
  }
  *hdu_number = hdu;
  return true;
}

}  // namespace

std::optional<FitsImage> ReadFitsImage(const std::string& path, const std::string& hdu_selector,
                                       std::string* error) {
  OpenedFits opened;
  if (!OpenForReading(path, &opened, error)) return std::nullopt;
  int hdu = 0;
  if (!SelectImageHdu(opened, path, hdu_selector, &hdu, error)) return std::nullopt;
  return ReadCurrentImage(opened, path, hdu, error);
}

struct FitsImageStream::Opened {
  OpenedFits fits;
};

FitsImageStream::FitsImageStream() = default;
FitsImageStream::~FitsImageStream() = default;

std::unique_ptr<FitsImageStream> FitsImageStream::Open(const std::string& path,
                                                       const std::string& hdu_selector,
                                                       std::string* error) {
  std::unique_ptr<FitsImageStream> stream(new FitsImageStream());
  stream->opened_ = std::make_unique<Opened>();
  stream->path_ = path;
  OpenedFits& opened = stream->opened_->fits;
  if (!OpenForReading(path, &opened, error)) return nullptr;
  int hdu = 0;
  if (!SelectImageHdu(opened, path, hdu_selector, &hdu, error) ||
      !DescribeCurrentImage(opened, path, hdu, &stream->image_, &stream->nx_, &stream->ny_,
                            error)) {
    return nullptr;
  }
  return stream;
}

bool FitsImageStream::ReadRows(int y_begin, int rows, double* out, std::string* error) {
  if (y_begin < 0 || rows < 0 || y_begin + rows > ny_) {
    *error = Quoted(path_) + ": rows " + std::to_string(y_begin) + ".." +
             std::to_string(y_begin + rows) + " lie outside the image's " + std::to_string(ny_);
    return false;
  }
  if (rows == 0) return true;
  return ReadCurrentRows(opened_->fits.file.get(), path_, nx_, y_begin, rows, out, error);
}

namespace {

// The 2-D images of an opened file (ListFitsImageHdus).
std::vector<FitsHduInfo> ListImages(const OpenedFits& opened, const std::string& path,
                                    std::string* error) {
  std::vector<FitsHduInfo> out;
  const FitsFile& file = opened.file;
  int status = 0;
  const int num_hdus = opened.num_hdus;
  for (int h = 1; h <= num_hdus; ++h) {
    int type = 0;
    if (fits_movabs_hdu(file.get(), h, &type, &status)) {
      *error = Corrupt(path, status);
      out.clear();
      return out;
    }
    int naxis = 0;
    LONGLONG naxes[2] = {0, 0};
    if (type != IMAGE_HDU && !fits_is_compressed_image(file.get(), &status)) continue;
    if (fits_get_img_dim(file.get(), &naxis, &status) || naxis != 2 ||
        fits_get_img_sizell(file.get(), 2, naxes, &status) || naxes[0] <= 0 || naxes[1] <= 0) {
      status = 0;
      fits_clear_errmsg();
      continue;
    }
    out.push_back({h - 1, ExtName(file.get()), static_cast<long long>(naxes[0]),
                   static_cast<long long>(naxes[1])});
  }
  return out;
}

}  // namespace

std::vector<FitsHduInfo> ListFitsImageHdus(const std::string& path, std::string* error) {
  OpenedFits opened;
  if (!OpenForReading(path, &opened, error)) return {};
  return ListImages(opened, path, error);
}

struct FitsImageFile::Opened {
  OpenedFits fits;
};

FitsImageFile::FitsImageFile() = default;
FitsImageFile::~FitsImageFile() = default;

std::unique_ptr<FitsImageFile> FitsImageFile::Open(const std::string& path, std::string* error) {
  std::unique_ptr<FitsImageFile> file(new FitsImageFile());
  file->opened_ = std::make_unique<Opened>();
  file->path_ = path;
  if (!OpenForReading(path, &file->opened_->fits, error)) return nullptr;
  // A file whose later HDUs cannot be listed can still be read (its primary image): the
  // list is then empty, as ListFitsImageHdus's is, and Read says what fails.
  std::string unlisted;
  file->images_ = ListImages(file->opened_->fits, path, &unlisted);
  return file;
}

std::optional<FitsImage> FitsImageFile::Read(const std::string& hdu_selector,
                                             std::string* error) {
  // An EXTNAME is found in the list (a name is looked for HDU by HDU otherwise, moving
  // CFITSIO through every header before it); a number is used as it is.
  std::string selector = hdu_selector;
  int index = 0;
  if (!selector.empty() && !ParseHduIndex(selector, &index)) {
    for (const FitsHduInfo& info : images_) {
      if (!info.extname.empty() && ToUpper(info.extname) == ToUpper(selector)) {
        selector = std::to_string(info.index);
        break;
      }
    }
  }
  int hdu = 0;
  if (!SelectImageHdu(opened_->fits, path_, selector, &hdu, error)) return std::nullopt;
  return ReadCurrentImage(opened_->fits, path_, hdu, error);
}

bool WriteFitsImageU16(const std::string& path, const Image& image, const FitsHeader& header,
                       std::string* error) {
  if (!ValidateImage(path, image, error) || !ValidateHeader(path, header, error)) return false;
  for (int y = 0; y < image.ny; ++y) {
    for (int x = 0; x < image.nx; ++x) {
      const double v = image(x, y);
      if (!(v >= 0.0 && v <= 65535.0 && v == std::floor(v))) {
        char text[64];
        std::snprintf(text, sizeof(text), "%.17g", v);
        *error = "cannot write " + Quoted(path) + " as 16-bit unsigned: pixel (" +
                 std::to_string(x) + ", " + std::to_string(y) + ") = " + text +
                 " is not an integer in [0, 65535]";
        return false;
      }
    }
  }
  return WriteAtomically(
      path,
      [&](const std::string& temp_path, std::string* write_error) {
        FitsFile file;
        int status = 0;
        if (!CreateFile(temp_path, &file, &status)) {
          *write_error = WriteError(path, "cannot create file", status);
          return false;
        }
        return WriteImageHdu(file.get(), path, USHORT_IMG, image, "", header, write_error) &&
               CloseWritten(&file, path, write_error);
      },
      error);
}

bool WriteFitsImageF64(const std::string& path, const Image& image, const FitsHeader& header,
                       std::string* error) {
  if (!ValidateImage(path, image, error) || !ValidateHeader(path, header, error)) return false;
  return WriteAtomically(
      path,
      [&](const std::string& temp_path, std::string* write_error) {
        FitsFile file;
        int status = 0;
        if (!CreateFile(temp_path, &file, &status)) {
          *write_error = WriteError(path, "cannot create file", status);
          return false;
        }
        return WriteImageHdu(file.get(), path, DOUBLE_IMG, image, "", header, write_error) &&
               CloseWritten(&file, path, write_error);
      },
      error);
}

bool WriteFitsImagesF64(const std::string& path, const FitsHeader& primary_header,
                        const std::vector<FitsImageHdu>& images, std::string* error) {
  if (!ValidateHeader(path, primary_header, error)) return false;
  for (const FitsImageHdu& hdu : images) {
    if (!ValidateImage(path, hdu.image, error) || !ValidateHeader(path, hdu.header, error)) {
      return false;
    }
    for (const FitsKey& key : hdu.header) {
      if (ToUpper(key.name) == "EXTNAME") {
        *error = "cannot write " + Quoted(path) +
                 ": give the extension name in extname, not "
                 "as an EXTNAME keyword";
        return false;
      }
    }
  }
  return WriteAtomically(
      path,
      [&](const std::string& temp_path, std::string* write_error) {
        FitsFile file;
        int status = 0;
        if (!CreateFile(temp_path, &file, &status)) {
          *write_error = WriteError(path, "cannot create file", status);
          return false;
        }
        if (!WriteEmptyPrimary(file.get(), path, primary_header, write_error)) return false;
        for (const FitsImageHdu& hdu : images) {
          if (!WriteImageHdu(file.get(), path, DOUBLE_IMG, hdu.image, hdu.extname, hdu.header,
                             write_error)) {
            return false;
          }
        }
        return CloseWritten(&file, path, write_error);
      },
      error);
}

bool WriteFitsTable(const std::string& path, const FitsHeader& primary_header,
                    const std::string& extname, const std::vector<FitsColumn>& columns,
                    const FitsHeader& table_header, std::string* error) {
  if (!ValidateHeader(path, primary_header, error) || !ValidateHeader(path, table_header, error)) {
    return false;
  }
  if (columns.empty()) {
    *error = "cannot write " + Quoted(path) + ": table has no columns";
    return false;
  }
  const size_t num_rows = columns.front().Rows();
  std::set<std::string> seen;
  for (const FitsColumn& column : columns) {
    if (column.name.empty()) {
      *error = "cannot write " + Quoted(path) + ": a table column has no name";
      return false;
    }
    // TTYPEn of letters, digits and underscores (column_units.h has FitsColumnName).
    for (char c : column.name) {
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) {
        *error = "cannot write " + Quoted(path) + ": column name '" + column.name +
                 "' holds a character other than letters, digits and '_'";
        return false;
      }
    }
    // FITS column names are compared without case by most readers (astropy, TOPCAT).
    if (!seen.insert(ToUpper(column.name)).second) {
      *error = "cannot write " + Quoted(path) + ": duplicate column name '" + column.name + "'";
      return false;
    }
    if (column.Rows() != num_rows) {
      *error = "cannot write " + Quoted(path) + ": column '" + column.name + "' has " +
               std::to_string(column.Rows()) + " rows, column '" + columns.front().name + "' has " +
               std::to_string(num_rows);
      return false;
    }
    for (const std::string& text : column.texts) {
      if (!IsPrintableAscii(text)) {
        *error = "cannot write " + Quoted(path) + ": text column '" + column.name +
                 "' holds a character that is not printable ASCII";
        return false;
      }
    }
    if (column.is_integer && column.texts.empty()) {
      for (size_t row = 0; row < num_rows; ++row) {
        const double v = column.values[row];
        // 9.2e18 ~ 2^63: beyond it a 64-bit integer cannot hold the value.
        if (!std::isfinite(v) || std::fabs(v) >= 9.2e18) {
          *error = "cannot write " + Quoted(path) + ": integer column '" + column.name + "' row " +
                   std::to_string(row) +
                   " holds a value that is not a finite "
                   "64-bit integer";
          return false;
        }
      }
    }
  }
  return WriteAtomically(
      path,
      [&](const std::string& temp_path, std::string* write_error) {
        FitsFile file;
        int status = 0;
        if (!CreateFile(temp_path, &file, &status)) {
          *write_error = WriteError(path, "cannot create file", status);
          return false;
        }
        if (!WriteEmptyPrimary(file.get(), path, primary_header, write_error)) return false;

        std::vector<std::string> tforms;
        std::vector<char*> ttype, tform, tunit;
        // Each column's width in a row and its byte offset there [bytes].
        std::vector<size_t> widths, offsets;
        size_t row_bytes = 0;
        for (const FitsColumn& column : columns) {
          size_t width = 8;  // 1D, 1K
          if (!column.texts.empty()) {
            width = 1;
            for (const std::string& t : column.texts) width = std::max(width, t.size());
            tforms.push_back(std::to_string(width) + "A");
          } else {
            tforms.push_back(column.is_integer ? "1K" : "1D");
          }
          widths.push_back(width);
          offsets.push_back(row_bytes);
          row_bytes += width;
        }
        for (size_t i = 0; i < columns.size(); ++i) {
          ttype.push_back(const_cast<char*>(columns[i].name.c_str()));
          tform.push_back(const_cast<char*>(tforms[i].c_str()));
          // CFITSIO writes no TUNITn card for an empty unit.
          tunit.push_back(const_cast<char*>(columns[i].unit.c_str()));
        }
        if (fits_create_tbl(file.get(), BINARY_TBL, static_cast<LONGLONG>(num_rows),
                            static_cast<int>(columns.size()), ttype.data(), tform.data(),
                            tunit.data(), extname.empty() ? nullptr : extname.c_str(), &status)) {
          *write_error = WriteError(path, "cannot create table", status);
          return false;
        }
        std::string failed_key;
        if (!WriteHeader(file.get(), table_header, &status, &failed_key)) {
          *write_error = WriteError(path, "cannot write keyword " + failed_key, status);
          return false;
        }
        // Row blocks of the size CFITSIO's buffers hold (fits_get_rowsize), every column of a
        // block before the next: a table is stored row by row, so writing whole columns one
        // after another would pass over the file once per column (for a 14 MB chain, ~460 000
        // seeks and 2 s of system time).
        long block_rows = 0;
        if (fits_get_rowsize(file.get(), &block_rows, &status) || block_rows < 1) {
          block_rows = 1;
          status = 0;
        }
        std::vector<LONGLONG> integers;
        std::vector<double> doubles;
        for (size_t first = 0; first < num_rows; first += static_cast<size_t>(block_rows)) {
          const size_t n = std::min(num_rows - first, static_cast<size_t>(block_rows));
          for (size_t i = 0; i < columns.size(); ++i) {
            const int column_number = static_cast<int>(i) + 1;
            if (!columns[i].texts.empty()) {
              // The bytes themselves, NUL-padded: CFITSIO pads strings with blanks, which
              // astropy's Table.read keeps ('ok     '); a NUL ends a FITS string.
              std::vector<unsigned char> field(widths[i]);
              for (size_t row = 0; row < n && status == 0; ++row) {
                const std::string& text = columns[i].texts[first + row];
                std::fill(field.begin(), field.end(), 0);
                std::copy(text.begin(), text.end(), field.begin());
                fits_write_tblbytes(file.get(), static_cast<LONGLONG>(first + row) + 1,
                                    static_cast<LONGLONG>(offsets[i]) + 1,
                                    static_cast<LONGLONG>(widths[i]), field.data(), &status);
              }
            } else if (columns[i].is_integer) {
              const double* v = columns[i].values.data() + first;
              integers.resize(n);
              for (size_t row = 0; row < n; ++row) integers[row] = std::llround(v[row]);
              fits_write_col(file.get(), TLONGLONG, column_number, static_cast<LONGLONG>(first) + 1,
                             1, static_cast<LONGLONG>(n), integers.data(), &status);
            } else {
              const double* v = columns[i].values.data() + first;
              // CFITSIO may byte-swap the array it is given in place: pass a copy.
              doubles.assign(v, v + n);
              fits_write_col(file.get(), TDOUBLE, column_number, static_cast<LONGLONG>(first) + 1,
                             1, static_cast<LONGLONG>(n), doubles.data(), &status);
            }
            if (status != 0) {
              *write_error =
                  WriteError(path, "cannot write column '" + columns[i].name + "'", status);
              return false;
            }
          }
        }
        return CloseWritten(&file, path, write_error);
      },
      error);
}

}  // namespace ccdpsf
