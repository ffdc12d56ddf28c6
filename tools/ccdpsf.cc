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
DEFINE_string(plot_format, "png", "fit, trend, diagnose: format of the plots: png, pdf or svg");
DEFINE_string(truth, "",
              "fit, trend: truth.json of simulated data, drawn on the plots (default: a "
              "truth.json in the folder holding all the inputs, if there is one)");
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

int Usage(const std::string& message) {
  std::fprintf(stderr, "ccdpsf: error: %s\n", message.c_str());
  return kExitUsage;
}

bool FlagGiven(const char* name) {
  gflags::CommandLineFlagInfo info;
  return gflags::GetCommandLineFlagInfo(name, &info) && !info.is_default;
}

namespace {

// Checks the flags in argv[first..argc) before gflags parses them: gflags ends the process
// with exit code 1 on an unknown flag or a value it cannot parse, where a usage error must
// exit with 2. Empty if every flag is known and its value parses; else a one-line reason.
std::string FlagSyntaxError(int first, int argc, char** argv, const char* command) {
  for (int i = first; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--") break;  // positional arguments only after it
    if (arg.size() < 2 || arg[0] != '-') continue;
    arg.erase(0, arg[1] == '-' ? 2 : 1);
    const size_t eq = arg.find('=');
    const std::string name = arg.substr(0, eq);
    gflags::CommandLineFlagInfo info;
    if (!gflags::GetCommandLineFlagInfo(name.c_str(), &info)) {
      // --nofoo for a boolean foo.
      if (eq == std::string::npos && name.rfind("no", 0) == 0 &&
          gflags::GetCommandLineFlagInfo(name.substr(2).c_str(), &info) && info.type == "bool") {
        continue;
      }
      return "unknown option --" + name + " for '" + command + "'; 'ccdpsf help " + command +
             "' lists its options";
    }
    std::string value;
    if (eq != std::string::npos) {
      value = arg.substr(eq + 1);
    } else if (info.type == "bool") {
      continue;
    } else if (i + 1 < argc) {
      value = argv[++i];  // "--name value"
    } else {
      return "--" + name + " needs a value";
    }
    // Parsed as gflags will parse it (the value is set again, identically, by the parse).
    if (gflags::SetCommandLineOption(name.c_str(), value.c_str()).empty()) {
      return "--" + name + "=" + value + " is not a valid " + info.type + " value";
    }
  }
  return "";
}

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
    return ccdpsf::tools::kExitUsage;
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
    return ccdpsf::tools::kExitUsage;
  }
  for (int i = 2; i < argc; ++i) {
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0 ||
        std::strcmp(argv[i], "-help") == 0) {
      ccdpsf::tools::PrintCommandHelp(*command);
      return 0;
    }
  }
  const std::string syntax = ccdpsf::tools::FlagSyntaxError(2, argc, argv, command->name);
  if (!syntax.empty()) return ccdpsf::tools::Usage(syntax);
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
      return ccdpsf::tools::Usage("--" + info.name + " does not apply to '" + command->name +
                                  "'");
    }
  }
  std::vector<std::string> args(sub_argv + 1, sub_argv + sub_argc);
  return command->run(args);
}
