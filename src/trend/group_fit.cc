#include "ccdpsf/trend/group_fit.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <numeric>
#include <thread>

#include "ccdpsf/exposure.h"
#include "ccdpsf/exposure_set.h"
#include "ccdpsf/fit/fit_exposures.h"
#include "ccdpsf/fit/fit_report.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/random.h"
#include "ccdpsf/safe_path.h"
#include "ccdpsf/trend/group_store.h"
#include "ccdpsf/trend/intensity_series.h"
#include "glog/logging.h"
#include "internal/text.h"

namespace ccdpsf::trend {
namespace {

// `folder` is the group's report folder's name in options.reports_dir: its name made safe
// (safe_path.h), since a group is named after a manifest's setting or a file's stem.
GroupResult FitOne(const CampaignGroup& group, int position, int index, const std::string& folder,
                   const GroupFitOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  GroupResult out;
  out.group = group;
  out.exposures = static_cast<int>(group.files.size());
  auto finish = [&](const std::string& failure) {
    out.ok = failure.empty();
    out.failure = failure;
    out.seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return out;
  };
  if (!group.problem.empty()) return finish(group.problem);
  fit::FitConfig config = options.config;
  if (group.focus_series) {
    // A through-focus series is fitted with its own model (fit_model.h), which exists in
    // integrated sampling with a Gaussian defocus only: there it identifies the CCD widths.
    if (config.model.model.sampling == model::Sampling::kPixelCentre) {
      out.warnings.push_back(
          "through-focus series in a pixel_centre campaign: fitted in integrated sampling, so "
          "the CCD-only relations mix its CCD widths with the 2015 model's of the single-focus "
          "settings (which do not resolve widths below ~0.25 px)");
    }
    config.model.model.sampling = model::Sampling::kIntegrated;
    config.model.model.defocus = model::DefocusKind::kGaussian;
    config.model.through_focus = true;
    out.notes.push_back(
        "through-focus series: fitted with defocus = rate x |z - z0| (integrated sampling, "
        "Gaussian defocus), which identifies the CCD widths");
  }
  if (group.intensity_series) {
    // intensity_series.h: the settings of one wavelength and focus, with the slope.
    for (const fit::FitEffect& e : options.intensity_series_effects) {
      config.model.effects.push_back(e);
    }
    out.notes.push_back(
        std::string("intensity series: ") +
        (group.focus_series ? "the through-focus series at this wavelength and its "
                              "single-focus settings at a stage position fitted jointly, "
                              "sharing the CCD kernel and the focus law"
                            : "the single-focus settings at this wavelength and stage "
                              "position fitted jointly, sharing the CCD kernel and the defocus") +
        ", with " +
        (options.intensity_series_effects.empty()
             ? std::string("no signal-dependent effect")
             : model::ToString(options.intensity_series_effects.front().kind)) +
        ": the CCD-only intensity relations are this fit's");
  }
  if (group.defocus_anchor && !group.focus_series) {
    // defocus_anchor.h: the series' 99.73 % interval of the defocus at this stage position.
    const DefocusAnchor& a = *group.defocus_anchor;
    config.model.priors.defocus_px[0] = a.lower_px;
    config.model.priors.defocus_px[1] = a.upper_px;
    out.notes.push_back("defocus anchored by the through-focus series " + a.series + " (" +
                        internal::FormatNumber(a.series_wavelength_nm) +
                        " nm) at z = " + internal::FormatNumber(a.focus_position_um) +
                        " um: sigma_f in [" + internal::FormatNumber(a.lower_px) + ", " +
                        internal::FormatNumber(a.upper_px) + "] px (median " +
                        internal::FormatNumber(a.median_px) + ")");
  }
  std::string error;
  ExposureSet set;
  if (options.load_exposures) {
    if (!options.load_exposures(position, &set, &error)) return finish(error);
  } else {
    std::vector<InputFile> inputs = group.inputs;
    if (inputs.empty()) {
      for (const std::string& f : group.files) inputs.push_back({f, "", config.calibration});
    }
    ExposureSetOptions set_options;
    set_options.compression_modelled = fit::SignalDependenceModelled(config.model);
    if (!LoadExposureSet(inputs, set_options, &set, &error)) return finish(error);
  }
  if (set.exposures.size() == 1) {
    out.warnings.push_back("one exposure only: fitted alone, without the joint constraint");
  }
  fit::ExposuresFitOptions fit_options;
  fit_options.config = config;
  fit_options.flux_given = options.flux_given;
  fit_options.config.fit.mcmc.num_threads = 1;
  fit_options.config.fit.mcmc.progress = false;
  fit_options.config.fit.mcmc.seed = DeriveSeed(options.seed, static_cast<uint64_t>(index));
  fit::ExposuresFit fitted;
  if (!fit::FitExposures(set.exposures, set.quality, fit_options, &fitted, &error)) {
    return finish(error);
  }
  const fit::FitModel* model = fitted.model.get();
  const fit::FitResult& result = fitted.result;
  const fit::FitOptions& fo = fit_options.config.fit;
  out.quality = fitted.quality;
  out.notes.insert(out.notes.end(), fitted.notes.begin(), fitted.notes.end());
  out.chi2_per_dof = result.map.chi2 / result.map.dof;
  out.mcmc_ran = result.have_mcmc;
  out.converged = result.have_mcmc && result.chain.converged;
  for (const Finding& f : fitted.quality.findings) {
    if (f.severity != Severity::kNote) out.warnings.push_back(ToString(f.severity) + ": " + f.message);
  }

  for (const auto& [name, summary] : result.derived) out.summaries[name] = summary;
  for (int i = 0; i < fit::kNumShared; ++i) out.summaries[result.names[i]] = result.parameters[i];
  if (model->FocusIndex() >= 0) {
    out.summaries[result.names[model->FocusIndex()]] = result.parameters[model->FocusIndex()];
  }
  // Fitted effects' parameters ("serial_cti.trail_fraction", ...), to the end of theta.
  for (int i = std::max(0, model->EffectsFirstIndex()); model->HasEffects() && i < model->dim();
       ++i) {
    out.summaries[result.names[i]] = result.parameters[i];
  }
  out.peak_e = out.summaries["peak_e"];
  // An anchored defocus box splits the total widths (defocus_anchor.h).
  out.ccd_split_unidentified = fit::CcdSplitUnidentified(model->options()) && !group.defocus_anchor;
  // In pixel_centre sampling a posterior can also have a plateau down to the bound next to
  // an identified peak (a few % of the mass at 83 ke-): its 0.135th percentile is then within
  // 10 % of (median - bound) of the bound, and its median and sd mix in the prior.
  const bool pixel_centre = config.model.model.sampling == model::Sampling::kPixelCentre;
  for (int i = 0; i < fit::kNumShared; ++i) {
    const double lower = model->lower()[i], range = model->upper()[i] - lower;
    const fit::Summary& p = result.parameters[i];
    const bool at_bound = result.map.theta[i] - lower <= 1e-6 * range;
    const bool reaches_bound = pixel_centre && result.have_mcmc && std::isfinite(p.lo997) &&
                               p.lo997 - lower < 0.1 * (p.median - lower);
    if (at_bound || reaches_bound) out.unbounded_below.push_back(result.names[i]);
  }

  if (result.have_mcmc) {
    const fit::SamplerResult& c = result.chain;
    const int dim = model->dim();
    const std::vector<std::string>& names = fit::DerivedNames();
    for (const size_t s : c.ThinnedStates(options.draws)) {
      const double* theta = &c.chain[s * dim];
      const std::vector<double> d = fit::DerivedAt(*model, theta);
      for (size_t j = 0; j < names.size(); ++j) {
        if (std::isfinite(d[j])) out.draws[names[j]].push_back(d[j]);
      }
      for (int i = 0; i < fit::kNumShared; ++i) out.draws[result.names[i]].push_back(theta[i]);
      // A series' best focus too: with the rate it gives the defocus at any stage position.
      const int focus = model->FocusIndex();
      if (focus >= 0) out.draws[result.names[focus]].push_back(theta[focus]);
    }
  }

  if (group.intensity_series && result.have_mcmc) {
    if (!SettingKernelDraws(*model, result, group.member_settings, group.member_focus_series,
                            options.draws, &out.draws, &error)) {
      return finish("intensity series: " + error);
    }
  }

  if (!options.reports_dir.empty()) {
    out.report_dir = options.reports_dir + "/" + folder;
    nlohmann::json run = {{"command", "trend (group fit)"},
                          {"group", group.name},
                          {"files", group.files},
                          {"options", fit::FitConfigJson(config)},
                          {"seed", fo.mcmc.seed},
                          {"software", SoftwareVersions()}};
    std::vector<std::string> plot_warnings;
    fit::FitReportOptions report_options;
    report_options.plot.format = options.plot_format;
    report_options.plot.draw = fit::DrawsPictures(options.pictures, out.quality);
    report_options.plot_reason =
        std::string("trend --group_plots=") + fit::ToString(options.pictures) +
        (options.pictures == fit::Pictures::kFlagged ? ", and this group's verdict is ok" : "");
    std::string truth_error;
    if (!FindTruth("", group.files, &report_options.truth, &truth_error)) {
      plot_warnings.push_back("truth not drawn: " + truth_error);
    }
    if (!fit::WriteFitReport(out.report_dir, fitted, run, &plot_warnings, &error, report_options)) {
      out.warnings.push_back("fit report not written: " + error);
      out.report_dir.clear();
    }
    for (const std::string& w : plot_warnings) out.warnings.push_back(w);
  }
  // An invalid fit measures nothing: the group is a gap with the reason.
  if (out.quality.Worst() == Severity::kInvalid) {
    return finish("verdict invalid: " + out.quality.OneLine().substr(std::string("invalid: ").size()));
  }
  return finish("");
}

}  // namespace

std::vector<GroupResult> FitGroups(const std::vector<CampaignGroup>& groups,
                                   const GroupFitOptions& options, const GroupProgress& progress,
                                   const GroupSchedule* schedule) {
  const int total = static_cast<int>(groups.size());
  std::vector<GroupResult> results(total);
  if (total == 0) return results;
  std::vector<std::string> names;
  for (const CampaignGroup& g : groups) names.push_back(g.name);
  const std::vector<std::string> folders = UniqueSafeComponents(names);
  const bool with_schedule = schedule != nullptr && !schedule->after.empty();
  if (with_schedule) CHECK_EQ(static_cast<int>(schedule->after.size()), total);
  auto after = [&](int g) -> const std::vector<int>& {
    static const std::vector<int> kNone;
    return with_schedule ? schedule->after[g] : kNone;
  };
  // Intensity series first (the longest fits by far, which nothing waits for: started last
  // they would run alone at the end), then groups that others wait for, then the largest
  // first, so that the last to start are the quick ones.
  std::vector<char> awaited(total, 0);
  for (int g = 0; g < total; ++g) {
    for (int d : after(g)) awaited[d] = 1;
  }
  std::vector<int> order(total);
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    if (groups[a].intensity_series != groups[b].intensity_series) {
      return groups[a].intensity_series;
    }
    if (awaited[a] != awaited[b]) return awaited[a] > awaited[b];
    return groups[a].files.size() > groups[b].files.size();
  });
  // Workers take the first group in `order` whose dependencies are finished, so a group
  // waits only for what it needs and no worker idles while another group could run.
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<char> started(total, 0), finished(total, 0);
  int done = 0, running = 0;
  auto ready = [&](int g) {
    for (int d : after(g)) {
      if (!finished[d]) return false;
    }
    return true;
  };
  auto worker = [&](int) {
    std::unique_lock<std::mutex> lock(mutex);
    for (;;) {
      int pick = -1;
      bool left = false;
      for (int g : order) {
        if (started[g]) continue;
        left = true;
        if (ready(g)) {
          pick = g;
          break;
        }
      }
      if (!left) return;
      if (pick < 0) {
        CHECK_GT(running, 0) << "FitGroups: groups wait for groups that never finish";
        changed.wait(lock);
        continue;
      }
      started[pick] = 1;
      ++running;
      CampaignGroup group = groups[pick];
      if (with_schedule && schedule->prepare) schedule->prepare(pick, results, &group);
      lock.unlock();
      const int index = options.seed_indices.empty() ? pick : options.seed_indices[pick];
      GroupResult r;
      std::string stored;
      if (!options.store_dir.empty()) {
        stored = options.store_dir + "/" + GroupStoreName(options.run_signature, group, index);
        r.group = group;
        r.resumed = LoadGroupResult(stored, &r);
      }
      if (!r.resumed) {
        // A report folder left by an interrupted fit of this group goes first.
        const std::string report = options.reports_dir + "/" + folders[pick];
        std::string outside;
        if (!options.reports_dir.empty() && IsInsideFolder(options.reports_dir, report, &outside)) {
          std::error_code ec;
          std::filesystem::remove_all(report, ec);
        }
        r = FitOne(group, pick, index, folders[pick], options);
        std::string error;
        // A group that cannot be stored is only refitted by a resumed run.
        if (!stored.empty() && !SaveGroupResult(stored, r, &error)) r.warnings.push_back(error);
      }
      lock.lock();
      results[pick] = std::move(r);
      finished[pick] = 1;
      --running;
      ++done;
      if (progress) progress(results[pick], done, total);
      changed.notify_all();
    }
  };
  const int count = std::clamp(options.parallel_groups, 1, total);
  std::vector<std::thread> pool;
  for (int w = 1; w < count; ++w) pool.emplace_back(worker, w);
  worker(0);
  for (std::thread& t : pool) t.join();
  return results;
}

}  // namespace ccdpsf::trend
