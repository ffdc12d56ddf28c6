#include "ccdpsf/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>

namespace ccdpsf {
namespace {

// Distinguishes the temporary files of several writes in flight in one process (threads);
// the process id in the name distinguishes processes.
std::atomic<unsigned long> temp_counter{0};

std::string ErrnoText(int errno_value) { return std::strerror(errno_value); }

// The folder `path` lives in, for messages and for syncing the rename ("." if none).
std::string ParentDirectory(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

// Removes a file if it exists; a missing file is not an error.
void RemoveQuietly(const std::string& path) { ::unlink(path.c_str()); }

// Flushes a finished file to stable storage, so that after a crash the renamed file is either
// absent or complete (rename alone orders nothing on some file systems). Returns false with a
// reason when the file cannot be opened or synced.
bool SyncFile(const std::string& path, std::string* error) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    *error = "cannot reopen '" + path + "' to sync it: " + ErrnoText(errno);
    return false;
  }
  bool ok = true;
  if (::fsync(fd) != 0 && errno != EINVAL && errno != EROFS) {
    // EINVAL/EROFS: the file system does not support syncing (pipes, some FUSE mounts);
    // there is nothing more we can do, and the data are as safe as that system allows.
    *error = "cannot sync '" + path + "': " + ErrnoText(errno);
    ok = false;
  }
  ::close(fd);
  return ok;
}

// Best effort: makes the rename itself durable. Failure here does not undo a completed write,
// so it is not reported.
void SyncDirectory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

bool MakeDirectories(const std::string& dir, std::string* error) {
  if (dir.empty()) {
    *error = "cannot create a directory with an empty name";
    return false;
  }
  // Walk the path one component at a time so that the message names the component that
  // failed (a file in the way, no permission) rather than only the leaf.
  size_t pos = 0;
  while (pos != std::string::npos) {
    pos = dir.find('/', pos + 1);
    const std::string prefix = dir.substr(0, pos);
    if (prefix.empty() || prefix == "/" || prefix == "." || prefix == "..") continue;
    struct stat st;
    if (::stat(prefix.c_str(), &st) == 0) {
      if (!S_ISDIR(st.st_mode)) {
        *error =
            "cannot create directory '" + dir + "': '" + prefix + "' exists and is not a directory";
        return false;
      }
      continue;
    }
    if (::mkdir(prefix.c_str(), 0777) != 0 && errno != EEXIST) {
      *error = "cannot create directory '" + prefix + "': " + ErrnoText(errno);
      return false;
    }
    // EEXIST: another process created it between stat and mkdir; the next stat (or the
    // final check below) verifies it is a directory.
  }
  struct stat st;
  if (::stat(dir.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
    *error = "cannot create directory '" + dir + "'";
    return false;
  }
  return true;
}

bool WriteAtomically(
    const std::string& path,
    const std::function<bool(const std::string& temp_path, std::string* error)>& write,
    std::string* error) {
  if (path.empty()) {
    *error = "cannot write a file with an empty name";
    return false;
  }
  if (path.back() == '/') {
    *error = "cannot write '" + path + "': the name is a directory";
    return false;
  }
  // Say plainly when the folder is missing: the writers' own messages ("couldn't create the
  // named file") would not.
  const std::string dir = ParentDirectory(path);
  struct stat st;
  if (::stat(dir.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
    *error = "cannot write '" + path + "': folder '" + dir + "' does not exist";
    return false;
  }
  // The temporary file sits in the same folder as the target, so that rename() never crosses
  // a file system and is atomic.
  const std::string temp_path =
      path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(temp_counter.fetch_add(1));
  // A stale file of this name can only be left by a crashed process that had the same pid;
  // remove it, because writers such as CFITSIO refuse to create a file that exists.
  RemoveQuietly(temp_path);

  std::string write_error;
  if (!write(temp_path, &write_error)) {
    RemoveQuietly(temp_path);
    *error = write_error.empty() ? "cannot write '" + path + "'" : write_error;
    return false;
  }
  std::string sync_error;
  if (!SyncFile(temp_path, &sync_error)) {
    RemoveQuietly(temp_path);
    *error = "cannot write '" + path + "': " + sync_error;
    return false;
  }
  if (std::rename(temp_path.c_str(), path.c_str()) != 0) {
    const int rename_errno = errno;
    RemoveQuietly(temp_path);
    *error = "cannot write '" + path +
             "': rename from temporary file failed: " + ErrnoText(rename_errno);
    return false;
  }
  SyncDirectory(dir);
  return true;
}

bool WriteTextFileAtomically(const std::string& path, const std::string& contents,
                             std::string* error) {
  return WriteAtomically(
      path,
      [&path, &contents](const std::string& temp_path, std::string* write_error) {
        std::FILE* file = std::fopen(temp_path.c_str(), "wb");
        if (file == nullptr) {
          *write_error = "cannot write '" + path + "': " + ErrnoText(errno);
          return false;
        }
        const size_t written = std::fwrite(contents.data(), 1, contents.size(), file);
        const bool write_ok = written == contents.size() && std::fflush(file) == 0;
        const int write_errno = errno;
        const bool close_ok = std::fclose(file) == 0;
        if (!write_ok || !close_ok) {
          *write_error =
              "cannot write '" + path + "': " + ErrnoText(write_ok ? errno : write_errno);
          return false;
        }
        return true;
      },
      error);
}

}  // namespace ccdpsf
