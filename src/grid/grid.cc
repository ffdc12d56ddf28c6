// Every spot of a campaign's frames, fitted (grid.h).
#include "ccdpsf/grid/grid.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iterator>
#include <map>
#include <mutex>

#include "ccdpsf/exposure_set.h"
#include "ccdpsf/grid/spot_relations.h"
#include "ccdpsf/trend/group_store.h"
#include "internal/text.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::grid {
namespace {

std::string SpotName(const trend::CampaignGroup& setting, int spot) {
  char text[32];
  std::snprintf(text, sizeof(text), "spot_%05d", spot);
  return setting.name + "_" + text;
}

// A cutout's own data section (1-based, inclusive): the part of the frame's data section it
// covers.
std::string CutoutDataSection(const ScannedFrame& frame, const FrameCutout& cut) {
  const PixelRegion& d = frame.data_region;
  const int x0 = std::max(d.x_begin, cut.x0) - cut.x0;
  const int x1 = std::min(d.x_end, cut.x0 + cut.image.pixels.nx) - cut.x0;
  const int y0 = std::max(d.y_begin, cut.y0) - cut.y0;
  const int y1 = std::min(d.y_end, cut.y0 + cut.image.pixels.ny) - cut.y0;
  return "[" + std::to_string(x0 + 1) + ":" + std::to_string(x1) + "," + std::to_string(y0 + 1) +
         ":" + std::to_string(y1) + "]";
}

// File e's calibration options: its own (flags, manifest row, FIT.json merged), else the run's.
const CalibrationOptions& FileOptions(const trend::CampaignGroup& setting, size_t e,
                                      const CalibrationOptions& run) {
  return e < setting.inputs.size() ? setting.inputs[e].options : run;
}

// The spot's calibrated exposures, from its cutouts.
bool CalibrateSpot(const trend::CampaignGroup& setting, const std::vector<ScannedFrame>& frames,
                   const GridSpot& spot, const CalibrationOptions& run, ExposureSet* set,
                   std::string* error) {
  for (size_t e = 0; e < frames.size(); ++e) {
    const ScannedFrame& frame = frames[e];
    const FrameSource& source = frame.sources[spot.source[e]];
    const FrameCutout& cut = frame.cutouts[source.cutout];
    CalibrationOptions options = FileOptions(setting, e, run);
    const std::string from = "grid: the peak found in the frame scan";
    options.given.SetNumber("spot_x_px", source.shape.peak_x - cut.x0, from);
    options.given.SetNumber("spot_y_px", source.shape.peak_y - cut.y0, from);
    options.given.SetText("data_section", CutoutDataSection(frame, cut),
                          "grid: the cutout's part of the data section");
    char where[96];
    std::snprintf(where, sizeof(where), "[%d:%d,%d:%d]", cut.x0 + 1, cut.x0 + cut.image.pixels.nx,
                  cut.y0 + 1, cut.y0 + cut.image.pixels.ny);
    std::optional<Exposure> exposure =
        CalibrateExposure(cut.image, frame.path + where, options, error);
    if (!exposure) return false;
    // Stamp coordinates back to the frame's, so positions read as in DS9.
    exposure->stamp.origin_x += cut.x0;
    exposure->stamp.origin_y += cut.y0;
    exposure->report.spot_x_px += cut.x0;
    exposure->report.spot_y_px += cut.y0;
    exposure->report.peak_x_px += cut.x0;
    exposure->report.peak_y_px += cut.y0;
    set->exposures.push_back(std::move(*exposure));
    set->settings.push_back(setting.name);
  }
  CheckPeakCompression(set->exposures, &set->quality);
  return true;
}

// Every spot of setting `s`, numbered from *next_spot on; a fitted one's result is named.
std::vector<SpotEntry> SettingSpots(const std::vector<trend::CampaignGroup>& settings, int s,
                                    const std::vector<ScannedFrame>& frames, double radius,
                                    int* next_spot) {
  std::string segment = frames.empty() ? "" : frames[0].extname;
  if (segment.empty() && !frames.empty()) segment = std::to_string(frames[0].hdu_number - 1);
  std::vector<SpotEntry> entries;
  for (const GridSpot& spot : MatchSpots(frames, radius)) {
    SpotEntry entry;
    entry.setting = s;
    entry.spot = (*next_spot)++;
    entry.where = spot;
    entry.segment = segment;
    entry.fitted = spot.refused.empty();
    if (entry.fitted) {
      entry.fit.group = settings[s];
      entry.fit.group.name = SpotName(settings[s], entry.spot);
      entry.fit.group.problem.clear();
    }
    entries.push_back(std::move(entry));
  }
  return entries;
}

}  // namespace

bool RunGrid(const std::vector<trend::CampaignGroup>& settings, const GridOptions& options,
             GridResult* result, std::string* error) {
  *result = GridResult();
  result->settings = settings;
  std::vector<SpotEntry> mine;
  int next_spot = 0;
  // Every frame scanned so far, to refuse one counted twice (as fit does): the same file
  // and HDU, or identical pixels under another name. Each would count as an exposure of its
  // own, and its spots' intervals would shrink by 1/sqrt(2) for nothing.
  struct Seen {
    std::string key, path;
    uint64_t digest;
  };
  std::vector<Seen> seen;
  for (size_t s = 0; s < settings.size(); ++s) {
    const trend::CampaignGroup& setting = settings[s];
    std::vector<ScannedFrame> frames(setting.files.size());
    if (!setting.problem.empty()) {
      *error = "setting " + setting.name + ": " + setting.problem;
      return false;
    }
    for (size_t e = 0; e < setting.files.size(); ++e) {
      if (!ScanFrame(setting.files[e], FileOptions(setting, e, options.fit.config.calibration),
                     options.scan, &frames[e], error)) {
        return false;
      }
      const Seen frame = {CanonicalPath(setting.files[e]) + "[" +
                              std::to_string(frames[e].hdu_number) + "]",
                          setting.files[e], frames[e].pixel_digest};
      for (const Seen& earlier : seen) {
        if (earlier.key == frame.key || earlier.digest == frame.digest) {
          *error = CountedTwice(frame.path, earlier.path, earlier.key == frame.key);
          return false;
        }
      }
      seen.push_back(frame);
      if (options.progress) {
        int fittable = 0;
        for (const FrameSource& src : frames[e].sources) fittable += src.refused.empty();
        options.progress("scanned " + setting.files[e] + ": " +
                         std::to_string(frames[e].sources.size()) + " sources, " +
                         std::to_string(fittable) + " compact and isolated");
      }
    }
    // This process's spots of the setting; the fittable ones as trend groups.
    std::vector<trend::CampaignGroup> groups;
    std::vector<int> group_spot, seeds;
    std::vector<SpotEntry> entries;
    for (SpotEntry& entry :
         SettingSpots(settings, static_cast<int>(s), frames, options.match_radius_px, &next_spot)) {
      if (entry.spot % options.size != options.rank) continue;
      if (entry.fitted) {
        groups.push_back(entry.fit.group);
        group_spot.push_back(static_cast<int>(entries.size()));
        seeds.push_back(entry.spot);
      }
      entries.push_back(std::move(entry));
    }
    trend::GroupFitOptions fit = options.fit;
    fit.seed_indices = seeds;
    fit.load_exposures = [&](int g, ExposureSet* set, std::string* why) {
      return CalibrateSpot(setting, frames, entries[group_spot[g]].where,
                           options.fit.config.calibration, set, why);
    };
    std::vector<trend::GroupResult> fitted =
        trend::FitGroups(groups, fit, [&](const trend::GroupResult& r, int done, int total) {
          if (!options.progress) return;
          char line[256];
          if (r.ok) {
            std::snprintf(line, sizeof(line), "[%d/%d] %s: verdict %s, chi2/dof %.3f, %.1f s%s",
                          done, total, r.group.name.c_str(), r.quality.Verdict().c_str(),
                          r.chi2_per_dof, r.seconds,
                          r.resumed ? " (kept from an earlier run)" : "");
          } else {
            std::snprintf(line, sizeof(line), "[%d/%d] %s: not fitted: %.180s", done, total,
                          r.group.name.c_str(), r.failure.c_str());
          }
          options.progress(line);
        });
    for (size_t g = 0; g < fitted.size(); ++g) {
      // Only the related metrics' draws are kept (spot_relations.h): the others would make a
      // spot's result ~115 KB instead of ~16 KB, which 10^4 spots gathered to one process
      // cannot afford.
      std::map<std::string, std::vector<double>>& draws = fitted[g].draws;
      for (auto it = draws.begin(); it != draws.end();) {
        const std::vector<std::string>& keep = SpotRelationMetrics();
        it = std::find(keep.begin(), keep.end(), it->first) == keep.end() ? draws.erase(it)
                                                                           : std::next(it);
      }
      entries[group_spot[g]].fit = std::move(fitted[g]);
    }
    for (SpotEntry& entry : entries) mine.push_back(std::move(entry));
    for (ScannedFrame& frame : frames) frame.cutouts.clear();
    result->frames.push_back(std::move(frames));
  }

  if (next_spot == 0) {
    // Every process scanned every frame: they all stop here alike.
    *error = "no source found in the " + std::to_string(seen.size()) +
             " frame(s) (at --min_significance=" +
             internal::FormatNumber(options.scan.finder.min_significance) +
             "): there is no spot to fit and no map to make";
    return false;
  }
  if (options.size <= 1) {
    result->spots = std::move(mine);
    return true;
  }
  // The shards' spots to the first process, which puts them in run order.
  nlohmann::json text = nlohmann::json::array();
  for (const SpotEntry& e : mine) {
    text.push_back({e.spot, e.fitted ? trend::GroupResultJson(e.fit) : nlohmann::json()});
  }
  if (!options.gather) {
    *error = "grid: " + std::to_string(options.size) + " processes but no way to gather results";
    return false;
  }
  const std::vector<std::string> all = options.gather(text.dump());
  if (options.rank != 0) {
    result->spots = std::move(mine);
    return true;
  }
  if (static_cast<int>(all.size()) != options.size) {
    *error = "grid: results arrived from " + std::to_string(all.size()) + " of " +
             std::to_string(options.size) + " processes";
    return false;
  }
  // Every process matched the same spots (the same frames and options): rebuild the full list
  // here and fill in the fits.
  std::vector<SpotEntry> every;
  int spot_index = 0;
  for (size_t s = 0; s < settings.size(); ++s) {
    for (SpotEntry& entry : SettingSpots(settings, static_cast<int>(s), result->frames[s],
                                         options.match_radius_px, &spot_index)) {
      every.push_back(std::move(entry));
    }
  }
  std::vector<uint8_t> arrived(every.size(), 0);
  for (int rank = 0; rank < options.size; ++rank) {
    const nlohmann::json j = nlohmann::json::parse(all[rank], nullptr, false);
    if (!j.is_array()) {
      *error = "grid: the results of process " + std::to_string(rank) + " are unreadable";
      return false;
    }
    for (const nlohmann::json& item : j) {
      const int spot = item.is_array() && item.size() == 2 && item[0].is_number_integer()
                           ? item[0].get<int>()
                           : -1;
      if (spot < 0 || spot >= static_cast<int>(every.size()) || spot % options.size != rank ||
          arrived[spot]) {
        *error = "grid: process " + std::to_string(rank) + " sent a result for spot " +
                 std::to_string(spot) +
                 ", which is not its own (the processes disagree about "
                 "the frames)";
        return false;
      }
      arrived[spot] = 1;
      SpotEntry& entry = every[spot];
      if (entry.fitted && !trend::GroupResultFromJson(item[1], &entry.fit)) {
        *error = "grid: the result of spot " + std::to_string(spot) + " from process " +
                 std::to_string(rank) + " is unreadable";
        return false;
      }
    }
  }
  for (size_t i = 0; i < every.size(); ++i) {
    if (!arrived[i]) {
      *error = "grid: no result arrived for spot " + std::to_string(i) + " (process " +
               std::to_string(static_cast<int>(i) % options.size) + ")";
      return false;
    }
  }
  result->spots = std::move(every);
  return true;
}

}  // namespace ccdpsf::grid
