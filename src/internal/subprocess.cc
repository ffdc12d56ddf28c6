#include "internal/subprocess.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>

namespace ccdpsf::internal {
namespace {

constexpr size_t kMaxOutputBytes = 64 * 1024;

bool IsExecutableFile(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode) && ::access(path.c_str(), X_OK) == 0;
}

void CloseIfOpen(int* fd) {
  if (*fd >= 0) ::close(*fd);
  *fd = -1;
}

// Waits for `pid`, retrying on EINTR. Returns false (with errno set) if it cannot.
bool WaitFor(pid_t pid, int* status) {
  while (::waitpid(pid, status, 0) < 0) {
    if (errno != EINTR) return false;
  }
  return true;
}

}  // namespace

std::optional<std::string> FindExecutable(const std::string& name) {
  if (name.empty()) return std::nullopt;
  if (name.find('/') != std::string::npos) {
    if (IsExecutableFile(name)) return name;
    return std::nullopt;
  }
  const char* env_path = std::getenv("PATH");
  const std::string search = env_path != nullptr ? env_path : "/usr/local/bin:/usr/bin:/bin";
  size_t begin = 0;
  while (begin <= search.size()) {
    size_t end = search.find(':', begin);
    if (end == std::string::npos) end = search.size();
    // An empty PATH entry means the current folder, as for execvp.
    const std::string folder = end > begin ? search.substr(begin, end - begin) : ".";
    const std::string candidate = folder + "/" + name;
    if (IsExecutableFile(candidate)) return candidate;
    begin = end + 1;
  }
  return std::nullopt;
}

SubprocessOutcome RunSubprocess(const std::string& executable, const std::vector<std::string>& args,
                                const std::string& working_dir, double timeout_s) {
  SubprocessOutcome outcome;

  // Everything the child needs is prepared before fork: after it, in a multi-threaded
  // process, the child may only make async-signal-safe calls (no allocation).
  std::vector<std::string> argv_storage;
  argv_storage.reserve(args.size() + 1);
  argv_storage.push_back(executable);
  argv_storage.insert(argv_storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : argv_storage) argv.push_back(a.data());
  argv.push_back(nullptr);

  int output_pipe[2] = {-1, -1};  // child's stdout + stderr -> parent
  int status_pipe[2] = {-1, -1};  // child's errno if chdir/exec fails; closed by a good exec
  if (::pipe2(output_pipe, O_CLOEXEC) != 0 || ::pipe2(status_pipe, O_CLOEXEC) != 0) {
    outcome.error = std::string("cannot create a pipe: ") + std::strerror(errno);
    CloseIfOpen(&output_pipe[0]);
    CloseIfOpen(&output_pipe[1]);
    return outcome;
  }
  const int dev_null = ::open("/dev/null", O_RDONLY | O_CLOEXEC);

  const pid_t pid = ::fork();
  if (pid < 0) {
    outcome.error = std::string("cannot fork: ") + std::strerror(errno);
    for (int* fd : {&output_pipe[0], &output_pipe[1], &status_pipe[0], &status_pipe[1]}) {
      CloseIfOpen(fd);
    }
    if (dev_null >= 0) ::close(dev_null);
    return outcome;
  }
  if (pid == 0) {
    // Child. dup2 clears FD_CLOEXEC on the new descriptors; the originals close at exec.
    // On failure, report {step, errno} to the parent (1: redirect, 2: chdir, 3: exec).
    int report[2] = {0, 0};
    if (dev_null >= 0) ::dup2(dev_null, STDIN_FILENO);
    if (::dup2(output_pipe[1], STDOUT_FILENO) < 0 || ::dup2(output_pipe[1], STDERR_FILENO) < 0) {
      report[0] = 1;
    } else if (::chdir(working_dir.c_str()) != 0) {
      report[0] = 2;
    } else {
      ::execv(argv[0], argv.data());
      report[0] = 3;
    }
    report[1] = errno;
    ssize_t ignored = ::write(status_pipe[1], report, sizeof(report));
    (void)ignored;
    ::_exit(127);
  }

  // Parent.
  CloseIfOpen(&output_pipe[1]);
  CloseIfOpen(&status_pipe[1]);
  if (dev_null >= 0) ::close(dev_null);

  int report[2] = {0, 0};
  ssize_t got;
  do {
    got = ::read(status_pipe[0], report, sizeof(report));
  } while (got < 0 && errno == EINTR);
  CloseIfOpen(&status_pipe[0]);
  if (got == static_cast<ssize_t>(sizeof(report))) {
    int status = 0;
    WaitFor(pid, &status);
    CloseIfOpen(&output_pipe[0]);
    const std::string reason = std::strerror(report[1]);
    if (report[0] == 2) {
      outcome.error = "cannot enter folder '" + working_dir + "': " + reason;
    } else if (report[0] == 1) {
      outcome.error = "cannot redirect the output of '" + executable + "': " + reason;
    } else {
      outcome.error = "cannot run '" + executable + "': " + reason;
    }
    return outcome;
  }
  outcome.started = true;

  // Read the output until the child closes it (normally: when it exits) or time runs out.
  const auto deadline =
      std::chrono::steady_clock::now() +
      std::chrono::milliseconds(static_cast<long long>(std::max(0.0, timeout_s) * 1000.0));
  char buffer[4096];
  while (true) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= deadline) {
      outcome.timed_out = true;
      break;
    }
    const long long wait_ms =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now).count();
    struct pollfd pfd = {output_pipe[0], POLLIN, 0};
    const int ready = ::poll(&pfd, 1, static_cast<int>(std::min<long long>(wait_ms, 1000)));
    if (ready < 0) {
      if (errno == EINTR) continue;
      break;
    }
    if (ready == 0) continue;
    const ssize_t n = ::read(output_pipe[0], buffer, sizeof(buffer));
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      break;
    }
    if (n == 0) break;  // end of output
    outcome.output.append(buffer, static_cast<size_t>(n));
    if (outcome.output.size() > 2 * kMaxOutputBytes) {
      outcome.output.erase(0, outcome.output.size() - kMaxOutputBytes);
    }
  }
  CloseIfOpen(&output_pipe[0]);
  if (outcome.output.size() > kMaxOutputBytes) {
    outcome.output.erase(0, outcome.output.size() - kMaxOutputBytes);
  }
  if (outcome.timed_out) ::kill(pid, SIGKILL);  // our own child, by its id

  int status = 0;
  if (!WaitFor(pid, &status)) {
    // ECHILD: SIGCHLD is ignored in this process, so the status is gone; the caller judges
    // by what the program produced.
    outcome.error = std::string("cannot wait for '") + executable + "': " + std::strerror(errno);
    if (errno == ECHILD && !outcome.timed_out) {
      outcome.exited = true;
      outcome.exit_code = 0;
    }
    return outcome;
  }
  if (WIFEXITED(status)) {
    outcome.exited = true;
    outcome.exit_code = WEXITSTATUS(status);
  } else if (WIFSIGNALED(status)) {
    outcome.signal = WTERMSIG(status);
  }
  return outcome;
}

}  // namespace ccdpsf::internal
