// Running an external program (gnuplot) with a working folder, captured output and a time
// limit, without a shell, so that no argument is ever re-parsed or needs quoting.
#ifndef CCDPSF_INTERNAL_SUBPROCESS_H_
#define CCDPSF_INTERNAL_SUBPROCESS_H_

#include <optional>
#include <string>
#include <vector>

namespace ccdpsf::internal {

// The executable `name` would run as: a name containing '/' is taken as a path and must be
// an executable regular file; otherwise the folders of $PATH are searched in order (an unset
// PATH searches /usr/local/bin:/usr/bin:/bin). nullopt when nothing executable is found.
std::optional<std::string> FindExecutable(const std::string& name);

struct SubprocessOutcome {
  bool started = false;    // the program was executed (false: see error)
  bool timed_out = false;  // killed (SIGKILL) after the time limit
  bool exited = false;     // ended by exit(); exit_code is meaningful
  int exit_code = -1;
  int signal = 0;      // the signal that ended it, when it did not exit
  std::string output;  // stdout and stderr interleaved; at most the last 64 KiB
  std::string error;   // why it could not be started or waited for
  bool Succeeded() const { return started && exited && exit_code == 0 && !timed_out; }
};

// Runs `executable` (a path, as FindExecutable returns) with `args` (argv[1..]) in
// `working_dir`, stdin from /dev/null, stdout and stderr captured together. Waits at most
// timeout_s seconds, then kills the child. Safe to call from several threads at once (the
// child only makes async-signal-safe calls between fork and exec).
SubprocessOutcome RunSubprocess(const std::string& executable, const std::vector<std::string>& args,
                                const std::string& working_dir, double timeout_s);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_SUBPROCESS_H_
