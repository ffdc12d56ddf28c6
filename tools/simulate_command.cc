// ccdpsf simulate: the paper's 9-step simulator, for one set of exposures or (a config whose
// top level has the key "campaign") a whole characterisation campaign with a known truth.
#include <cstdio>

#include "ccdpsf/campaign_simulation.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/simulate.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DEFINE_bool(noiseless, false, "");  // meaning: SimulateCommand()'s table

namespace ccdpsf::tools {
namespace {

nlohmann::json RunOptions() {
  return {{"config", FLAGS_config}, {"out", FLAGS_out}, {"noiseless", FLAGS_noiseless}};
}

int RunCampaignSimulation() {
  std::string error;
  auto config = LoadCampaignConfig(FLAGS_config, &error);
  if (!config) return Fail(error);
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs({}), {}, &error)) return Fail(error);
  CampaignResult result;
  if (!RunCampaign(*config, out.partial(), FLAGS_noiseless, &result, &error) ||
      !WriteRunRecord(out.partial(), "simulate", RunOptions(), config->seed, &error) ||
      !out.Commit({}, &error)) {
    return Fail(error);
  }
  std::printf("simulated a campaign of %d groups, %d %s into %s (manifest: %s/manifest.json)\n",
              result.groups, result.exposures, FLAGS_noiseless ? "noiseless models" : "exposures",
              FLAGS_out.c_str(), FLAGS_out.c_str());
  return 0;
}

int RunSimulate(const std::vector<std::string>& args) {
  if (!args.empty()) return Usage("simulate takes no file arguments (got '" + args[0] + "')");
  if (FLAGS_config.empty()) return Usage("simulate needs --config=SIM.json");
  if (FLAGS_out.empty()) return Usage("simulate needs --out=DIR");
  {
    std::string text, error;
    if (!ReadTextInput(FLAGS_config, "simulation config", &text, &error)) return Fail(error);
    if (IsCampaignConfig(text)) return RunCampaignSimulation();
  }
  std::string error;
  auto config = LoadSimulationConfig(FLAGS_config, &error);
  if (!config) return Fail(error);
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs({}), {}, &error)) return Fail(error);
  SimulationResult result;
  if (!RunSimulation(*config, out.partial(), FLAGS_noiseless, &result, &error) ||
      !WriteRunRecord(out.partial(), "simulate", RunOptions(), config->seed, &error) ||
      !out.Commit({}, &error)) {
    return Fail(error);
  }
  std::printf("simulated %zu %s into %s (truth: %s/truth.json)\n", result.files.size(),
              FLAGS_noiseless ? "noiseless models" : "exposures", FLAGS_out.c_str(),
              FLAGS_out.c_str());
  return 0;
}

}  // namespace

Command SimulateCommand() {
  return {"simulate",
          "ccdpsf simulate --config=SIM.json --out=DIR [--noiseless]",
          "Simulate spot-projection exposures (the paper's 9-step procedure), or a whole "
          "campaign with a known truth.",
          {{"config", "",
            "The simulation config SIM.json (required); a top-level \"campaign\" key makes a "
            "whole campaign"},
           {"out", "", "Output folder (required); replaced as a whole by the simulated files"},
           {"noiseless", "false",
            "Write the expected electrons per pixel as 64-bit floats (model_NNN.fits) instead "
            "of noisy 16-bit exposures"}},
          RunSimulate};
}

}  // namespace ccdpsf::tools
