// Does the verdict cry wolf? Over many clean simulated data sets (no defect, the model's own
// physics), the fraction whose verdict is "ok", and the reasons given otherwise; the issue
// asks for at least 95 %. Every set goes the whole way a user's file goes: FITS written by
// the simulator, read, calibrated (spot search, contamination checks, censoring), fitted
// with outlier masking, and judged.
//
//   ./build/verdict_check [sets=100] [--mcmc] [--joint] [--flux_e=F] [--pixel_centre]
//
// Each set: testdata/demo_simulation.json's detector and PSF, five exposures at the given
// flux (default the demo's 4.26e5 e-, peak ~158 ke-) with positions jittered by up to
// 0.1 px, a seed per set. Without --joint the first exposure is fitted alone.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <random>
#include <string>

#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/simulate.h"

using namespace ccdpsf;
namespace fs = std::filesystem;

int main(int argc, char** argv) {
  int sets = 100;
  bool mcmc = false, joint = false, pixel_centre = false;
  double flux_e = 4.26e5;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--mcmc") == 0) {
      mcmc = true;
    } else if (std::strcmp(argv[i], "--joint") == 0) {
      joint = true;
    } else if (std::strcmp(argv[i], "--pixel_centre") == 0) {
      pixel_centre = true;
    } else if (std::strncmp(argv[i], "--flux_e=", 9) == 0) {
      flux_e = std::atof(argv[i] + 9);
    } else {
      sets = std::atoi(argv[i]);
    }
  }
  std::string error;
  std::optional<SimulationConfig> base =
      LoadSimulationConfig(std::string(CCDPSF_SOURCE_DIR) + "/testdata/demo_simulation.json", &error);
  if (!base) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  if (pixel_centre) base->model.sampling = model::Sampling::kPixelCentre;
  const std::string dir = fs::temp_directory_path().string() + "/ccdpsf_verdict_check";
  int ok = 0, done = 0;
  std::map<std::string, int> reasons;
  for (int s = 0; s < sets; ++s) {
    SimulationConfig c = *base;
    c.seed = 700000 + s;
    std::mt19937_64 engine(c.seed);
    std::uniform_real_distribution<double> jitter(-0.1, 0.1);
    for (SimulatedExposure& e : c.exposures) {
      e.x_px = 32.0 + jitter(engine);
      e.y_px = 24.0 + jitter(engine);
      // pixel_centre: the 2015 meta-parameter m, near the peak pixel (0.37 of the flux here).
      e.flux_e = pixel_centre ? 0.37 * flux_e : flux_e;
    }
    fs::remove_all(dir);
    SimulationResult sim;
    if (!RunSimulation(c, dir, false, &sim, &error)) {
      std::fprintf(stderr, "set %d: %s\n", s, error.c_str());
      continue;
    }
    std::vector<InputFile> inputs;
    for (int k = 0; k < (joint ? 5 : 1); ++k) {
      InputFile in;
      in.path = dir + "/exposure_00" + std::to_string(k) + ".fits";
      inputs.push_back(in);
    }
    ExposureSet set;
    if (!LoadExposureSet(inputs, ExposureSetOptions(), &set, &error)) {
      std::fprintf(stderr, "set %d: %s\n", s, error.c_str());
      continue;
    }
    fit::ExposuresFitOptions options;
    options.config.model.model.sampling = c.model.sampling;
    options.config.fit.run_mcmc = mcmc;
    options.config.fit.mcmc.seed = c.seed;
    options.config.fit.mcmc.progress = false;
    fit::ExposuresFit fitted;
    if (!fit::FitExposures(set.exposures, set.quality, options, &fitted, &error)) {
      std::fprintf(stderr, "set %d: %s\n", s, error.c_str());
      continue;
    }
    ++done;
    if (fitted.quality.Verdict() == "ok") {
      ++ok;
    } else {
      for (const Finding& f : fitted.quality.findings) {
        if (f.severity != Severity::kNote) ++reasons[f.code];
      }
      std::fprintf(stderr, "set %d: %s\n", s, fitted.quality.OneLine().c_str());
    }
    if ((s + 1) % 10 == 0) std::fprintf(stderr, "%d / %d sets, %d ok\n", s + 1, sets, ok);
  }
  fs::remove_all(dir);
  const double p = done > 0 ? static_cast<double>(ok) / done : NAN;
  std::printf("%s%s%s, flux %.3g e-: %d / %d clean sets ok = %.1f %% (binomial sd %.1f %%)\n",
              joint ? "joint fits of 5 exposures" : "single exposures",
              pixel_centre ? ", pixel_centre" : "", mcmc ? ", with MCMC" : ", MAP + Laplace",
              flux_e, ok, done, 100 * p, 100 * std::sqrt(p * (1 - p) / std::max(done, 1)));
  for (const auto& [code, n] : reasons) std::printf("  %-22s %d\n", code.c_str(), n);
  return 0;
}
