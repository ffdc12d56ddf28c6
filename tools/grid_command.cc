// ccdpsf grid: every spot of full-sensor frames fitted, and the PSF map across the sensor;
// sharded across processes when started by mpirun.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/grid/grid.h"
#include "ccdpsf/grid/psf_map.h"
#include "ccdpsf/grid/spot_relations.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/process_group.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/trend/campaign.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(config);
DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_bool(strict);
DECLARE_string(manifest);
DECLARE_bool(resume);
DECLARE_int32(stamp_size);
// The parser's flags read only by grid; their meanings are GridCommand()'s table.
DEFINE_double(match_radius_px, 3.0, "");
DEFINE_double(min_significance, 10.0, "");

namespace ccdpsf::tools {
namespace {

// A spot's posterior needs a few hundred independent draws for its 68 % interval (the MC
// error of a bound is then ~0.07 sd), as trend's settings do.
constexpr double kGridTargetEss = 400;

// The terminal's last line: spots by what became of them.
std::string GridSummary(const grid::GridResult& r, const std::string& out_dir) {
  std::map<std::string, int> verdicts, refusals;
  for (const grid::SpotEntry& e : r.spots) {
    if (!e.fitted) {
      ++refusals[e.where.refused];
    } else if (!e.fit.ok) {
      ++verdicts["failed or invalid"];
    } else {
      ++verdicts[e.fit.quality.Verdict()];
    }
  }
  auto list = [](const std::map<std::string, int>& counts) {
    std::string out;
    for (const auto& [name, n] : counts) {
      out += (out.empty() ? "" : ", ") + std::to_string(n) + " " + name;
    }
    return out.empty() ? std::string("none") : out;
  };
  int fitted = 0;
  for (const auto& [name, n] : verdicts) fitted += n;
  return "grid of " + std::to_string(r.spots.size()) + " spots in " +
         std::to_string(r.settings.size()) + " setting(s): " + std::to_string(fitted) +
         " fitted (" + list(verdicts) + "), " +
         std::to_string(r.spots.size() - static_cast<size_t>(fitted)) + " not fitted (" +
         list(refusals) + "); map: " + out_dir + "/psf_map.fits";
}

int RunGridCommand(const std::vector<std::string>& inputs) {
  ProcessGroup& processes = ProcessGroup::Get();
  std::string error;
  if (processes.launched_without_mpi_support()) return Fail(processes.launch_error());
  const bool root = processes.rank() == 0;
  // One process's fatal error ends every process of the job (the others may be waiting for
  // its results): the message from the process that saw it, then the job's end.
  auto fatal = [&](const std::string& message, bool usage = false) {
    const int code = usage ? Usage(message) : Fail(message);
    if (processes.distributed()) processes.Abort(code);
    processes.Finalize();  // `mpirun -np 1` joined MPI too
    return code;
  };
  if (FLAGS_out.empty()) return fatal("grid needs --out=DIR", true);
  PlotOptions plot;
  if (!ParsePlotFormat(FLAGS_plot_format, &plot.format, &error)) return fatal(error);
  grid::GridOptions options;
  if (!ResolveFitConfig(&options.fit.config, &error)) return fatal(error);
  for (const fit::FitEffect& e : options.fit.config.model.effects) {
    if (e.kind == model::EffectKind::kBrighterFatter) {
      // A setting holds one intensity, where the slope is exactly a change of the CCD widths.
      return fatal(
          "grid cannot fit brighter_fatter: each spot is fitted over one setting, at one "
          "intensity, where the slope is exactly a change of the CCD widths (use trend, whose "
          "intensity series fits it)",
          true);
    }
  }
  // Values out of range are bad input (exit 1, README "Exit codes"), not usage errors. The
  // match radius is at most 1e6 px, larger than any sensor.
  if (!(FLAGS_match_radius_px > 0 && FLAGS_match_radius_px <= 1e6)) {
    return fatal("--match_radius_px must be in (0, 1e6] px, got " +
                 NumberText(FLAGS_match_radius_px));
  }
  if (!(FLAGS_min_significance > 0 && std::isfinite(FLAGS_min_significance))) {
    return fatal("--min_significance must be finite and > 0, got " +
                 NumberText(FLAGS_min_significance));
  }
  options.fit.seed = options.fit.config.fit.mcmc.seed;
  options.fit.flux_given = options.fit.config.flux_given;
  options.fit.parallel_groups = options.fit.config.fit.mcmc.num_threads;
  options.fit.draws = 400;
  options.scan.finder.stamp_size = options.fit.config.calibration.stamp_size;
  options.scan.finder.min_significance = FLAGS_min_significance;
  options.match_radius_px = FLAGS_match_radius_px;
  options.rank = processes.rank();
  options.size = processes.size();
  options.gather = [&](const std::string& text) {
    std::vector<std::string> texts;
    std::string why;
    if (!processes.GatherToRoot(text, &texts, &why)) processes.Abort(Fail("grid: " + why));
    return texts;
  };
  const std::string prefix =
      processes.distributed() ? "[process " + std::to_string(processes.rank()) + "] " : "";
  std::mutex print;
  options.progress = [&](const std::string& line) {
    std::lock_guard<std::mutex> lock(print);
    std::fprintf(stderr, "%s%s\n", prefix.c_str(), line.c_str());
    std::fflush(stderr);
  };

  trend::CampaignOptions campaign;
  campaign.config = options.fit.config.calibration;
  if (!InputFlags(&campaign.flags, &campaign.config.keywords, &error)) return fatal(error);
  if (campaign.flags.Has("spot_x_px") || campaign.flags.Has("bad_pixel_mask")) {
    return fatal(
        "grid finds every spot itself and takes no --spot_x_px / --spot_y_px; "
        "--bad_pixel_mask is not supported by grid yet",
        true);
  }
  if (FlagGiven("manifest")) campaign.manifest = FLAGS_manifest;
  if (inputs.empty() && campaign.manifest.empty()) {
    return fatal("grid needs frames: FITS files, a folder of them, or a manifest", true);
  }
  std::vector<trend::CampaignGroup> settings;
  if (!trend::LoadCampaign(inputs, campaign, &settings, &error)) return fatal(error);
  for (const trend::CampaignGroup& g : settings) {
    if (!g.problem.empty()) return fatal(g.problem);  // names the file
  }
  std::vector<std::string> read = inputs;
  for (const trend::CampaignGroup& g : settings) {
    read.insert(read.end(), g.files.begin(), g.files.end());
  }

  // The first process owns the output folder; every process keeps its finished spots in its
  // store, so that --resume redoes only the spots not finished.
  const std::string kStore = "store";
  OutputFolder out;
  std::string partial;
  if (root) {
    if (!out.Begin(FLAGS_out, RunInputs(read),
                   FLAGS_resume ? std::vector<std::string>{kStore} : std::vector<std::string>{},
                   &error) ||
        !MakeDirectories(out.partial() + "/" + kStore, &error)) {
      return fatal(error);
    }
    partial = out.partial();
  }
  if (!processes.Broadcast(&partial, &error)) return fatal(error);
  options.fit.store_dir = partial + "/" + kStore;
  options.fit.run_signature = RunSignature(inputs);
  if (root) {
    int frames = 0;
    for (const auto& g : settings) frames += static_cast<int>(g.files.size());
    std::fprintf(stderr,
                 "ccdpsf grid: %zu setting(s), %d frames; %d process(es), %d spot fits "
                 "at a time in each\n",
                 settings.size(), frames, processes.size(), options.fit.parallel_groups);
  }
  const auto start = std::chrono::steady_clock::now();
  grid::GridResult result;
  if (!grid::RunGrid(settings, options, &result, &error)) return fatal(error);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!root) {
    processes.Finalize();
    return 0;
  }

  const bool have_mcmc = options.fit.config.fit.run_mcmc;
  grid::PsfMapOutputs outputs;
  nlohmann::json run = {{"command", "grid"},
                        {"inputs", inputs},
                        {"options", fit::FitConfigJson(options.fit.config)},
                        {"seed", options.fit.seed},
                        {"processes", processes.size()},
                        {"threads_per_process", options.fit.parallel_groups},
                        {"seconds", seconds},
                        {"software", SoftwareVersions()}};
  trend::RelationOptions relation_options;
  relation_options.seed = options.fit.seed;
  const std::vector<grid::SpotRelation> relations =
      grid::FitSpotRelations(result, options.match_radius_px, relation_options);
  if (!grid::WritePsfMap(partial, result, relations, options.fit.config.model.effects, have_mcmc,
                         plot, &outputs, &error) ||
      !WriteTextFileAtomically(partial + "/run.json", run.dump(2) + "\n", &error) ||
      !WriteRunConfig(partial, options.fit.config, nlohmann::json::object(), &error) ||
      !out.Commit({kStore}, &error)) {
    return fatal(error);
  }
  for (const std::string& w : outputs.warnings) {
    std::fprintf(stderr, "ccdpsf: warning: %s\n", w.c_str());
  }
  std::printf("%s\n", GridSummary(result, FLAGS_out).c_str());
  processes.Finalize();
  int flagged = 0;
  for (const grid::SpotEntry& e : result.spots) {
    flagged += e.fitted && (!e.fit.ok || e.fit.quality.Worst() != Severity::kNote);
  }
  return FLAGS_strict && flagged > 0 ? kExitStrict : 0;
}

}  // namespace

Command GridCommand() {
  const fit::FitConfig d;
  std::vector<Option> options = {
      {"out", "", "Output folder (required); replaced as a whole by the run's results"},
      {"config", "",
       "FIT.json with the options of every spot's fit (priors, MCMC settings, calibration, "
       "keyword map); a grid's OUT/config.json repeats it; flags given override it"},
      {"plot_format", "png", "Format of the maps: png, pdf or svg"},
      {"sampling", model::ToString(d.model.model.sampling),
       "Model sampling of every spot's fit: integrated or pixel_centre"},
      {"defocus", model::ToString(d.model.model.defocus),
       "Defocus kernel of every spot's fit: gaussian or pillbox"},
      {"likelihood", fit::ToString(d.model.likelihood),
       "gaussian (the paper's) or poisson_normal (exact, for low signal)"},
      {"seed", "1", "Random seed of the spots' MCMCs (spot i's derived from it and i)"},
      {"walkers", std::to_string(d.fit.num_walkers),
       "MCMC walkers per spot (0: max(2 x ensemble dimension + 2, target_ess / 50))"},
      {"max_steps", std::to_string(d.fit.mcmc.max_steps), "MCMC step limit per spot"},
      {"target_ess", NumberText(kGridTargetEss),
       "Effective sample size every parameter of a spot must reach"},
      {"threads", std::to_string(d.fit.mcmc.num_threads),
       "Spots fitted at a time in each process (each MCMC on one thread)"},
      {"mcmc", d.fit.run_mcmc ? "true" : "false",
       "Run each spot's MCMC (--nomcmc: MAP and Laplace only; intervals MAP +- Laplace sd)"},
      {"flux", "auto",
       "How a spot's exposures share the light: auto, shared, per_exposure or exptime_scaled"},
      {"effects", "",
       "Effects of the catalogue fitted with every spot, comma-separated (" +
           fit::FittableEffectNames(", ", {model::EffectKind::kBrighterFatter}) +
           "; `ccdpsf effects` describes them), with the catalogue's priors (FIT.json "
           "\"effects\" sets others); psf_map gets each parameter's column and map"},
      {"match_radius_px", "3",
       "Largest distance [px] between a spot's centroids in two exposures of a setting"},
      {"min_significance", "10",
       "Detection threshold: a source's 3 x 3-smoothed peak in sds of the smoothed background "
       "(10: at 5, a 4096 x 4096 frame of pure noise yields about ten false sources; lab "
       "spots stand thousands of sds high)"},
      {"strict", "false",
       "Exit with code 3 when a fitted spot failed or its verdict is suspect or invalid"},
      {"resume", "false",
       "Continue a run that was killed, into the same --out with the same inputs and options: "
       "the spots already fitted are kept"}};
  for (const Option& o : InputOptions()) {
    if (o.name != "spot_x_px" && o.name != "spot_y_px" && o.name != "bad_pixel_mask") {
      options.push_back(o);
    }
  }
  return {"grid",
          "ccdpsf grid --out=DIR [options] FRAMES (FITS files, folders, or a manifest; "
          "`mpirun -np N ccdpsf grid ...` shards the spots over N processes)",
          "Fit every compact, isolated spot of full frames jointly over each setting's "
          "exposures; PSF map across the sensor (psf_map.fits / .csv), catalogue, DS9 regions.",
          options, RunGridCommand};
}

}  // namespace ccdpsf::tools
