#include "ccdpsf/staged_output.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <filesystem>

#include "ccdpsf/atomic_file.h"

namespace ccdpsf {

namespace fs = std::filesystem;

StagedOutput::~StagedOutput() {
  if (staging_.empty()) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

bool StagedOutput::Begin(const std::string& out_dir, std::string* error) {
  if (!MakeDirectories(out_dir, error)) return false;
  static std::atomic<int> counter{0};
  out_dir_ = out_dir;
  staging_ = out_dir + "/.ccdpsf-staging-" + std::to_string(static_cast<long>(::getpid())) +
             "-" + std::to_string(counter++);
  std::error_code ec;
  fs::remove_all(staging_, ec);
  if (!fs::create_directory(staging_, ec)) {
    *error = "cannot create a staging folder in '" + out_dir + "': " + ec.message();
    staging_.clear();
    return false;
  }
  return true;
}

bool StagedOutput::Commit(const std::vector<std::string>& last, std::string* error) {
  std::error_code ec;
  for (const std::string& name : last) fs::remove(out_dir_ + "/" + name, ec);
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(staging_, ec)) {
    names.push_back(entry.path().filename().string());
  }
  if (ec) {
    *error = "cannot list '" + staging_ + "': " + ec.message();
    return false;
  }
  std::sort(names.begin(), names.end());
  std::vector<std::string> order;
  for (const std::string& n : names) {
    if (std::find(last.begin(), last.end(), n) == last.end()) order.push_back(n);
  }
  for (const std::string& n : last) {
    if (std::find(names.begin(), names.end(), n) != names.end()) order.push_back(n);
  }
  for (const std::string& n : order) {
    const fs::path to = fs::path(out_dir_) / n;
    if (fs::is_directory(to, ec)) fs::remove_all(to, ec);
    fs::rename(fs::path(staging_) / n, to, ec);
    if (ec) {
      *error = "cannot move '" + n + "' into '" + out_dir_ + "': " + ec.message();
      return false;
    }
  }
  fs::remove_all(staging_, ec);
  staging_.clear();
  return true;
}

}  // namespace ccdpsf
