// A through-focus series anchors the defocus of single-focus settings at a stage position
// inside its scanned range (trend/defocus_anchor.h).
#include "ccdpsf/trend/defocus_anchor.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/trend/group_store.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/fit_helpers.h"
#include "support/run_ccdpsf.h"
#include "support/simulated_stamps.h"
#include "support/slow_test.h"

namespace ccdpsf::trend {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// A fitted series at `wavelength` scanning `positions`, with posterior draws of the rate
// [px/um] and best focus [um] drawn from independent normals (the draws' shape does not
// matter to the box, only its percentiles do).
GroupResult SeriesWithDraws(const std::string& name, double wavelength,
                            const std::vector<double>& positions, double rate, double rate_sd,
                            double z0, double z0_sd, uint64_t seed) {
  GroupResult s;
  s.ok = true;
  s.converged = true;
  s.group.name = name;
  s.group.wavelength_nm = wavelength;
  s.group.focus_series = true;
  s.group.focus_positions_um = positions;
  std::mt19937_64 engine(seed);
  std::normal_distribution<double> normal;
  for (int i = 0; i < 4000; ++i) {
    s.draws["defocus_rate_px_per_um"].push_back(rate + rate_sd * normal(engine));
    s.draws["best_focus_um"].push_back(z0 + z0_sd * normal(engine));
  }
  return s;
}

CampaignGroup SingleFocus(const std::string& name, double wavelength,
                          std::vector<double> positions) {
  CampaignGroup g;
  g.name = name;
  g.wavelength_nm = wavelength;
  g.focus_positions_um = std::move(positions);
  return g;
}

// The box is the series' central 99.73 % of rate |z - z0| at the setting's position: checked
// by counting the draws inside it (independent of how the percentiles are interpolated:
// within 1 / 4000 of 99.73 %, and the median with half the draws below). Settings outside
// the scanned range, with several or no positions, at another wavelength (unless any is
// allowed), and a pixel_centre campaign are not anchored, with the reason in a note.
TEST(DefocusAnchor, BoxIsTheSeriesIntervalAtTheStagePosition) {
  const std::vector<double> scanned = {-400, -200, 0, 200, 400};
  std::vector<GroupResult> series = {SeriesWithDraws("f800", 800, scanned, 0.0015, 5e-5, 60, 8, 1)};
  std::vector<CampaignGroup> groups = {
      SingleFocus("at300", 800, {300}),   SingleFocus("outside", 800, {500}),
      SingleFocus("two", 800, {0, 100}),  SingleFocus("none", 800, {}),
      SingleFocus("at600nm", 600, {300}), series[0].group};
  fit::FitModelOptions model;
  const std::vector<std::string> notes =
      AnchorDefocus(series, model, AnchorScope::kSameWavelength, &groups);
  ASSERT_TRUE(groups[0].defocus_anchor.has_value());
  const DefocusAnchor& a = *groups[0].defocus_anchor;
  EXPECT_EQ(a.series, "f800");
  EXPECT_EQ(a.focus_position_um, 300);
  const std::vector<double>& rate = series[0].draws.at("defocus_rate_px_per_um");
  const std::vector<double>& z0 = series[0].draws.at("best_focus_um");
  int inside = 0, below_median = 0;
  for (size_t i = 0; i < rate.size(); ++i) {
    const double d = rate[i] * std::fabs(300 - z0[i]);
    inside += d >= a.lower_px && d <= a.upper_px ? 1 : 0;
    below_median += d < a.median_px ? 1 : 0;
  }
  EXPECT_NEAR(inside / 4000.0, 0.9973, 1.5 / 4000);
  EXPECT_NEAR(below_median / 4000.0, 0.5, 1.0 / 4000);
  // The nominal defocus there: 0.0015 x 240 = 0.36 px.
  EXPECT_NEAR(a.median_px, 0.36, 0.01);
  for (int k = 1; k < 6; ++k) EXPECT_FALSE(groups[k].defocus_anchor) << groups[k].name;
  ASSERT_EQ(notes.size(), 2u);
  EXPECT_NE(notes[0].find("1 single-focus setting(s) anchored"), std::string::npos) << notes[0];
  EXPECT_NE(notes[0].find("at the same wavelength"), std::string::npos) << notes[0];
  EXPECT_NE(notes[1].find("outside the scanned range"), std::string::npos) << notes[1];

  // Any wavelength: the 600 nm setting too, and the note states the assumption.
  const std::vector<std::string> any =
      AnchorDefocus(series, model, AnchorScope::kAnyWavelength, &groups);
  EXPECT_TRUE(groups[0].defocus_anchor.has_value());
  ASSERT_TRUE(groups[4].defocus_anchor.has_value());
  EXPECT_EQ(groups[4].defocus_anchor->series_wavelength_nm, 800);
  EXPECT_NE(any[0].find("chromatic"), std::string::npos) << any[0];

  // The box is clipped to the configured prior; a box wholly outside it anchors nothing.
  model.priors.defocus_px[1] = 0.36;
  AnchorDefocus(series, model, AnchorScope::kSameWavelength, &groups);
  ASSERT_TRUE(groups[0].defocus_anchor.has_value());
  EXPECT_EQ(groups[0].defocus_anchor->upper_px, 0.36);
  model.priors.defocus_px[1] = 0.2;
  const std::vector<std::string> clipped =
      AnchorDefocus(series, model, AnchorScope::kSameWavelength, &groups);
  EXPECT_FALSE(groups[0].defocus_anchor.has_value());
  EXPECT_NE(clipped[0].find("outside the defocus prior"), std::string::npos) << clipped[0];

  // Neither off, nor a series that failed, nor a model other than the series' own.
  model = fit::FitModelOptions();
  EXPECT_TRUE(AnchorDefocus(series, model, AnchorScope::kOff, &groups).empty());
  EXPECT_FALSE(groups[0].defocus_anchor.has_value());
  std::vector<GroupResult> failed = series;
  failed[0].ok = false;
  AnchorDefocus(failed, model, AnchorScope::kSameWavelength, &groups);
  EXPECT_FALSE(groups[0].defocus_anchor.has_value());
  // A series whose MCMC did not converge (or ran without one) anchors nothing, and says so.
  std::vector<GroupResult> unconverged = series;
  unconverged[0].converged = false;
  const std::vector<std::string> no_draws =
      AnchorDefocus(unconverged, model, AnchorScope::kSameWavelength, &groups);
  EXPECT_FALSE(groups[0].defocus_anchor.has_value());
  ASSERT_EQ(no_draws.size(), 2u);
  EXPECT_NE(no_draws[0].find("no posterior draws of a converged MCMC"), std::string::npos)
      << no_draws[0];
  model.model.sampling = model::Sampling::kPixelCentre;
  const std::vector<std::string> pc =
      AnchorDefocus(series, model, AnchorScope::kSameWavelength, &groups);
  EXPECT_FALSE(groups[0].defocus_anchor.has_value());
  ASSERT_EQ(pc.size(), 1u);
  EXPECT_NE(pc[0].find("integrated sampling with a Gaussian defocus"), std::string::npos);
}

// An anchored fit depends on its box, which depends on the series' fit: a kept result must
// not be reused once the box changes (a resumed run whose series was refitted).
TEST(DefocusAnchor, TheBoxIsPartOfAKeptGroupsKey) {
  CampaignGroup g = SingleFocus("g", 800, {300});
  const std::string plain = GroupStoreName("run", g, 0);
  DefocusAnchor a;
  a.series = "f";
  a.focus_position_um = 300;
  a.lower_px = 0.35;
  a.upper_px = 0.37;
  g.defocus_anchor = a;
  const std::string anchored = GroupStoreName("run", g, 0);
  g.defocus_anchor->upper_px = 0.38;
  const std::string wider = GroupStoreName("run", g, 0);
  EXPECT_NE(plain, anchored);
  EXPECT_NE(anchored, wider);
  EXPECT_EQ(wider, GroupStoreName("run", g, 0));
}

fit::FitOptions Mcmc(uint64_t seed) {
  fit::FitOptions o;
  o.mcmc.seed = seed;
  // As ThroughFocus.McmcCoversTheCcdWidths: ESS 200 knows a 68 % interval's ends to a
  // fraction of an sd.
  o.mcmc.target_ess = 200;
  o.mcmc.min_tau_multiple = 20;
  o.mcmc.max_steps = 3000;
  o.mcmc.progress = false;
  return o;
}

// The approximation against the exact answer on a small case: a five-position series and a
// sixth exposure at z = 300 um of the same setting (the paper's Airy radius and CCD kernel,
// best focus 60 um, 0.0015 px/um: sigma_f = 0.36 px there). At one setting the exact joint
// answer is the through-focus fit of all six exposures (they share the CCD widths and the
// defocus law). The anchored fit of the sixth alone, with the series' box, must agree with
// it: medians within the anchored fit's own sd (it uses one exposure of six, so it is the
// wider), its 99.7 % interval holding the truth, and the anchor must matter: without it the
// single exposure's CCD widths span the prior's ridge (68 % interval several times wider).
TEST(DefocusAnchor, AgreesWithTheExactJointFitOnASmallCase) {
  CCDPSF_RELEASE_ONLY();  // two joint fits; the anchor runs sanitized in
  // DefocusAnchor.BoxIsTheSeriesIntervalAtTheStagePosition
  const std::vector<double> z = {-400, -200, 0, 200, 400, 300};
  const SimulationConfig c = testing_support::FocusSeriesConfig(z, 60.0, 0.0015, 4.0e5, 7);
  const std::vector<Stamp> stamps = testing_support::SimulateStamps(c, 8);
  const std::vector<Stamp> series_stamps(stamps.begin(), stamps.begin() + 5);
  fit::FitModelOptions focus;
  focus.through_focus = true;
  std::string error;

  fit::FitResult exact;
  auto exact_model = testing_support::MustCreate(stamps, focus);
  ASSERT_TRUE(fit::RunFit(*exact_model, Mcmc(3), &exact, &error)) << error;
  ASSERT_TRUE(exact.chain.converged) << exact.chain.stop_reason;

  // The series alone, as trend keeps it: draws of the rate and best focus.
  fit::FitResult series_fit;
  auto series_model = testing_support::MustCreate(series_stamps, focus);
  ASSERT_TRUE(fit::RunFit(*series_model, Mcmc(4), &series_fit, &error)) << error;
  ASSERT_TRUE(series_fit.chain.converged) << series_fit.chain.stop_reason;
  GroupResult series;
  series.ok = true;
  series.converged = true;
  series.group.name = "series";
  series.group.wavelength_nm = 800;
  series.group.focus_series = true;
  series.group.focus_positions_um = {-400, -200, 0, 200, 400};
  const fit::SamplerResult& chain = series_fit.chain;
  const int dim = series_model->dim(), f = series_model->FocusIndex();
  for (size_t s = static_cast<size_t>(chain.burn_in) * chain.num_walkers;
       s < static_cast<size_t>(chain.num_steps) * chain.num_walkers; ++s) {
    series.draws["defocus_rate_px_per_um"].push_back(chain.chain[s * dim + fit::kDefocusPx]);
    series.draws["best_focus_um"].push_back(chain.chain[s * dim + f]);
  }
  std::vector<CampaignGroup> groups = {SingleFocus("single", 800, {300})};
  AnchorDefocus({series}, fit::FitModelOptions(), AnchorScope::kSameWavelength, &groups);
  ASSERT_TRUE(groups[0].defocus_anchor.has_value());
  const DefocusAnchor& a = *groups[0].defocus_anchor;
  std::printf("  box at z = 300 um: [%.4f, %.4f] px, median %.4f (truth 0.36)\n", a.lower_px,
              a.upper_px, a.median_px);
  EXPECT_LT(a.lower_px, 0.36);
  EXPECT_GT(a.upper_px, 0.36);

  fit::FitModelOptions anchored_options;
  anchored_options.priors.defocus_px[0] = a.lower_px;
  anchored_options.priors.defocus_px[1] = a.upper_px;
  fit::FitResult anchored, free;
  auto anchored_model = testing_support::MustCreate({stamps[5]}, anchored_options);
  ASSERT_TRUE(fit::RunFit(*anchored_model, Mcmc(5), &anchored, &error)) << error;
  ASSERT_TRUE(anchored.chain.converged) << anchored.chain.stop_reason;
  auto free_model = testing_support::MustCreate({stamps[5]});
  ASSERT_TRUE(fit::RunFit(*free_model, Mcmc(5), &free, &error)) << error;

  const double truth[2] = {c.ccd_sigma_x_px, c.ccd_sigma_y_px};
  int k = 0;
  for (int p : {fit::kCcdSigmaXPx, fit::kCcdSigmaYPx}) {
    const fit::Summary &e = exact.parameters[p], &x = anchored.parameters[p],
                       &u = free.parameters[p];
    const double sd_x = 0.5 * (x.hi68 - x.lo68), sd_e = 0.5 * (e.hi68 - e.lo68);
    std::printf(
        "  %s truth %.4f  exact %.4f +- %.4f  anchored %.4f +- %.4f  free 68%% [%.4f, %.4f]\n",
        exact.names[p].c_str(), truth[k], e.median, sd_e, x.median, sd_x, u.lo68, u.hi68);
    EXPECT_NEAR(x.median, e.median, sd_x) << exact.names[p];
    EXPECT_GT(sd_x, sd_e) << exact.names[p];
    EXPECT_LT(x.lo997, truth[k]) << exact.names[p];
    EXPECT_GT(x.hi997, truth[k]) << exact.names[p];
    EXPECT_GT(u.hi68 - u.lo68, 3 * (x.hi68 - x.lo68)) << exact.names[p];
    ++k;
  }
}

// End to end: a simulated campaign with a through-focus series at 800 nm and a single-focus
// setting at 800 nm taken at a stage position inside its range (the simulator gives it the
// series' defocus there and writes FOCUSPOS), and one at 600 nm without a series. `trend`
// fits the series first, anchors the 800 nm setting (its CCD widths identified: in the
// CCD-only relations, within 3 sd of the truth) and not the 600 nm one (a gap there); the
// notes state the assumption. A bad --anchor_defocus is a one-line error.
TEST(DefocusAnchor, TrendAnchorsASimulatedSetting) {
  CCDPSF_RELEASE_ONLY();  // a trend run; the anchor's code runs sanitized in
  // DefocusAnchor.BoxIsTheSeriesIntervalAtTheStagePosition
  const std::string dir = testing_support::FreshDir("DefocusAnchor", "trend");
  {
    std::ofstream(dir + "/campaign.json") << R"({"campaign": {"seed": 3,
        "settings": [{"wavelength_nm": 800, "peak_e": 150000, "exptime_s": 4,
                      "exposures": 2, "focus_position_um": 273},
                     {"wavelength_nm": 600, "peak_e": 150000, "exptime_s": 2.5,
                      "exposures": 2}],
        "focus_series": [{"wavelength_nm": 800, "peak_e": 150000, "exptime_s": 4,
                          "focus_positions_um": [-400, -200, 0, 200, 400],
                          "best_focus_um": 0, "defocus_sigma_px_per_um": 0.0015}]}})";
  }
  testing_support::RunResult r = testing_support::RunCcdpsf(
      "simulate --config=" + dir + "/campaign.json --out=" + dir + "/data");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json truth = json::parse(std::ifstream(dir + "/data/truth.json"));
  const json& t800 = truth["groups"][0];
  ASSERT_EQ(t800["name"], "g00_800nm_150000e");
  EXPECT_EQ(t800["focus_position_um"], 273);
  EXPECT_NEAR(t800["defocus_sigma_px"].get<double>(), 0.0015 * 273, 1e-12);

  r = testing_support::RunCcdpsf("trend --target_ess=300 --group_reports=false --out=" + dir +
                                 "/trend " + dir + "/data");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("1 single-focus setting(s) anchored"), std::string::npos) << r.output;
  const json trend = json::parse(std::ifstream(dir + "/trend/trend.json"));
  std::map<std::string, json> groups;
  for (const json& g : trend["groups"]) groups[g["name"].get<std::string>()] = g;
  const json& g800 = groups.at("g00_800nm_150000e");
  ASSERT_TRUE(g800.contains("defocus_anchor")) << g800.dump();
  EXPECT_EQ(g800["defocus_anchor"]["series"], "f00_800nm_150000e_focus");
  EXPECT_EQ(g800["defocus_anchor"]["focus_position_um"], 273);
  const json& box = g800["defocus_anchor"]["defocus_px"];
  EXPECT_LT(box[0].get<double>(), 0.4095);
  EXPECT_GT(box[1].get<double>(), 0.4095);
  EXPECT_TRUE(g800["ccd_widths_identified"].get<bool>());
  const json& fwhm = g800["metrics"]["fwhm_um"];
  const double sd = 0.5 * (fwhm["hi68"].get<double>() - fwhm["lo68"].get<double>());
  std::printf("  anchored fwhm_um %.4f +- %.4f, truth %.4f\n", fwhm["median"].get<double>(), sd,
              t800["fwhm_um"].get<double>());
  EXPECT_NEAR(fwhm["median"].get<double>(), t800["fwhm_um"].get<double>(), 3 * sd);
  EXPECT_LT(sd, 0.05 * t800["fwhm_um"].get<double>());
  const json& g600 = groups.at("g01_600nm_150000e");
  EXPECT_FALSE(g600.contains("defocus_anchor"));
  EXPECT_FALSE(g600["ccd_widths_identified"].get<bool>());
  // The 800 nm setting is a point of the CCD-only relations, the 600 nm one a gap.
  bool anchored_point = false, gap_600 = false;
  for (const json& p : trend["relations"]["fwhm_um_vs_intensity"]["points"]) {
    anchored_point = anchored_point || p["label"] == "g00_800nm_150000e";
  }
  for (const json& p : trend["relations"]["fwhm_um_vs_wavelength"]["gaps"]) {
    gap_600 = gap_600 || p["label"] == "g01_600nm_150000e";
  }
  EXPECT_TRUE(anchored_point) << trend["relations"]["fwhm_um_vs_intensity"].dump();
  EXPECT_TRUE(gap_600) << trend["relations"]["fwhm_um_vs_wavelength"].dump();
  // groups.csv says the same, for TOPCAT and astropy.
  std::ifstream csv(dir + "/trend/groups.csv");
  std::string header, line, row800;
  std::getline(csv, header);
  while (std::getline(csv, line)) {
    if (line.rfind("g00_800nm_150000e,", 0) == 0) row800 = line;
  }
  EXPECT_NE(header.find(",ccd_widths_identified,defocus_anchor_series,"), std::string::npos)
      << header;
  EXPECT_NE(row800.find(",1,f00_800nm_150000e_focus,"), std::string::npos) << row800;

  r = testing_support::RunCcdpsf("trend --anchor_defocus=sometimes --out=" + dir + "/bad " + dir +
                                 "/data");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_NE(r.output.find("--anchor_defocus must be"), std::string::npos) << r.output;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ccdpsf::trend
