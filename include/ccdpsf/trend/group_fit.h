// The joint fit of every group of a campaign, in parallel across groups, and the posterior
// draws of the PSF metrics that the trend relations are fitted to.
//
// Groups are dealt to `parallel_groups` worker threads (largest first, for balance); each fit
// runs its MCMC on one thread, so the whole run uses parallel_groups cores. A group's MCMC
// seed is DeriveSeed(seed, group index), so the results do not depend on the scheduling or
// on parallel_groups. A group that cannot be fitted (no usable file, a calibration error,
// stamps of different sizes, a fit that does not converge to a MAP) is kept with the reason;
// the others go on.
#ifndef CCDPSF_TREND_GROUP_FIT_H_
#define CCDPSF_TREND_GROUP_FIT_H_

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/quality.h"
#include "ccdpsf/trend/campaign.h"

namespace ccdpsf::trend {

struct GroupFitOptions {
  fit::FitConfig config;  // model, fit and calibration options (MCMC threads are set to 1)
  bool flux_given = false;  // config.model.flux was chosen by the user (else from the data)
  uint64_t seed = 1;
  int parallel_groups = 2;
  // Posterior draws of each metric kept per group (evenly thinned from the chain).
  int draws = 2000;
  // Where each group's full fit report goes (out_dir/<group name>/); empty: none. Its plots
  // are in `plot_format`, with the truth.json of the group's folder when there is one.
  std::string reports_dir;
  PlotFormat plot_format = PlotFormat::kPng;
  fit::Pictures pictures = fit::Pictures::kFlagged;  // whose pictures are drawn
  // Effects fitted with an intensity series' spot only (intensity_series.h; the
  // brighter-fatter slope, which a setting at one intensity cannot fit).
  std::vector<fit::FitEffect> intensity_series_effects;
  // Where finished groups are kept (group_store.h), and the run's signature that their keys
  // include; empty: not kept. A group kept there by an earlier run with the same signature,
  // group and files is taken from it instead of being fitted again.
  std::string store_dir;
  std::string run_signature;
  // Where a group's calibrated exposures come from: empty = LoadExposureSet on its files; set
  // (e.g. by `grid`, whose stamps are cut from frames already read) = called with the
  // group's position in `groups`, from the worker threads.
  std::function<bool(int group, ExposureSet* set, std::string* error)> load_exposures;
  // The index of each group for its MCMC seed and store key; empty = its position. A shard
  // of a run fits a subset of its groups with the seeds the whole run gives them.
  std::vector<int> seed_indices;
};

struct GroupResult {
  CampaignGroup group;
  bool ok = false;
  std::string failure;                 // why the group has no result (ok == false)
  std::vector<std::string> warnings;   // e.g. one exposure only, the verdict's reasons
  std::vector<std::string> notes;      // choices made from the data (e.g. the flux model)
  int exposures = 0;
  bool mcmc_ran = false;   // false with --nomcmc: `converged` then says nothing
  bool converged = false;  // the MCMC ran and converged
  double chi2_per_dof = NAN;
  double seconds = 0.0;
  std::string report_dir;              // the group's fit report, if written
  Quality quality;                     // the fit's verdict (quality.h); an invalid group is
                                       // not ok, with the verdict as its failure
  // Intensity: the model's peak pixel [e-] (mean over the exposures), posterior summary.
  fit::Summary peak_e;
  // Summaries and posterior draws of the derived metrics (fit.h DerivedNames(), peak_e
  // excepted) and of the shared parameters.
  std::map<std::string, fit::Summary> summaries;
  std::map<std::string, std::vector<double>> draws;  // an intensity series' also hold its
                                                     // settings' (SettingDrawKey)
  // Shared parameters the data do not bound from below (trend.h, "bound only"): the MAP sits
  // at the prior's lower bound (within 1e-6 of the range), or, in pixel_centre sampling, the
  // posterior's 0.135th percentile is within 10 % of (median - bound) of the bound.
  std::vector<std::string> unbounded_below;
  // The fit identifies only the total widths (fit_model.h CcdSplitUnidentified: integrated
  // sampling, Gaussian defocus, one focus): its CCD-only metrics are not measurements.
  bool ccd_split_unidentified = false;
  // Taken from the store of an interrupted run (not fitted again) - for messages only.
  bool resumed = false;
};

// Called after each group finishes (from the worker thread, serialised by a lock): its
// result and how many are done.
using GroupProgress = std::function<void(const GroupResult&, int done, int total)>;

// The order in which groups may be fitted: group g waits until every group in after[g] is
// finished (none may wait for itself, directly or not); then prepare(g, results, &group), if
// set, may change the group to be fitted from the results of those it waited for (called
// under FitGroups' lock, from a worker thread). Empty `after`: no group waits.
struct GroupSchedule {
  std::vector<std::vector<int>> after;
  std::function<void(int g, const std::vector<GroupResult>& results, CampaignGroup* group)> prepare;
};

// Fits (or takes from the store) every group, parallel_groups at a time: a worker takes the
// next group whose dependencies are finished (intensity series first, then groups that
// others wait for, then the largest first). Results are in the order of `groups`.
std::vector<GroupResult> FitGroups(const std::vector<CampaignGroup>& groups,
                                   const GroupFitOptions& options, const GroupProgress& progress,
                                   const GroupSchedule* schedule = nullptr);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_GROUP_FIT_H_
