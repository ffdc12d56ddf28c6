// Every spot of a campaign's frames, each fitted jointly over its setting's exposures: the
// PSF across the sensor (`ccdpsf grid`).
//
// Per setting (trend/campaign.h groups the files as `trend` does), in order:
//   1. every frame is scanned once (frame_scan.h): all sources, refusals with reasons,
//      cutouts of the fittable ones;
//   2. sources are matched across the setting's exposures (spot_matching.h);
//   3. each fittable spot's cutouts are calibrated (exposure.h, with the spot's position
//      given) and fitted jointly like one of trend's groups (trend/group_fit.h): the same
//      model, flux choice, outlier masking, MCMC and verdict. A setting of three or more
//      focus positions is a through-focus series, which identifies the CCD widths per spot.
// Spots are numbered over the whole run (settings in order, then spot_matching.h's order);
// spot i's MCMC seed is DeriveSeed(seed, i).
//
// Sharding. With size > 1 processes (MPI ranks, or any launcher that gives each process its
// rank), every process scans the frames (a few tenths of a second a frame, against seconds
// per spot fit) and fits the spots with i % size == rank; the results travel to the first
// process through `gather`. Each spot's result depends only on its data, the options and its
// index, never on which process fitted it or on the thread count, so the merged result
// equals that of one process bit for bit.
#ifndef CCDPSF_GRID_GRID_H_
#define CCDPSF_GRID_GRID_H_

#include <functional>
#include <string>
#include <vector>

#include "ccdpsf/grid/frame_scan.h"
#include "ccdpsf/grid/spot_matching.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"

namespace ccdpsf::grid {

struct GridOptions {
  trend::GroupFitOptions fit;  // model and fit options, seed, spots fitted at a time, store
  FrameScanOptions scan;
  double match_radius_px = 3.0;
  int rank = 0;  // this process, of `size`
  int size = 1;
  // Sends this process's text to the first process and returns every process's, in rank
  // order, there (an empty vector elsewhere). Needed when size > 1.
  std::function<std::vector<std::string>(const std::string&)> gather;
  // A line of progress for the terminal (from worker threads, serialised); may be null.
  std::function<void(const std::string&)> progress;
};

// One spot of one setting.
struct SpotEntry {
  int setting = 0;      // index into GridResult::settings
  int spot = 0;         // index over the whole run
  GridSpot where;       // position and refusal
  std::string segment;  // the frames' EXTNAME, else their HDU number
  bool fitted = false;  // not refused: a fit was made (fit.ok says whether it succeeded)
  trend::GroupResult fit;  // its draws: those of SpotRelationMetrics() only
};

struct GridResult {
  std::vector<trend::CampaignGroup> settings;
  std::vector<std::vector<ScannedFrame>> frames;  // per setting and exposure; no cutouts
  std::vector<SpotEntry> spots;  // every spot on the first process; this shard's elsewhere
};

// False with a one-line reason when a frame cannot be read or the processes' results do not
// arrive; spots that cannot be fitted are kept with their reasons.
bool RunGrid(const std::vector<trend::CampaignGroup>& settings, const GridOptions& options,
             GridResult* result, std::string* error);

}  // namespace ccdpsf::grid

#endif  // CCDPSF_GRID_GRID_H_
