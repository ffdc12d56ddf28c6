#include "ccdpsf/output_folder.h"

#include <fcntl.h>
#include <stdio.h>  // renameat2, RENAME_EXCHANGE (glibc >= 2.28)
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {
namespace fs = std::filesystem;

namespace {

std::string Quoted(const fs::path& p) { return "'" + p.string() + "'"; }

// `path` made absolute and normal, following symbolic links where they exist, so that
// "out/../out/a.fits" and a link into out/ are seen inside out/.
fs::path Resolved(const std::string& path) {
  std::error_code ec;
  fs::path p = fs::weakly_canonical(fs::absolute(path, ec), ec);
  return ec ? fs::absolute(path).lexically_normal() : p;
}

// True if `inner` is `outer` or lies below it (both resolved).
bool IsWithin(const fs::path& inner, const fs::path& outer) {
  auto i = inner.begin();
  for (auto o = outer.begin(); o != outer.end(); ++o, ++i) {
    if (o->empty()) continue;  // a trailing separator
    if (i == inner.end() || *i != *o) return false;
  }
  return true;
}

}  // namespace

bool IsCcdpsfOutput(const std::string& dir) {
  std::string text, error;
  if (!ReadTextInput((fs::path(dir) / "run.json").string(), "run record", &text, &error)) {
    return false;
  }
  const nlohmann::json record = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  return record.is_object() && record.contains("software") && record["software"].is_object() &&
         record["software"].contains("ccdpsf");
}

OutputFolder::~OutputFolder() {
  if (!partial_.empty() && !keep_) {
    std::error_code ec;
    fs::remove_all(partial_, ec);
  }
  if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the lock
}

bool OutputFolder::Begin(const std::string& out_dir, const std::vector<std::string>& inputs,
                         const std::vector<std::string>& resumable, std::string* error) {
  std::error_code ec;
  fs::path out = fs::path(out_dir).lexically_normal();
  if (out.filename().empty() && out.has_parent_path()) out = out.parent_path();  // "out/"
  if (out.empty() || out.filename().empty() || out.filename() == "." ||
      out.filename() == "..") {
    // "--out=." or "--out=dir/..": the folder has no name of its own to put a partial
    // folder beside; it would also be the working folder that is replaced.
    *error = "--out=" + out_dir + " is not a folder ccdpsf can replace: give a folder name";
    return false;
  }
  const fs::path resolved_out = Resolved(out_dir);
  for (const std::string& input : inputs) {
    if (input.empty()) continue;
    if (IsWithin(Resolved(input), resolved_out)) {
      *error = "--out=" + out_dir + " would be replaced, and it holds the input " +
               Quoted(input) + ": choose another --out";
      return false;
    }
  }
  if (fs::exists(out, ec)) {
    if (!fs::is_directory(out, ec)) {
      *error = "--out=" + out_dir + " is a file, not a folder";
      return false;
    }
    if (!fs::is_empty(out, ec) && !IsCcdpsfOutput(out.string())) {
      std::string example;
      for (const auto& entry : fs::directory_iterator(out, ec)) {
        example = entry.path().filename().string();
        break;
      }
      *error = "--out=" + out_dir + " holds files ccdpsf did not write (e.g. '" + example +
               "'), and an output folder is replaced as a whole: give a new or empty folder";
      return false;
    }
  }
  const fs::path parent = out.has_parent_path() ? out.parent_path() : fs::path(".");
  if (!MakeDirectories(parent.string(), error)) return false;
  out_dir_ = out.string();
  partial_ = (parent / ("." + out.filename().string() + ".ccdpsf-partial")).string();
  if (!fs::is_directory(partial_, ec) && !fs::create_directory(partial_, ec)) {
    *error = "cannot create " + Quoted(partial_) + ": " + ec.message();
    partial_.clear();
    return false;
  }
  lock_fd_ = ::open(partial_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (lock_fd_ < 0 || ::flock(lock_fd_, LOCK_EX | LOCK_NB) != 0) {
    const bool busy = errno == EWOULDBLOCK;
    *error = busy ? "another ccdpsf run is writing --out=" + out_dir + " (it holds " +
                        Quoted(partial_) + ")"
                  : "cannot lock " + Quoted(partial_) + ": " + std::strerror(errno);
    partial_.clear();  // not ours: the destructor must not remove it
    return false;
  }
  // What a killed run left: kept only where the command can reuse it.
  for (const auto& entry : fs::directory_iterator(partial_, ec)) {
    const std::string name = entry.path().filename().string();
    if (std::find(resumable.begin(), resumable.end(), name) != resumable.end()) continue;
    fs::remove_all(entry.path(), ec);
  }
  if (ec) {
    *error = "cannot empty " + Quoted(partial_) + ": " + ec.message();
    return false;
  }
  return true;
}

bool OutputFolder::Commit(const std::vector<std::string>& drop, std::string* error) {
  std::error_code ec;
  for (const std::string& name : drop) fs::remove_all(fs::path(partial_) / name, ec);
  if (!fs::exists(out_dir_, ec)) {
    fs::rename(partial_, out_dir_, ec);
    if (ec) {
      *error = "cannot move the results into " + Quoted(out_dir_) + ": " + ec.message();
      return false;
    }
    partial_.clear();
    return true;
  }
  if (::renameat2(AT_FDCWD, partial_.c_str(), AT_FDCWD, out_dir_.c_str(),
                  RENAME_EXCHANGE) != 0) {
    if (errno != EINVAL && errno != ENOSYS) {
      *error = "cannot replace " + Quoted(out_dir_) + ": " + std::strerror(errno);
      return false;
    }
    // A file system without the exchange: the old folder aside, the new one in, the old
    // one removed. Between the two renames --out does not exist; nothing is mixed.
    const std::string old = partial_ + "-old";
    fs::remove_all(old, ec);
    fs::rename(out_dir_, old, ec);
    if (!ec) fs::rename(partial_, out_dir_, ec);
    if (ec) {
      *error = "cannot replace " + Quoted(out_dir_) + ": " + ec.message();
      return false;
    }
    fs::remove_all(old, ec);
    partial_.clear();
    return true;
  }
  // After the exchange, the partial folder's name holds the earlier run's files.
  fs::remove_all(partial_, ec);
  partial_.clear();
  return true;
}

}  // namespace ccdpsf
