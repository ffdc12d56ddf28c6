// Runs the ccdpsf binary under test (CCDPSF_BINARY) for the end-to-end tests.
#ifndef CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_
#define CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_

#include <functional>
#include <string>

namespace ccdpsf::testing_support {

struct RunResult {
  int exit_code = -1;  // -1 when the process could not be run or did not exit normally
  std::string output;  // stdout and stderr together
};

// Runs a shell command; returns its exit code (-1 if it could not run or did not exit
// normally), *output gets stdout and stderr.
int Shell(const std::string& command, std::string* output);

// `ccdpsf ARGS` through the shell, stderr merged into stdout.
RunResult RunCcdpsf(const std::string& args);

// The same, returning the exit code and replacing *output with what was printed.
int RunCcdpsf(const std::string& args, std::string* output);

// Starts `ccdpsf args` (output discarded), waits until `ready()` holds, then kills it with
// SIGKILL: nothing of the process runs after, as when a machine or a scheduler kills a job.
// False if the run ended before `ready()` held (the kill then tests nothing).
bool RunAndKill(const std::string& args, const std::function<bool()>& ready);

// A new, empty folder private to this test process (ctest runs tests in parallel processes):
// <test temp dir>/ccdpsf_<suite>_<pid>_<name>.
std::string FreshDir(const std::string& suite, const std::string& name);

// Writes `text` to the file `path` (a test's small input or stand-in file).
void Touch(const std::string& path, const std::string& text = "x");

// A run record as ccdpsf writes it in `dir` (the mark of a folder it may replace).
void WriteRunRecord(const std::string& dir);

// The folder of testdata/demo_simulation.json's five exposures (exposure_000.fits ...),
// simulated by the binary once per process.
const std::string& DemoSet();

// The folder of the real bench frames (an 8-bit camera, one frame per exposure time; not in
// the repository): $CCDPSF_REALDATA/lpnhe_intensity, else ../shared/realdata/lpnhe_intensity
// beside the source tree. Tests that read it skip when it is absent.
std::string RealFramesFolder();

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_
