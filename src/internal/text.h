// Small text helpers for messages and parsing, shared by the readers of files and headers.
#ifndef CCDPSF_INTERNAL_TEXT_H_
#define CCDPSF_INTERNAL_TEXT_H_

#include <cctype>
#include <cstdio>
#include <string>

namespace ccdpsf::internal {

// Text as it may appear in a one-line message: control and non-ASCII bytes (which a corrupt
// file or header can hold) become '?'.
inline std::string Printable(std::string text) {
  for (char& c : text) {
    if (c < 0x20 || c > 0x7e) c = '?';
  }
  return text;
}

// A number for a message, printf's %g with `significant` digits (6: as a stream prints it).
inline std::string FormatNumber(double value, int significant = 6) {
  char text[32];
  std::snprintf(text, sizeof text, "%.*g", significant, value);
  return text;
}

// Without leading and trailing blanks, tabs and line ends.
inline std::string Trim(const std::string& text) {
  const size_t first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return "";
  const size_t last = text.find_last_not_of(" \t\r\n");
  return text.substr(first, last - first + 1);
}

inline std::string ToUpper(std::string text) {
  for (char& c : text) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return text;
}

// Text that a FITS header card can hold (printable ASCII only): other bytes, such as those
// of a UTF-8 file name, and '%' itself become %XX (RFC 3986 percent-encoding), so the
// original is recoverable: "é.fits" -> "%C3%A9.fits".
inline std::string PercentEncoded(const std::string& text) {
  static const char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (char c : text) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (u >= 0x20 && u <= 0x7e && u != '%') {
      out += c;
    } else {
      out += '%';
      out += kHex[u >> 4];
      out += kHex[u & 15];
    }
  }
  return out;
}

// A path as messages quote it: 'run 1.fits'.
inline std::string Quoted(const std::string& path) { return "'" + path + "'"; }

// True if `text` is `prefix` followed by one or more digits (NAXIS1, TFORM12, ...).
inline bool IsIndexed(const std::string& text, const std::string& prefix) {
  const size_t n = prefix.size();
  if (text.size() <= n || text.compare(0, n, prefix) != 0) return false;
  for (size_t i = n; i < text.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(text[i]))) return false;
  }
  return true;
}

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_TEXT_H_
