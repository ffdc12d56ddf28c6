// OUT/config.json: a run's resolved options in FIT.json's format (fit/fit_config.h), and
// FIT.json's "flags" applied to the command that reads it. Together they make
// `ccdpsf <command> --config=OUT/config.json INPUTS` repeat a run of fit, trend or diagnose.
#include <algorithm>
#include <filesystem>
#include <map>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/metadata.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(keywords);

namespace ccdpsf::tools {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Flags whose value FIT.json's own keys hold (fit::FitConfigJson): in "flags" they would be a
// second place for one setting, so they are refused there.
const std::map<std::string, std::string>& HeldByFitJson() {
  static const std::map<std::string, std::string> held = {{"sampling", "sampling"},
                                                          {"defocus", "defocus"},
                                                          {"likelihood", "likelihood"},
                                                          {"joint", "joint"},
                                                          {"through_focus", "through_focus"},
                                                          {"flux", "flux"},
                                                          {"effects", "effects"},
                                                          {"seed", "mcmc.seed"},
                                                          {"walkers", "mcmc.walkers"},
                                                          {"max_steps", "mcmc.max_steps"},
                                                          {"target_ess", "mcmc.target_ess"},
                                                          {"threads", "mcmc.threads"},
                                                          {"mcmc", "mcmc.enabled"},
                                                          {"stamp_size", "calibration.stamp_size"},
                                                          {"keywords", "keywords"}};
  return held;
}

// Options about where and how a run is invoked, not what it computes; a config sets none.
bool AboutTheInvocation(const std::string& name) {
  return name == "out" || name == "config" || name == "resume";
}

// Options whose value is a path, recorded absolute so the config works from any folder.
bool IsPathOption(const std::string& name) {
  return name == "manifest" || name == "bad_pixel_mask" || name == "ptc";
}

// The flag's current value as typed JSON (gflags' type names).
json FlagValueJson(const gflags::CommandLineFlagInfo& info) {
  const std::string& v = info.current_value;
  if (info.type == "bool") return v == "true";
  if (info.type == "int32" || info.type == "int64") return std::stoll(v);
  if (info.type == "uint32" || info.type == "uint64") return std::stoull(v);
  if (info.type == "double") return std::stod(v);
  return v;
}

// `value` as the text of a flag of gflags type `type`; false when the JSON type does not fit.
bool FlagText(const json& value, const std::string& type, std::string* text) {
  if (type == "bool") {
    if (!value.is_boolean()) return false;
    *text = value.get<bool>() ? "true" : "false";
  } else if (type == "int32" || type == "int64" || type == "uint32" || type == "uint64") {
    if (!value.is_number_integer()) return false;
    *text = value.dump();
  } else if (type == "double") {
    if (!value.is_number()) return false;
    *text = value.is_number_integer() ? value.dump() : NumberText(value.get<double>());
  } else {
    if (!value.is_string()) return false;
    *text = value.get<std::string>();
  }
  return true;
}

bool IsMetadataOrManifest(const std::string& name) {
  return IsMetadataQuantity(name) || name == "manifest";
}

}  // namespace

json RunConfigJson(const fit::FitConfig& config, const json& command_options, std::string* error) {
  json j = fit::FitConfigJson(config);
  // The keyword map in use: FIT.json's with --keywords laid over it. A default name switched
  // off is written as "" (off), since FIT.json's map is laid over the default one.
  KeywordMap keywords = config.calibration.keywords;
  if (FlagGiven("keywords") && !keywords.OverlayFileOrText(FLAGS_keywords, error)) return json();
  json names = keywords.ToJson();
  const KeywordMap defaults;
  for (const auto& [quantity, rule] : defaults.rules()) {
    if (keywords.Find(quantity) == nullptr) names[quantity] = "";
  }
  j["keywords"] = names;
  json flags = json::object();
  for (const Option& o : CurrentCommand().options) {
    if (AboutTheInvocation(o.name) || HeldByFitJson().count(o.name) > 0) continue;
    // A metadata flag or manifest not given means "from the manifest / header": nothing to
    // record.
    if (IsMetadataOrManifest(o.name) && !FlagGiven(o.name.c_str())) continue;
    gflags::CommandLineFlagInfo info;
    if (!gflags::GetCommandLineFlagInfo(o.name.c_str(), &info)) continue;
    json value = FlagValueJson(info);
    if (IsPathOption(o.name) && !info.current_value.empty()) {
      value = fs::absolute(fs::path(info.current_value)).lexically_normal().string();
    }
    flags[o.name] = value;
  }
  for (auto it = command_options.begin(); it != command_options.end(); ++it) {
    flags[it.key()] = it.value();
  }
  j["flags"] = flags;
  return j;
}

bool WriteRunConfig(const std::string& dir, const fit::FitConfig& config,
                    const json& command_options, std::string* error) {
  const json j = RunConfigJson(config, command_options, error);
  if (j.is_null()) return false;
  return WriteTextFileAtomically(dir + "/config.json", j.dump(2) + "\n", error);
}

bool ApplyConfigFlags(const json& flags, const std::vector<std::string>& skip, std::string* error) {
  const Command& command = CurrentCommand();
  for (auto it = flags.begin(); it != flags.end(); ++it) {
    const std::string& name = it.key();
    if (std::find(skip.begin(), skip.end(), name) != skip.end()) continue;
    const std::string where = "'flags." + name + "'";
    if (command.Find(name) == nullptr) {
      *error = where + " is not an option of '" + command.name + "'";
      return false;
    }
    const auto held = HeldByFitJson().find(name);
    if (held != HeldByFitJson().end()) {
      *error = where + ": give it as '" + held->second + "'";
      return false;
    }
    if (AboutTheInvocation(name)) {
      *error = where + ": --" + name + " is given on the command line only";
      return false;
    }
    gflags::CommandLineFlagInfo info;
    gflags::GetCommandLineFlagInfo(name.c_str(), &info);
    std::string text;
    if (!FlagText(it.value(), info.type, &text)) {
      *error = where + " must be a " +
               (info.type == "bool"     ? std::string("boolean")
                : info.type == "double" ? std::string("number")
                : info.type == "string" ? std::string("string")
                                        : std::string("integer"));
      return false;
    }
    if (FlagGiven(name.c_str())) continue;  // the command line outranks the file
    if (gflags::SetCommandLineOption(name.c_str(), text.c_str()).empty()) {
      *error = where + " = " + text + " is not a valid " + info.type + " value";
      return false;
    }
  }
  return true;
}

std::string RunSignature(const std::vector<std::string>& inputs) {
  nlohmann::json signature = {{"inputs", inputs}};
  std::vector<gflags::CommandLineFlagInfo> flags;
  gflags::GetAllFlags(&flags);
  for (const auto& f : flags) {
    if (f.is_default || f.name == "out" || f.name == "resume" || f.name == "threads") continue;
    signature["flags"][f.name] = f.current_value;
  }
  // The files --config, --manifest, --keywords, --requirements and --ptc name, by content.
  for (const char* flag : {"config", "manifest", "keywords", "requirements", "ptc"}) {
    std::string path;
    if (!gflags::GetCommandLineOption(flag, &path) || path.empty()) continue;
    // Unreadable here: the command itself reports it (this only identifies the run).
    std::string text, error;
    if (!ReadTextInput(path, flag, &text, &error)) text = error;
    signature["files"][flag] = text;
  }
  return signature.dump();
}

}  // namespace ccdpsf::tools
