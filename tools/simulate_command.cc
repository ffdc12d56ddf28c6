// ccdpsf simulate: the paper's 9-step simulator.
#include <cstdio>

#include "ccdpsf/provenance.h"
#include "ccdpsf/simulate.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DEFINE_bool(noiseless, false,
            "simulate: write the expected electrons per pixel as 64-bit floats "
            "(model_NNN.fits) instead of noisy 16-bit exposures");

namespace ccdpsf::tools {
namespace {

int RunSimulate(const std::vector<std::string>& args) {
  if (!args.empty()) return Fail("simulate takes no file arguments (got '" + args[0] + "')");
  if (FLAGS_config.empty()) return Fail("simulate needs --config=SIM.json");
  if (FLAGS_out.empty()) return Fail("simulate needs --out=DIR");
  std::string error;
  auto config = LoadSimulationConfig(FLAGS_config, &error);
  if (!config) return Fail(error);
  SimulationResult result;
  if (!RunSimulation(*config, FLAGS_out, FLAGS_noiseless, &result, &error)) return Fail(error);
  nlohmann::json options = {{"config", FLAGS_config},
                            {"out", FLAGS_out},
                            {"noiseless", FLAGS_noiseless}};
  if (!WriteRunRecord(FLAGS_out, "simulate", options, config->seed, &error)) return Fail(error);
  std::printf("simulated %zu %s into %s (truth: %s)\n", result.files.size(),
              FLAGS_noiseless ? "noiseless models" : "exposures", FLAGS_out.c_str(),
              result.truth_path.c_str());
  return 0;
}

}  // namespace

Command SimulateCommand() {
  return {"simulate", "ccdpsf simulate --config=SIM.json --out=DIR [--noiseless]",
          "Simulate spot-projection exposures with the paper's 9-step procedure.",
          {"config", "out", "noiseless"}, RunSimulate};
}

}  // namespace ccdpsf::tools
