// A manifest: one row per exposure file giving what its header lacks, read by `fit`,
// `diagnose` and `trend` alike (--manifest=FILE, or a trend campaign given as the manifest).
//
// CSV (FILE.csv): a header row naming the columns, then one row per file.
//     file,exptime_s,pixel_um,gain_e_per_adu,spot_x_px,spot_y_px
//     pose_0.1s.fits,0.1,4.65,25,644,468
//   `file` is required; `setting` optionally names the setting (trend's group) the file
//   belongs to; every other column is a quantity of metadata.h. An empty cell means "not
//   given". Lines starting with '#' and blank lines are skipped; a field may be
//   double-quoted (a doubled quote inside stands for one).
// JSON (FILE.json), either
//     {"exposures": [{"file": "a.fits", "setting": "800nm_0.1s", "exptime_s": 0.1}, ...]}
//   with the same keys, or the campaign form `ccdpsf simulate` writes:
//     {"groups": [{"name": "g00_600nm_7900e", "wavelength_nm": 600, "exptime_s": 0.1,
//                  "nominal_peak_e": 7900, "focus_series": false, "files": [...]}, ...]}
//   where a group's name is the setting of each of its files, and its wavelength_nm,
//   exptime_s and any other quantity apply to each of them.
// Relative paths are relative to the manifest's folder. Unknown columns or keys, a file
// listed twice, and malformed values are errors that name the line (or entry) and column.
// Values from a manifest have the source "manifest NAME line N" (CSV) or
// "manifest NAME entry N" (JSON).
#ifndef CCDPSF_MANIFEST_H_
#define CCDPSF_MANIFEST_H_

#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/metadata.h"

namespace ccdpsf {

struct ManifestRow {
  std::string file;       // the path as resolved against the manifest's folder
  std::string setting;    // empty when not given
  GivenMetadata values;
};

// What the campaign form says of a setting beyond its files' metadata.
struct ManifestSetting {
  std::string name;
  std::optional<double> nominal_peak_e;  // [e-], informational
  bool focus_series = false;
};

struct Manifest {
  std::string path;
  std::vector<ManifestRow> rows;
  std::vector<ManifestSetting> settings;  // only from the campaign form, in its order

  // The row for a file, matched by its canonical path; nullptr if the file is not listed.
  const ManifestRow* Find(const std::string& file) const;
};

// True when `path` looks like a manifest (.csv or .json).
bool IsManifestPath(const std::string& path);

bool LoadManifest(const std::string& path, Manifest* manifest, std::string* error);

// A file of a run and what is known of it before its header is read.
struct InputFile {
  std::string path;
  std::string setting;  // the manifest's setting, if any
  CalibrationOptions options;
};

// The files of a run with their options merged by metadata.h's precedence: `flags` (values
// given on the command line), then the file's manifest row, then `config` (FIT.json's
// calibration, keyword map and stamp settings, which every file shares). `files` empty with
// a manifest means every file the manifest lists; files given with a manifest must each be
// listed in it. False with a one-line reason (no files, a file not in the manifest).
bool ResolveInputFiles(const std::vector<std::string>& files, const Manifest* manifest,
                       const GivenMetadata& flags, const CalibrationOptions& config,
                       std::vector<InputFile>* inputs, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_MANIFEST_H_
