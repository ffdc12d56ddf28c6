// Runs the ccdpsf binary under test (CCDPSF_BINARY) for the end-to-end tests.
#ifndef CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_
#define CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_

#include <string>

namespace ccdpsf::testing_support {

struct RunResult {
  int exit_code = -1;  // -1 when the process could not be run or did not exit normally
  std::string output;  // stdout and stderr together
};

// `ccdpsf ARGS` through the shell, stderr merged into stdout.
RunResult RunCcdpsf(const std::string& args);

// The same, returning the exit code and replacing *output with what was printed.
int RunCcdpsf(const std::string& args, std::string* output);

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_RUN_CCDPSF_H_
