// Simulation-based calibration of the fit's intervals (issue 3): over many simulated data
// sets with known truth, how often the 68 % intervals contain the truth, for every identified
// quantity. Prints one line per quantity: coverage of the Laplace interval (MAP +- sd) and,
// with --mcmc, of the MCMC 68 % interval; the binomial sd is sqrt(0.68 0.32 / n).
//   ./build/calibration_check [n=200] [--mcmc]
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <string>

#include "ccdpsf/fit/fit.h"
#include "support/simulated_stamps.h"

using namespace ccdpsf;

int main(int argc, char** argv) {
  int n = 200;
  bool mcmc = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--mcmc") == 0) mcmc = true;
    else n = std::atoi(argv[i]);
  }
  std::map<std::string, int> laplace_in, mcmc_in;
  int done = 0;
  for (int s = 0; s < n; ++s) {
    const SimulationConfig c =
        testing_support::PaperConfig(model::Sampling::kIntegrated, 1, 5000 + s);
    std::string error;
    auto model = fit::FitModel::Create(testing_support::SimulateStamps(c, 9000 + s),
                                       fit::FitModelOptions(), &error);
    fit::FitOptions o;
    o.run_mcmc = mcmc;
    o.mcmc.seed = s;
    o.mcmc.progress = false;
    o.mcmc.target_ess = 400;
    fit::FitResult r;
    if (!model || !fit::RunFit(*model, o, &r, &error)) {
      std::fprintf(stderr, "data set %d: %s\n", s, error.c_str());
      continue;
    }
    ++done;
    std::map<std::string, std::pair<double, fit::Summary>> q;
    q["flux_e"] = {c.exposures[0].flux_e, r.parameters[fit::kFluxE]};
    q["airy_radius_px"] = {c.airy_radius_px, r.parameters[fit::kAiryRadiusPx]};
    q["x_px"] = {c.exposures[0].x_px, r.parameters[fit::FitModel::XIndex(0)]};
    q["y_px"] = {c.exposures[0].y_px, r.parameters[fit::FitModel::YIndex(0)]};
    for (const auto& [name, summary] : r.derived) {
      if (name == "total_sigma_x_px") q[name] = {std::hypot(c.defocus_px, c.ccd_sigma_x_px), summary};
      if (name == "total_sigma_y_px") q[name] = {std::hypot(c.defocus_px, c.ccd_sigma_y_px), summary};
    }
    for (const auto& [name, v] : q) {
      const double truth = v.first;
      const fit::Summary& sm = v.second;
      laplace_in[name] += std::fabs(sm.map - truth) < sm.laplace_sd;
      if (mcmc) mcmc_in[name] += truth > sm.lo68 && truth < sm.hi68;
    }
    if ((s + 1) % 20 == 0) std::fprintf(stderr, "%d / %d data sets\n", s + 1, n);
  }
  std::printf("data sets: %d; binomial sd of a 68 %% coverage: %.1f %%\n", done,
              100 * std::sqrt(0.68 * 0.32 / std::max(done, 1)));
  for (const auto& [name, count] : laplace_in) {
    std::printf("%-18s Laplace %.1f %%", name.c_str(), 100.0 * count / done);
    if (mcmc) std::printf("   MCMC %.1f %%", 100.0 * mcmc_in[name] / done);
    std::printf("\n");
  }
  return 0;
}
