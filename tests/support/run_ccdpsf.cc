#include "support/run_ccdpsf.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <thread>

#include "gtest/gtest.h"

namespace ccdpsf::testing_support {

int Shell(const std::string& command, std::string* output) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return -1;
  char buffer[4096];
  size_t n;
  output->clear();
  while ((n = fread(buffer, 1, sizeof(buffer), pipe)) > 0) output->append(buffer, n);
  const int status = pclose(pipe);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

RunResult RunCcdpsf(const std::string& args) {
  RunResult r;
  r.exit_code = Shell(std::string(CCDPSF_BINARY) + " " + args, &r.output);
  return r;
}

int RunCcdpsf(const std::string& args, std::string* output) {
  RunResult r = RunCcdpsf(args);
  *output = std::move(r.output);
  return r.exit_code;
}

void Touch(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

void WriteRunRecord(const std::string& dir) {
  Touch(dir + "/run.json", R"({"command": "fit", "software": {"ccdpsf": "0"}})");
}

std::string FreshDir(const std::string& suite, const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/ccdpsf_" + suite + "_" +
                          std::to_string(static_cast<long>(::getpid())) + "_" + name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

std::string RealFramesFolder() {
  const char* env = std::getenv("CCDPSF_REALDATA");
  const std::string root =
      env != nullptr ? std::string(env) : std::string(CCDPSF_SOURCE_DIR) + "/../shared/realdata";
  return root + "/lpnhe_intensity";
}

const std::string& DemoSet() {
  static const std::string dir = [] {
    const std::string d = FreshDir("demo", "set") + "/sim";
    const RunResult r = RunCcdpsf("simulate --config=" + std::string(CCDPSF_TESTDATA) +
                                  "/demo_simulation.json --out=" + d);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return d;
  }();
  return dir;
}

bool RunAndKill(const std::string& args, const std::function<bool()>& ready) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    const std::string command =
        "exec " + std::string(CCDPSF_BINARY) + " " + args + " > /dev/null 2>&1";
    ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  while (!ready()) {
    if (::waitpid(pid, &status, WNOHANG) == pid) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, &status, 0);
  return WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
}

}  // namespace ccdpsf::testing_support
