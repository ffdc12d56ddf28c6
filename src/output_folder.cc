#include "ccdpsf/output_folder.h"

#include <fcntl.h>
#include <stdio.h>  // renameat2, RENAME_EXCHANGE (glibc >= 2.28)
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
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


// Why `path` (an existing folder) is not ours to replace or empty: "" if it is. A folder
// the user made read-only (no owner write bit) or that belongs to another user is left as
// it is, even where the process could write it (root), and so is every folder inside it:
// otherwise its files would be stranded half-removed in the partial folder.
std::string NotOurs(const fs::path& path) {
  struct stat st;
  if (::lstat(path.c_str(), &st) != 0) return std::strerror(errno);
  if (st.st_uid != ::geteuid()) {
    return "it belongs to another user (uid " + std::to_string(st.st_uid) + ")";
  }
  if (S_ISDIR(st.st_mode) && (st.st_mode & S_IWUSR) == 0) {
    char mode[8];
    std::snprintf(mode, sizeof(mode), "%03o", static_cast<unsigned>(st.st_mode & 0777));
    return std::string("it is read-only (mode ") + mode + ")";
  }
  if (S_ISDIR(st.st_mode) && ::access(path.c_str(), W_OK | X_OK) != 0) {
    return "it is not writable: " + std::string(std::strerror(errno));
  }
  return "";
}

// Checks that --out may be replaced as a whole: absent; or a real folder (not a symbolic
// link, whose target would not be what is replaced) that is ours and writable throughout,
// and that is empty or an earlier ccdpsf output.
bool CheckReplaceable(const fs::path& out, const std::string& given, std::string* error) {
  struct stat st;
  if (::lstat(out.c_str(), &st) != 0) {
    if (errno == ENOENT) return true;
    *error = "cannot use --out=" + given + ": " + std::strerror(errno);
    return false;
  }
  if (S_ISLNK(st.st_mode)) {
    *error = "--out=" + given + " is a symbolic link, and an output folder is replaced as a "
             "whole: give the folder it points to, or a new one";
    return false;
  }
  if (!S_ISDIR(st.st_mode)) {
    *error = "--out=" + given + " is a file, not a folder";
    return false;
  }
  std::error_code ec;
  if (!fs::is_empty(out, ec) && !IsCcdpsfOutput(out.string())) {
    std::string example;
    for (const auto& entry : fs::directory_iterator(out, ec)) {
      example = entry.path().filename().string();
      break;
    }
    *error = "--out=" + given + " holds files ccdpsf did not write (e.g. '" + example +
             "'), and an output folder is replaced as a whole: give a new or empty folder";
    return false;
  }
  std::string why = NotOurs(out);
  for (fs::recursive_directory_iterator it(out, ec), end; why.empty() && !ec && it != end;
       it.increment(ec)) {
    if (it->is_directory(ec) && !it->is_symlink(ec)) {
      why = NotOurs(it->path());
      if (!why.empty()) why = "'" + it->path().string() + "' inside it: " + why;
    }
  }
  if (why.empty() && ec) why = ec.message();
  if (!why.empty()) {
    *error = "--out=" + given + " cannot be replaced: " + why + "; it is left as it is";
    return false;
  }
  return true;
}

// Creates the partial folder `partial` exclusively (mkdir fails on anything already there,
// a symbolic link included), or adopts the one a killed run left: a real folder of this
// user, never a link planted at the predictable name.
bool CreateOrAdoptPartial(const std::string& partial, std::string* error) {
  if (::mkdir(partial.c_str(), 0700) == 0) return true;
  if (errno != EEXIST) {
    *error = "cannot create " + Quoted(partial) + ": " + std::strerror(errno);
    return false;
  }
  struct stat st;
  if (::lstat(partial.c_str(), &st) != 0) {
    *error = "cannot create " + Quoted(partial) + ": " + std::strerror(errno);
    return false;
  }
  if (!S_ISDIR(st.st_mode)) {
    *error = Quoted(partial) + " is in the way of ccdpsf's partial folder and is not one (" +
             (S_ISLNK(st.st_mode) ? "a symbolic link" : "not a folder") +
             "): it is not followed; remove it";
    return false;
  }
  const std::string why = NotOurs(partial);
  if (!why.empty()) {
    *error = "cannot take over " + Quoted(partial) + ": " + why;
    return false;
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
  if (!CheckReplaceable(out, out_dir, error)) return false;
  const fs::path parent = out.has_parent_path() ? out.parent_path() : fs::path(".");
  if (!MakeDirectories(parent.string(), error)) return false;
  out_dir_ = out.string();
  const std::string partial =
      (parent / ("." + out.filename().string() + ".ccdpsf-partial")).string();
  if (!CreateOrAdoptPartial(partial, error)) return false;
  partial_ = partial;
  // O_NOFOLLOW: the folder checked above, not a link put in its place since.
  lock_fd_ = ::open(partial_.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
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
