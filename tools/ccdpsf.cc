// ccdpsf: measure the intrinsic PSF of a CCD from spot-projection exposures.
//
// A thin dispatcher: make the command's defaults the flags' defaults, check and parse the
// flags, call the command, return its exit code. Errors on user input are one line on stderr
// and exit code 1; usage errors exit with 2 (command.h).
#include <algorithm>
#include <charconv>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"
#include "glog/logging.h"

// The parser's flags read by several commands; their meanings are the commands' options.
DEFINE_string(config, "", "");
DEFINE_string(out, "", "");
DEFINE_string(plot_format, "png", "");
DEFINE_string(truth, "", "");
DEFINE_string(sampling, "integrated", "");
DEFINE_string(defocus, "gaussian", "");

namespace ccdpsf::tools {

const std::vector<Command>& Commands() {
  static const std::vector<Command> commands = {SimulateCommand(), FitCommand(),    TrendCommand(),
                                                DiagnoseCommand(), GainCommand(),   PtcCommand(),
                                                GridCommand(),     EffectsCommand()};
  return commands;
}

namespace {
const Command* current_command = nullptr;
}  // namespace

const Command& CurrentCommand() { return *current_command; }
void SetCurrentCommand(const Command& command) { current_command = &command; }

const Option* Command::Find(const std::string& option) const {
  for (const Option& o : options) {
    if (o.name == option) return &o;
  }
  return nullptr;
}

std::string NumberText(double value) {
  char text[64];
  // The shortest round-trip form (fixed or scientific, whichever is shorter).
  const auto end = std::to_chars(text, text + sizeof(text), value).ptr;
  return std::string(text, end);
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

// The edit distance between a and b (insertions, deletions, substitutions and swaps of two
// neighbours, each 1: the optimal string alignment distance).
size_t EditDistance(const std::string& a, const std::string& b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    for (size_t j = 1; j <= b.size(); ++j) {
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1,
                          d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) {
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
      }
    }
  }
  return d[a.size()][b.size()];
}

// "; did you mean --x?" for the command's option nearest to `name` when it is near enough to
// be a slip (within 2 edits, and fewer than half the name's letters; or `name` begins it),
// else "". The first of equally near options in the command's table.
std::string DidYouMean(const std::string& name, const Command& command) {
  const Option* best = nullptr;
  size_t best_distance = 0;
  for (const Option& o : command.options) {
    const bool prefix = name.size() >= 3 && o.name.rfind(name, 0) == 0;
    const size_t distance = prefix ? 1 : EditDistance(name, o.name);
    if (distance > 2 || 2 * distance >= name.size()) continue;
    if (best == nullptr || distance < best_distance) {
      best = &o;
      best_distance = distance;
    }
  }
  return best == nullptr ? "" : "; did you mean --" + best->name + "?";
}

// Checks the flags in argv[first..argc) before gflags parses them: gflags ends the process
// with exit code 1 on an unknown flag or a value it cannot parse, where a usage error must
// exit with 2; and it knows every command's flags (and its own, --flagfile, --version ...),
// where only the command's options are allowed. Empty if every flag is one of the command's
// and its value parses; else a one-line reason.
std::string FlagSyntaxError(int first, int argc, char** argv, const Command& command) {
  const std::string cname = command.name;
  for (int i = first; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--") break;  // positional arguments only after it
    if (arg.size() < 2 || arg[0] != '-') continue;
    arg.erase(0, arg[1] == '-' ? 2 : 1);
    const size_t eq = arg.find('=');
    std::string name = arg.substr(0, eq);
    gflags::CommandLineFlagInfo info;
    // --nofoo for a boolean foo.
    if (command.Find(name) == nullptr && eq == std::string::npos && name.rfind("no", 0) == 0 &&
        command.Find(name.substr(2)) != nullptr &&
        gflags::GetCommandLineFlagInfo(name.substr(2).c_str(), &info) && info.type == "bool") {
      continue;
    }
    if (command.Find(name) == nullptr) {
      for (const Command& other : Commands()) {
        if (other.Find(name) != nullptr) {
          return "--" + name + " does not apply to '" + cname + "'; 'ccdpsf " + cname +
                 " --help' lists its options";
        }
      }
      const std::string guess = DidYouMean(name, command);
      if (!guess.empty()) return "unknown option --" + name + " for '" + cname + "'" + guess;
      return "unknown option --" + name + " for '" + cname + "'; 'ccdpsf " + cname +
             " --help' lists its options";
    }
    if (!gflags::GetCommandLineFlagInfo(name.c_str(), &info)) {
      return "option --" + name + " has no flag";  // a table naming a flag never defined
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

// Makes each of the command's options default to the command's value: the flag then holds
// it until given, and is_default (FlagGiven) stays as gflags keeps it.
void ApplyCommandDefaults(const Command& command) {
  for (const Option& o : command.options) {
    const std::string set = gflags::SetCommandLineOptionWithMode(
        o.name.c_str(), o.default_value.c_str(), gflags::SET_FLAGS_DEFAULT);
    // Only a wrong table can fail here; say so rather than run with another default.
    if (set.empty()) {
      std::fprintf(stderr, "ccdpsf: internal error: %s's default for --%s ('%s') is not valid\n",
                   command.name, o.name.c_str(), o.default_value.c_str());
      std::exit(70);
    }
  }
}

void PrintCommandHelp(const Command& c) {
  std::printf("%s\n\n  %s\n\nOptions:\n", c.synopsis, c.summary);
  for (const Option& o : c.options) {
    gflags::CommandLineFlagInfo info;
    if (!gflags::GetCommandLineFlagInfo(o.name.c_str(), &info)) continue;
    if (o.no_default) {
      std::printf("  --%s (%s; no default)\n      %s\n", o.name.c_str(), info.type.c_str(),
                  o.description.c_str());
    } else {
      std::printf("  --%s (%s; default \"%s\")\n      %s\n", o.name.c_str(), info.type.c_str(),
                  o.default_value.c_str(), o.description.c_str());
    }
  }
  std::printf(
      "  --help\n      This list\n  --version\n      The versions of ccdpsf and its "
      "libraries\n");
}

void PrintVersions() { std::printf("%s\n", SoftwareVersions().dump(2).c_str()); }

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
  if (name == "version" || name == "--version" || name == "-version") {
    ccdpsf::tools::PrintVersions();
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
    if (std::strcmp(argv[i], "--") == 0) break;
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0 ||
        std::strcmp(argv[i], "-help") == 0) {
      ccdpsf::tools::PrintCommandHelp(*command);
      return 0;
    }
    if (std::strcmp(argv[i], "--version") == 0 || std::strcmp(argv[i], "-version") == 0) {
      ccdpsf::tools::PrintVersions();
      return 0;
    }
  }
  ccdpsf::tools::SetCurrentCommand(*command);
  ccdpsf::tools::ApplyCommandDefaults(*command);
  const std::string syntax = ccdpsf::tools::FlagSyntaxError(2, argc, argv, *command);
  if (!syntax.empty()) return ccdpsf::tools::Usage(syntax);
  // gflags sees the arguments after the command name; positional arguments remain.
  int sub_argc = argc - 1;
  char** sub_argv = argv + 1;
  gflags::SetUsageMessage(command->synopsis);
  gflags::ParseCommandLineFlags(&sub_argc, &sub_argv, /*remove_flags=*/true);
  std::vector<std::string> args(sub_argv + 1, sub_argv + sub_argc);
  return command->run(args);
}
