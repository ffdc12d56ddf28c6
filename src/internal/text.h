// Small text helpers for messages and parsing, shared by the readers of files and headers.
#ifndef CCDPSF_INTERNAL_TEXT_H_
#define CCDPSF_INTERNAL_TEXT_H_

#include <cctype>
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

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_TEXT_H_
