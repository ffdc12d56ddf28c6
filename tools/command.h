// The subcommands of the ccdpsf binary. Each lives in tools/<name>_command.cc with the table
// of its options and registers itself here; tools/ccdpsf.cc dispatches.
//
// gflags is the parser: every flag is defined once (DEFINE_* in the file that first reads
// it) for all commands. What a flag means and defaults to is the command's: its Option
// table. Before parsing, main() makes each option's default the command's
// (gflags::SET_FLAGS_DEFAULT), so a flag not given holds the command's default and
// FlagGiven() stays false for it; `--help` prints the table; an option not in the table is a
// usage error.
#ifndef CCDPSF_TOOLS_COMMAND_H_
#define CCDPSF_TOOLS_COMMAND_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/photon_transfer_frames.h"

namespace ccdpsf::tools {

// One option of a command, as that command's help shows it.
struct Option {
  std::string name;           // the flag, without "--"
  std::string default_value;  // this command's default, as flag text ("1000", "true", "")
  std::string description;    // what it does in this command
  // The flag's value means "not given" until it is given (the metadata flags: the value
  // then comes from the manifest or the header); help shows no default.
  bool no_default = false;
};

struct Command {
  const char* name;
  const char* synopsis;
  const char* summary;
  std::vector<Option> options;
  // args: the positional arguments after flag parsing. Returns the exit code.
  int (*run)(const std::vector<std::string>& args);

  // The option named `name`, or null when the command has none of that name.
  const Option* Find(const std::string& name) const;
};

const std::vector<Command>& Commands();

// The command being run (set by main() before it parses the flags).
const Command& CurrentCommand();
void SetCurrentCommand(const Command& command);

// A number as the shortest text that reads back to it exactly ("1000", "0.01").
std::string NumberText(double value);

// The commands, defined in their files.
Command SimulateCommand();
Command FitCommand();
Command TrendCommand();
Command DiagnoseCommand();
Command GainCommand();
Command PtcCommand();
Command GridCommand();
Command EffectsCommand();

// The fit options of `fit`, `trend` and `diagnose`: the command's defaults <- --config=FIT.json
// (its "flags" applied as flags not given on the command line: run_config.cc) <- the flags
// given (defined in fit_command.cc). False with a one-line reason on bad values.
bool ResolveFitConfig(fit::FitConfig* config, std::string* error);

// --ptc, the flats' boundary-shift prior, as fit's and trend's help shows it.
Option PtcOption();

// The options of a run as FIT.json (fit_config.h) holding every option it resolved: `config`
// with the --keywords flag's names merged into "keywords", and under "flags" every other
// option of the current command that decides what the run computes (the metadata flags only
// where given). `command_options` adds command-specific entries to "flags" (trend's
// requirement list). Written as OUT/config.json, so that --config=OUT/config.json with the
// same inputs repeats the run (run_config.cc).
nlohmann::json RunConfigJson(const fit::FitConfig& config, const nlohmann::json& command_options,
                             std::string* error);
// Writes it as dir/config.json. False with a one-line reason.
bool WriteRunConfig(const std::string& dir, const fit::FitConfig& config,
                    const nlohmann::json& command_options, std::string* error);
// Applies FIT.json's "flags" to the current command: each one not given on the command line
// is set as if it were; `skip` names entries the command reads itself ("requirements").
// False with a one-line reason for an option the command does not have or a value of the
// wrong type.
bool ApplyConfigFlags(const nlohmann::json& flags, const std::vector<std::string>& skip,
                      std::string* error);

// Prints "ccdpsf: error: <message>" on stderr and returns exit code 1.
int Fail(const std::string& message);

// Exit code of a usage error: an unknown option, a value that does not parse, a missing
// --out or input. Usage() prints "ccdpsf: error: <message>" on stderr and returns it.
constexpr int kExitUsage = 2;
int Usage(const std::string& message);

// Exit code of a completed run whose verdict is suspect or invalid under --strict.
constexpr int kExitStrict = 3;

// The options that say what a file's header lacks, shared by fit, diagnose and trend, and the
// reader's memory ceiling (tools/input_flags.cc).
std::vector<Option> InputOptions();
// --max_image_mb, the reader's memory ceiling, as every command that reads FITS files shows it.
Option MaxImageMbOption();
// The values the flags give (sources "flag --name") and the keyword map's overlay.
bool InputFlags(GivenMetadata* given, KeywordMap* keywords, std::string* error);
// The run's files with their options: flags, then --manifest's rows, then `config`.
// `files` may be empty with --manifest. *manifest receives the manifest if one was given.
bool ResolveInputs(const std::vector<std::string>& files, const CalibrationOptions& config,
                   std::vector<InputFile>* inputs, Manifest* manifest, std::string* error);

// The files of a photon-transfer command (gain, ptc) and what --manifest, --exptime_s,
// --bias_adu and --saturation_adu say of them: per file its exposure time (the flag for every
// file, else its manifest row, else NaN: the EXPTIME keyword) and scene (its manifest
// setting); one bias and one saturation level for the set (the flag, else the manifest's rows,
// which must agree). `args` may be empty with --manifest: every file it lists. `purpose` names
// the command's result in messages ("the gain estimate"). False with a one-line reason; the
// caller checks the options' validity.
bool ResolveTransferInputs(const std::vector<std::string>& args, const std::string& purpose,
                           std::vector<std::string>* files, TransferFrameOptions* options,
                           std::string* error);
// The options of those flags as the photon-transfer commands' help shows them.
std::vector<Option> TransferInputOptions();
// Those flags for run.json: the files, and each flag's value (null when not given).
nlohmann::json TransferRunOptions(const std::vector<std::string>& files);

// What a run reads: `args` and the files named by --config, --manifest, --keywords,
// --bad_pixel_mask and --requirements where given. An output folder must not hold any of
// them (it is replaced as a whole: output_folder.h).
std::vector<std::string> RunInputs(const std::vector<std::string>& args);

// What decides a run's numbers, for the keys of its stored results (trend/group_store.h):
// the inputs and every option given, but not those that change only where or how fast it
// runs (--out, --resume, --threads), with the files --config, --manifest, --keywords and
// --requirements name by content.
std::string RunSignature(const std::vector<std::string>& inputs);

// True when --name was given on the command line (or by the "flags" of --config).
bool FlagGiven(const char* name);

}  // namespace ccdpsf::tools

#endif  // CCDPSF_TOOLS_COMMAND_H_
