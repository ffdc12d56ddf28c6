#include "ccdpsf/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace ccdpsf {
namespace {

// What a file that is not a regular file is, for the message.
const char* TypeName(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

std::string Named(const std::string& what, const std::string& path) {
  return (what.empty() ? "" : what + " ") + "'" + path + "'";
}

}  // namespace

int OpenRegularFile(const std::string& path, const std::string& what, std::string* error) {
  // O_NONBLOCK: opening a FIFO for reading waits for a writer otherwise. It is cleared again
  // below for a regular file (where it changes nothing anyway).
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    *error = "cannot read " + Named(what, path) + ": " +
             (e == ENOENT || e == ENOTDIR ? std::string("no such file") : std::strerror(e));
    return -1;
  }
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    *error = "cannot read " + Named(what, path) + ": " + std::strerror(errno);
    ::close(fd);
    return -1;
  }
  if (!S_ISREG(st.st_mode)) {
    const char* type = TypeName(st.st_mode);
    *error = Named(what, path) + " is " + type +
             (std::strcmp(type, "not a regular file") == 0 ? "" : ", not a regular file");
    ::close(fd);
    return -1;
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  return fd;
}

bool ReadTextInput(const std::string& path, const std::string& what, std::string* text,
                   std::string* error, long long max_bytes) {
  text->clear();
  const int fd = OpenRegularFile(path, what, error);
  if (fd < 0) return false;
  // Read to the ceiling and one byte past it: the size fstat gave may change meanwhile.
  char buffer[1 << 16];
  bool ok = true;
  for (;;) {
    const ssize_t got = ::read(fd, buffer, sizeof(buffer));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) {
      *error = "cannot read " + Named(what, path) + ": " + std::strerror(errno);
      ok = false;
      break;
    }
    if (got == 0) break;
    text->append(buffer, static_cast<size_t>(got));
    if (static_cast<long long>(text->size()) > max_bytes) {
      const std::string ceiling = max_bytes >= (1LL << 20)
                                      ? std::to_string(max_bytes >> 20) + " MiB"
                                      : std::to_string(max_bytes) + " bytes";
      *error = Named(what, path) + " is larger than " + ceiling + ", the ceiling of a text input";
      ok = false;
      break;
    }
  }
  ::close(fd);
  if (!ok) text->clear();
  return ok;
}

}  // namespace ccdpsf
