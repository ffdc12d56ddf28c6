// Calibration of the wavelength relation's alpha: is the reported interval right, and is the
// median unbiased? Simulates N independent campaigns (seeds first, first + 1, ...) of a
// campaign config, runs `trend`'s pipeline on each (joint fit with MCMC of every group, the
// relations), and compares alpha of FWHM(lambda) with the truth, in units of its reported sd
// (68 % half-width).
//
//   ./build/alpha_calibration [N] [first_seed] [config.json]
//       defaults: 12, 201, testdata/campaign_table1.json cut to its wavelength points
//
// Without a config, each wavelength keeps only its setting nearest I0 (600, 700, 800 and 890
// nm at 143-160 ke-; 20 exposures), so a campaign takes ~25 s on 2 cores. Then there is no
// intensity relation and the points are used at their measured intensity: the truth's alpha
// is the least-squares power law through the true FWHM of the chosen settings, with the
// relation's own weights (1 / s_i^2 in log X). With an intensity series in the config the
// points are corrected to I0 and the truth is the config's alpha.
//
// Prints per seed: alpha, its 68 % interval, the truth, z; when the points were corrected to
// I0, also alpha of the same fits uncorrected (against the truth as measured) and the 800 nm
// slope used; then the mean z with its standard error (unbiased: |mean| within ~2 se), the
// rms z (calibrated sd: ~1) and the share of 68 % intervals that hold the truth.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "ccdpsf/campaign_simulation.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"
#include "ccdpsf/trend/trend.h"

namespace fs = std::filesystem;
using namespace ccdpsf;

namespace {

// Each wavelength's setting nearest I0 (the one the wavelength relation uses).
std::vector<CampaignSetting> WavelengthPoints(const CampaignConfig& config) {
  std::map<double, CampaignSetting> best;
  const double i0 = config.truth.reference_intensity_e;
  for (const CampaignSetting& s : config.settings) {
    auto it = best.find(s.wavelength_nm);
    if (it == best.end() ||
        std::fabs(s.peak_e / i0 - 1.0) < std::fabs(it->second.peak_e / i0 - 1.0)) {
      best[s.wavelength_nm] = s;
    }
  }
  std::vector<CampaignSetting> out;
  for (const auto& [wavelength, s] : best) out.push_back(s);
  return out;
}

// Weighted least-squares slope of log(true FWHM) on log(lambda) at the relation's points.
double TruthAlpha(const CampaignTruth& truth, const trend::RelationFit& fit,
                  const std::map<std::string, double>& peak_by_group, bool corrected) {
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (const trend::PointSummary& p : fit.points) {
    const double peak = corrected ? truth.reference_intensity_e : peak_by_group.at(p.label);
    const double f = std::sqrt(truth.FwhmXUm(peak, p.abscissa) * truth.FwhmYUm(peak, p.abscissa));
    const double w = 1.0 / (p.fit_sd * p.fit_sd);
    const double x = std::log(p.abscissa), y = std::log(f);
    sw += w;
    sx += w * x;
    sy += w * y;
    sxx += w * x * x;
    sxy += w * x * y;
  }
  return (sw * sxy - sx * sy) / (sw * sxx - sx * sx);
}

}  // namespace

int main(int argc, char** argv) {
  const int num = argc > 1 ? std::max(1, std::atoi(argv[1])) : 12;
  const uint64_t first = argc > 2 ? std::strtoull(argv[2], nullptr, 10) : 201;
  const bool own_config = argc > 3;
  const std::string config_path =
      own_config ? argv[3] : std::string(CCDPSF_SOURCE_DIR) + "/testdata/campaign_table1.json";
  std::string error;
  auto config = LoadCampaignConfig(config_path, &error);
  if (!config) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  if (!own_config) config->settings = WavelengthPoints(*config);
  std::printf("alpha calibration: %d campaigns of %zu settings (%s sampling), seeds %llu..%llu\n",
              num, config->settings.size(), model::ToString(config->sampling).c_str(),
              static_cast<unsigned long long>(first),
              static_cast<unsigned long long>(first + num - 1));
  const std::string dir = (fs::temp_directory_path() / "ccdpsf_alpha_calibration").string();
  std::vector<double> zs, zs_raw;
  int covered = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < num; ++k) {
    config->seed = first + k;
    fs::remove_all(dir);
    CampaignResult sim;
    std::vector<trend::CampaignGroup> groups;
    if (!RunCampaign(*config, dir, false, &sim, &error) ||
        !trend::LoadCampaign({sim.manifest_path}, &groups, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    std::map<std::string, double> peak_by_group;
    for (const trend::CampaignGroup& g : groups) {
      peak_by_group[g.name] = g.nominal_peak_e.value_or(NAN);
    }
    trend::GroupFitOptions options;
    options.config.model.model.sampling = config->sampling;
    options.config.fit.mcmc.target_ess = 400;  // as `ccdpsf trend` by default
    options.parallel_groups = 2;
    options.seed = 1;
    const std::vector<trend::GroupResult> fitted = trend::FitGroups(groups, options, nullptr);
    trend::TrendResult tr, as_measured;
    trend::TrendOptions uncorrected;
    uncorrected.correct_to_reference_intensity = false;
    if (!trend::ComputeTrend(fitted, trend::TrendOptions(), &tr, &error) ||
        !trend::ComputeTrend(fitted, uncorrected, &as_measured, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    const trend::RelationFit& fit = tr.relations.at("fwhm_um_vs_wavelength");
    const trend::RelationFit* intensity = nullptr;
    auto it = tr.relations.find("fwhm_um_vs_intensity");
    if (it != tr.relations.end() && it->second.fitted &&
        !it->second.HasFlag(trend::kFlagPoorlyConstrained)) {
      intensity = &it->second;
    }
    const trend::Estimate& alpha = fit.Find("alpha")->estimate;
    const double truth = TruthAlpha(config->truth, fit, peak_by_group, intensity != nullptr);
    const double z = (alpha.median - truth) / (0.5 * (alpha.hi68 - alpha.lo68));
    zs.push_back(z);
    covered += alpha.lo68 <= truth && truth <= alpha.hi68 ? 1 : 0;
    std::printf("seed %llu: alpha %.4f [%.4f, %.4f], truth %.4f (%s): %+.2f sd\n",
                static_cast<unsigned long long>(config->seed), alpha.median, alpha.lo68,
                alpha.hi68, truth, intensity ? "corrected to I0" : "as measured", z);
    if (intensity != nullptr) {
      // The same fits without the correction: does it move alpha away from its truth?
      const trend::RelationFit& raw = as_measured.relations.at("fwhm_um_vs_wavelength");
      const trend::Estimate& a = raw.Find("alpha")->estimate;
      const double t = TruthAlpha(config->truth, raw, peak_by_group, false);
      const double z_raw = (a.median - t) / (0.5 * (a.hi68 - a.lo68));
      zs_raw.push_back(z_raw);
      const trend::Estimate& slope = intensity->Find("slope")->estimate;
      std::printf("  uncorrected: alpha %.4f [%.4f, %.4f], truth %.4f: %+.2f sd; 800 nm slope "
                  "%.3g [%.3g, %.3g] um/e-\n",
                  a.median, a.lo68, a.hi68, t, z_raw, slope.median, slope.lo68, slope.hi68);
    }
    std::fflush(stdout);
  }
  fs::remove_all(dir);
  double mean = 0, ms = 0;
  for (double z : zs) {
    mean += z;
    ms += z * z;
  }
  mean /= zs.size();
  ms /= zs.size();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("mean z %+.2f (standard error %.2f), rms z %.2f, 68 %% intervals holding the "
              "truth %d/%zu; %.0f s\n",
              mean, 1.0 / std::sqrt(static_cast<double>(zs.size())), std::sqrt(ms), covered,
              zs.size(), seconds);
  if (!zs_raw.empty()) {
    double m = 0;
    for (double z : zs_raw) m += z;
    std::printf("the same fits uncorrected: mean z %+.2f over %zu campaigns\n",
                m / zs_raw.size(), zs_raw.size());
  }
  return 0;
}
