// The subcommands of the ccdpsf binary. Each lives in tools/<name>_command.cc, defines its
// own gflags, and registers itself here; tools/ccdpsf.cc dispatches.
#ifndef CCDPSF_TOOLS_COMMAND_H_
#define CCDPSF_TOOLS_COMMAND_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/manifest.h"

namespace ccdpsf::tools {

struct Command {
  const char* name;
  const char* synopsis;
  const char* summary;
  std::vector<const char*> flags;  // the gflags this command reads
  // args: the positional arguments after flag parsing. Returns the exit code.
  int (*run)(const std::vector<std::string>& args);
};

const std::vector<Command>& Commands();

// The commands, defined in their files.
Command SimulateCommand();
Command FitCommand();
Command TrendCommand();
Command DiagnoseCommand();
Command GainCommand();

// The fit options of `fit` and `trend`: defaults <- --config=FIT.json <- the fit flags given
// (defined in fit_command.cc). False with a one-line reason on bad values.
bool ResolveFitConfig(fit::FitConfig* config, std::string* error);

// Prints "ccdpsf: error: <message>" on stderr and returns exit code 1.
int Fail(const std::string& message);

// Exit code of a usage error: an unknown option, a value that does not parse, a missing
// --out or input. Usage() prints "ccdpsf: error: <message>" on stderr and returns it.
constexpr int kExitUsage = 2;
int Usage(const std::string& message);

// Exit code of a completed run whose verdict is suspect or invalid under --strict.
constexpr int kExitStrict = 3;

// The metadata flags shared by fit, diagnose and trend (tools/input_flags.cc).
const std::vector<const char*>& InputFlagNames();
// The values the flags give (sources "flag --name") and the keyword map's overlay.
bool InputFlags(GivenMetadata* given, KeywordMap* keywords, std::string* error);
// The run's files with their options: flags, then --manifest's rows, then `config`.
// `files` may be empty with --manifest. *manifest receives the manifest if one was given.
bool ResolveInputs(const std::vector<std::string>& files, const CalibrationOptions& config,
                   std::vector<InputFile>* inputs, Manifest* manifest, std::string* error);

// What a run reads: `args` and the files named by --config, --manifest, --keywords,
// --bad_pixel_mask and --requirements where given. An output folder must not hold any of
// them (it is replaced as a whole: output_folder.h).
std::vector<std::string> RunInputs(const std::vector<std::string>& args);

// True when --name was given on the command line.
bool FlagGiven(const char* name);

}  // namespace ccdpsf::tools

#endif  // CCDPSF_TOOLS_COMMAND_H_
