#include "support/run_ccdpsf.h"

#include <sys/wait.h>

#include <cstdio>

namespace ccdpsf::testing_support {

RunResult RunCcdpsf(const std::string& args) {
  const std::string command = std::string(CCDPSF_BINARY) + " " + args + " 2>&1";
  RunResult r;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return r;
  char buffer[4096];
  size_t n;
  while ((n = fread(buffer, 1, sizeof(buffer), pipe)) > 0) r.output.append(buffer, n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

int RunCcdpsf(const std::string& args, std::string* output) {
  RunResult r = RunCcdpsf(args);
  *output = std::move(r.output);
  return r.exit_code;
}

}  // namespace ccdpsf::testing_support
