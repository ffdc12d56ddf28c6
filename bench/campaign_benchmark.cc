// The whole Table-1 campaign end to end, timed: simulate the paper's 13 settings (87
// exposures, pixel_centre sampling, truth = the paper's relations), run `trend`'s pipeline
// (joint fit with MCMC of every group, two groups at a time, then the relations and the
// requirement checks) and compare the recovered relations with the truth.
//
//   ./build/campaign_benchmark [runs] [config.json]     (defaults: 1, testdata/campaign_table1.json)
//
// Prints each run's wall time and their median, and per run: alpha of FWHM(lambda) and the
// 800 nm intensity slope of FWHM against the truth, in units of the reported sd (68 %
// half-width), and the requirement verdicts against the truth's.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "ccdpsf/campaign_simulation.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"
#include "ccdpsf/trend/trend.h"

namespace fs = std::filesystem;
using namespace ccdpsf;

int main(int argc, char** argv) {
  const int runs = argc > 1 ? std::max(1, std::atoi(argv[1])) : 1;
  const std::string config_path =
      argc > 2 ? argv[2] : std::string(CCDPSF_SOURCE_DIR) + "/testdata/campaign_table1.json";
  std::string error;
  auto config = LoadCampaignConfig(config_path, &error);
  if (!config) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  const std::string dir = (fs::temp_directory_path() / "ccdpsf_campaign_benchmark").string();
  fs::remove_all(dir);
  CampaignResult sim;
  if (!RunCampaign(*config, dir, false, &sim, &error)) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  std::printf("campaign: %d groups, %d exposures (%s sampling)\n", sim.groups, sim.exposures,
              model::ToString(config->sampling).c_str());

  // Truth: alpha of the geometric-mean FWHM, and the least-squares line through the true
  // FWHM of the 800 nm settings.
  const CampaignTruth& truth = config->truth;
  const double alpha_true = truth.GeometricAlpha();
  double sx = 0, sy = 0, sxx = 0, sxy = 0, n = 0;
  for (const CampaignSetting& s : config->settings) {
    if (s.wavelength_nm != 800) continue;
    const double f = std::sqrt(truth.FwhmXUm(s.peak_e, 800) * truth.FwhmYUm(s.peak_e, 800));
    sx += s.peak_e;
    sy += f;
    sxx += s.peak_e * s.peak_e;
    sxy += s.peak_e * f;
    n += 1;
  }
  const double slope_true = (n * sxy - sx * sy) / (n * sxx - sx * sx);

  std::vector<double> seconds;
  for (int run = 0; run < runs; ++run) {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<trend::CampaignGroup> groups;
    if (!trend::LoadCampaign({sim.manifest_path}, &groups, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    trend::GroupFitOptions options;
    options.config.model.model.sampling = config->sampling;
    options.config.fit.mcmc.target_ess = 400;  // as `ccdpsf trend` by default
    options.parallel_groups = 2;
    options.seed = 1;
    std::vector<trend::GroupResult> results = trend::FitGroups(
        groups, options, [](const trend::GroupResult& r, int done, int total) {
          std::fprintf(stderr, "  [%d/%d] %s %s %.1f s\n", done, total, r.group.name.c_str(),
                       r.ok ? (r.converged ? "converged" : "NOT converged") : r.failure.c_str(),
                       r.seconds);
        });
    trend::TrendResult tr;
    if (!trend::ComputeTrend(std::move(results), trend::TrendOptions(), &tr, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    seconds.push_back(s);
    const trend::Estimate& alpha = tr.relations.at("fwhm_um_vs_wavelength").Find("alpha")->estimate;
    const trend::Estimate& slope = tr.relations.at("fwhm_um_vs_intensity").Find("slope")->estimate;
    const double alpha_sd = 0.5 * (alpha.hi68 - alpha.lo68);
    const double slope_sd = 0.5 * (slope.hi68 - slope.lo68);
    std::printf("run %d: %.1f s\n", run + 1, s);
    std::printf("  alpha(FWHM) = %.4f [%.4f, %.4f], truth %.4f: %+.2f sd\n", alpha.median,
                alpha.lo68, alpha.hi68, alpha_true, (alpha.median - alpha_true) / alpha_sd);
    std::printf("  800 nm slope = %.4g [%.4g, %.4g] um/e-, truth %.4g: %+.2f sd\n", slope.median,
                slope.lo68, slope.hi68, slope_true, (slope.median - slope_true) / slope_sd);
    for (const trend::RequirementResult& q : tr.requirements) {
      std::printf("  requirement %-20s value %.4g  pass %s  P(pass) %.3f  verdict %s\n",
                  q.requirement.name.c_str(), q.value.median,
                  q.pass ? (*q.pass ? "yes" : "no") : "n/a", q.pass_probability,
                  trend::Verdict(q).c_str());
    }
  }
  std::sort(seconds.begin(), seconds.end());
  std::printf("median wall time over %d run(s): %.1f s\n", runs, seconds[seconds.size() / 2]);
  fs::remove_all(dir);
  return 0;
}
