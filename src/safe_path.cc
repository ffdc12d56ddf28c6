#include "ccdpsf/safe_path.h"

#include <sys/stat.h>

#include <cctype>
#include <filesystem>
#include <set>

namespace ccdpsf {

namespace fs = std::filesystem;

namespace {

// Longest component kept [bytes]: well below NAME_MAX (255), leaving room for the suffixes
// that make names unique and for the writers' temporary-file suffixes.
constexpr size_t kMaxComponentBytes = 120;

bool IsKept(unsigned char c) {
  return std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '+' || c == '=' ||
         c == ',' || c == '@';
}

std::string Lower(std::string text) {
  for (char& c : text) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return text;
}

}  // namespace

std::string SafeComponent(const std::string& name) {
  std::string out;
  out.reserve(name.size() + 1);
  for (const char c : name) out += IsKept(static_cast<unsigned char>(c)) ? c : '_';
  // ".", ".." and hidden names (the tool's own working files start with '.').
  if (out.empty() || out[0] == '.') out.insert(out.begin(), '_');
  if (out.size() > kMaxComponentBytes) out.resize(kMaxComponentBytes);
  return out;
}

std::vector<std::string> UniqueSafeComponents(const std::vector<std::string>& names) {
  std::vector<std::string> out;
  std::set<std::string> taken;  // lower case
  for (const std::string& name : names) {
    const std::string base = SafeComponent(name);
    std::string candidate = base;
    for (int n = 2; !taken.insert(Lower(candidate)).second; ++n) {
      candidate = base + "_" + std::to_string(n);
    }
    out.push_back(candidate);
  }
  return out;
}

bool IsInsideFolder(const std::string& folder, const std::string& path, std::string* error) {
  const fs::path root = fs::path(folder).lexically_normal();
  const fs::path relative = fs::path(path).lexically_normal().lexically_relative(root);
  auto refuse = [&](const std::string& why) {
    *error = "'" + path + "' " + why + " (not inside '" + folder + "')";
    return false;
  };
  if (relative.empty() || relative == ".") return refuse("is the output folder itself");
  for (const fs::path& part : relative) {
    if (part == "..") return refuse("climbs out with '..'");
  }
  // Every folder between root and the last component must be a real folder, not a link.
  fs::path walked = root;
  for (auto it = relative.begin(); it != relative.end(); ++it) {
    if (std::next(it) == relative.end()) break;
    walked /= *it;
    struct stat st;
    if (::lstat(walked.c_str(), &st) != 0) return true;  // nothing there yet: nothing followed
    if (S_ISLNK(st.st_mode)) {
      return refuse("passes through the symbolic link '" + walked.string() + "'");
    }
  }
  return true;
}

}  // namespace ccdpsf
