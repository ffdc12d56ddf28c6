// ccdpsf: measure the intrinsic PSF of a CCD from spot-projection exposures.
//
// A thin dispatcher: parse flags, turn them into library options, call the library, map the
// outcome to an exit code. Errors on user input are one line on stderr and exit code 1;
// usage errors exit with 2.
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"
#include "glog/logging.h"

DEFINE_string(config, "",
              "JSON configuration file (simulate: the simulation config; fit: FIT.json)");
DEFINE_string(out, "", "Output folder; created if missing");
DEFINE_string(sampling, "integrated",
              "Model sampling: integrated (exact pixel integral) or pixel_centre (the 2015 "
              "code's discretisation)");
DEFINE_string(defocus, "gaussian", "Defocus kernel: gaussian or pillbox");

namespace ccdpsf::tools {

const std::vector<Command>& Commands() {
  static const std::vector<Command> commands = {SimulateCommand(), FitCommand(), TrendCommand(),
                                                DiagnoseCommand(), GainCommand()};
  return commands;
}

int Fail(const std::string& message) {
  std::fprintf(stderr, "ccdpsf: error: %s\n", message.c_str());
  return 1;
}

bool FlagGiven(const char* name) {
  gflags::CommandLineFlagInfo info;
  return gflags::GetCommandLineFlagInfo(name, &info) && !info.is_default;
}

namespace {

void PrintCommandHelp(const Command& c) {
  std::printf("%s\n\n  %s\n\nOptions:\n", c.synopsis, c.summary);
  for (const char* name : c.flags) {
    gflags::CommandLineFlagInfo info;
    if (!gflags::GetCommandLineFlagInfo(name, &info)) continue;
    std::printf("  --%s (%s; default \"%s\")\n      %s\n", info.name.c_str(), info.type.c_str(),
                info.default_value.c_str(), info.description.c_str());
  }
}

void PrintHelp() {
  std::printf(
      "ccdpsf %s: the intrinsic PSF of a CCD from spot-projection exposures.\n\n"
      "Commands:\n",
      SoftwareVersions()["ccdpsf"].get<std::string>().c_str());
  for (const Command& c : Commands()) std::printf("  %-10s %s\n", c.name, c.summary);
  std::printf("\n'ccdpsf <command> --help' lists a command's options.\n");
}

}  // namespace
}  // namespace ccdpsf::tools

int main(int argc, char** argv) {
  using ccdpsf::tools::Command;
  using ccdpsf::tools::Commands;
  google::InitGoogleLogging(argv[0]);
  FLAGS_logtostderr = true;
  FLAGS_minloglevel = 1;  // warnings and above
  if (argc < 2) {
    std::fprintf(stderr, "usage: ccdpsf <command> [options]; 'ccdpsf help' lists commands\n");
    return 2;
  }
  const std::string name = argv[1];
  if (name == "help" || name == "--help" || name == "-h") {
    if (argc >= 3) {
      for (const Command& c : Commands()) {
        if (argv[2] == std::string(c.name)) {
          ccdpsf::tools::PrintCommandHelp(c);
          return 0;
        }
      }
    }
    ccdpsf::tools::PrintHelp();
    return 0;
  }
  if (name == "version" || name == "--version") {
    std::printf("%s\n", ccdpsf::SoftwareVersions().dump(2).c_str());
    return 0;
  }
  const Command* command = nullptr;
  for (const Command& c : Commands()) {
    if (name == c.name) command = &c;
  }
  if (command == nullptr) {
    std::fprintf(stderr, "ccdpsf: error: unknown command '%s'; 'ccdpsf help' lists commands\n",
                 name.c_str());
    return 2;
  }
  for (int i = 2; i < argc; ++i) {
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0 ||
        std::strcmp(argv[i], "-help") == 0) {
      ccdpsf::tools::PrintCommandHelp(*command);
      return 0;
    }
  }
  // gflags sees the arguments after the command name; positional arguments remain.
  int sub_argc = argc - 1;
  char** sub_argv = argv + 1;
  gflags::SetUsageMessage(command->synopsis);
  gflags::ParseCommandLineFlags(&sub_argc, &sub_argv, /*remove_flags=*/true);
  // A flag that belongs to another command is an error, never silently ignored.
  std::vector<gflags::CommandLineFlagInfo> all;
  gflags::GetAllFlags(&all);
  for (const auto& info : all) {
    if (info.is_default || info.filename.find("tools/") == std::string::npos) continue;
    bool allowed = false;
    for (const char* f : command->flags) allowed |= info.name == f;
    if (!allowed) {
      std::fprintf(stderr, "ccdpsf: error: --%s does not apply to '%s'\n", info.name.c_str(),
                   command->name);
      return 2;
    }
  }
  std::vector<std::string> args(sub_argv + 1, sub_argv + sub_argc);
  return command->run(args);
}
