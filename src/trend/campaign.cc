#include "ccdpsf/trend/campaign.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>

#include "ccdpsf/fits_io.h"
#include "internal/text.h"

namespace ccdpsf::trend {
namespace {

namespace fs = std::filesystem;

bool IsFitsName(const fs::path& p) {
  const std::string ext = p.extension().string();
  const std::string name = p.filename().string();
  return ext == ".fits" || ext == ".fit" || ext == ".fts" ||
         (name.size() > 8 && name.compare(name.size() - 8, 8, ".fits.gz") == 0);
}

std::vector<std::string> FitsFilesIn(const fs::path& folder) {
  std::vector<std::string> found;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    if (entry.is_regular_file() && IsFitsName(entry.path())) found.push_back(entry.path().string());
  }
  std::sort(found.begin(), found.end());
  return found;
}

// What grouping needs of one file: its wavelength, exposure time and focus position from
// metadata.h's sources. A file that cannot be read or has no wavelength gets a problem.
struct Placed {
  InputFile input;
  double wavelength = NAN, exptime = NAN, focus = NAN;
  std::string problem;
};

Placed Place(InputFile input) {
  Placed p;
  p.input = std::move(input);
  const CalibrationOptions& o = p.input.options;
  std::string why;
  const GivenValue* hdu = o.given.Find("hdu");
  // The header only (the same screen and HDU choice as reading the pixels): a campaign of
  // full-sensor frames is placed without holding any of them.
  const std::unique_ptr<FitsImageStream> image =
      FitsImageStream::Open(p.input.path, hdu != nullptr && hdu->text ? *hdu->text : "", &why);
  if (!image) {
    p.problem = why;
    return p;
  }
  std::optional<double> value;
  std::string source;
  if (!ResolveNumber(o.given, o.keywords, image->image().header, "wavelength_nm", &value, &source,
                     &why)) {
    p.problem = "'" + p.input.path + "': " + why;
    return p;
  }
  if (!value || !(*value > 0)) {
    p.problem = "'" + p.input.path +
                "': no wavelength (a WAVELEN keyword, --wavelength_nm or a manifest column "
                "wavelength_nm), so its setting is unknown";
    return p;
  }
  p.wavelength = *value;
  if (ResolveNumber(o.given, o.keywords, image->image().header, "exptime_s", &value, &source,
                    &why) &&
      value) {
    p.exptime = *value;
  }
  if (ResolveNumber(o.given, o.keywords, image->image().header, "focus_position_um", &value,
                    &source, &why) &&
      value) {
    p.focus = *value;
  }
  return p;
}

CampaignGroup FailedFile(const Placed& p) {
  CampaignGroup bad;
  bad.name = fs::path(p.input.path).stem().string();
  bad.wavelength_nm = NAN;
  bad.files = {p.input.path};
  bad.inputs = {p.input};
  bad.problem = p.problem;
  return bad;
}

// A group of placed files: its wavelength (which they must share), exposure time and
// whether it is a focus series.
CampaignGroup MakeGroup(const std::string& name, const std::vector<Placed>& files) {
  CampaignGroup g;
  g.name = name;
  std::set<double> focus;
  std::set<double> exptimes;
  double lo = INFINITY, hi = -INFINITY;
  for (const Placed& p : files) {
    g.files.push_back(p.input.path);
    g.inputs.push_back(p.input);
    if (std::isfinite(p.focus)) focus.insert(p.focus);
    if (std::isfinite(p.exptime)) exptimes.insert(p.exptime);
    lo = std::min(lo, p.wavelength);
    hi = std::max(hi, p.wavelength);
  }
  g.wavelength_nm = lo;
  if (exptimes.size() == 1) g.exptime_s = *exptimes.begin();
  g.focus_series = focus.size() >= 3;
  bool every_focus = !files.empty();
  for (const Placed& p : files) every_focus = every_focus && std::isfinite(p.focus);
  if (every_focus) g.focus_positions_um.assign(focus.begin(), focus.end());
  if (hi - lo > 1.0) {
    g.problem = "its files are at wavelengths from " + internal::FormatNumber(lo) + " to " +
                internal::FormatNumber(hi) + " nm, which do not share one PSF";
  }
  return g;
}

// Groups placed files by (wavelength, exposure time).
void GroupByMetadata(const std::vector<Placed>& placed, std::vector<CampaignGroup>* groups) {
  struct Key {
    double wavelength;
    double exptime;  // -1 when unknown
    bool operator<(const Key& o) const {
      if (wavelength != o.wavelength) return wavelength < o.wavelength;
      return exptime < o.exptime;
    }
  };
  std::map<Key, std::vector<Placed>> by_setting;
  for (const Placed& p : placed) {
    if (!p.problem.empty()) {
      groups->push_back(FailedFile(p));
      continue;
    }
    by_setting[{p.wavelength, std::isfinite(p.exptime) ? p.exptime : -1.0}].push_back(p);
  }
  for (const auto& [key, files] : by_setting) {
    std::string name =
        internal::FormatNumber(key.wavelength) + "nm" +
        (key.exptime >= 0 ? "_" + internal::FormatNumber(key.exptime) + "s" : std::string());
    CampaignGroup g = MakeGroup(name, files);
    if (g.focus_series) g.name += "_focus";
    groups->push_back(std::move(g));
  }
}

std::vector<Placed> PlaceAll(const std::vector<InputFile>& inputs) {
  std::vector<Placed> out;
  for (const InputFile& input : inputs) out.push_back(Place(input));
  return out;
}

bool FromManifest(const Manifest& manifest, const std::vector<std::string>& files,
                  const CampaignOptions& options, std::vector<CampaignGroup>* groups,
                  std::string* error) {
  std::vector<InputFile> inputs;
  if (!ResolveInputFiles(files, &manifest, options.flags, options.config, &inputs, error)) {
    return false;
  }
  // Files with a setting, in the manifest's order of settings; the rest by metadata.
  std::vector<std::string> order;
  std::map<std::string, std::vector<Placed>> by_setting;
  std::vector<Placed> unset;
  for (const InputFile& input : inputs) {
    Placed p = Place(input);
    if (input.setting.empty()) {
      unset.push_back(std::move(p));
      continue;
    }
    if (!by_setting.count(input.setting)) order.push_back(input.setting);
    by_setting[input.setting].push_back(std::move(p));
  }
  for (const std::string& name : order) {
    const std::vector<Placed>& members = by_setting[name];
    CampaignGroup g;
    bool failed = false;
    for (const Placed& p : members) {
      if (!p.problem.empty()) {
        g = FailedFile(p);
        g.name = name;
        for (const Placed& q : members) {
          if (&q != &p) {
            g.files.push_back(q.input.path);
            g.inputs.push_back(q.input);
          }
        }
        failed = true;
        break;
      }
    }
    if (!failed) g = MakeGroup(name, members);
    for (const ManifestSetting& s : manifest.settings) {
      if (s.name != name) continue;
      g.nominal_peak_e = s.nominal_peak_e;
      if (!failed) g.focus_series = s.focus_series || g.focus_series;
    }
    groups->push_back(std::move(g));
  }
  for (const ManifestSetting& s : manifest.settings) {
    if (!by_setting.count(s.name)) {
      CampaignGroup g;
      g.name = s.name;
      g.wavelength_nm = NAN;
      g.problem = "the manifest lists no files for this group";
      groups->push_back(std::move(g));
    }
  }
  GroupByMetadata(unset, groups);
  return true;
}

}  // namespace

bool LoadCampaign(const std::vector<std::string>& inputs, std::vector<CampaignGroup>* groups,
                  std::string* error) {
  return LoadCampaign(inputs, CampaignOptions(), groups, error);
}

bool LoadCampaign(const std::vector<std::string>& inputs, const CampaignOptions& options,
                  std::vector<CampaignGroup>* groups, std::string* error) {
  groups->clear();
  std::error_code ec;
  // A manifest: --manifest, a manifest file given, or a folder holding manifest.json.
  std::string manifest_path = options.manifest;
  std::vector<std::string> rest;
  for (const std::string& input : inputs) {
    const fs::path p(input);
    if (manifest_path.empty() && inputs.size() == 1 && fs::is_directory(p, ec) &&
        fs::exists(p / "manifest.json", ec)) {
      manifest_path = (p / "manifest.json").string();
    } else if (manifest_path.empty() && IsManifestPath(input) && !fs::is_directory(p, ec)) {
      manifest_path = input;
    } else {
      rest.push_back(input);
    }
  }
  if (!manifest_path.empty()) {
    Manifest manifest;
    if (!LoadManifest(manifest_path, &manifest, error)) return false;
    std::vector<std::string> files;
    for (const std::string& r : rest) {
      if (fs::is_directory(r, ec)) {
        for (const std::string& f : FitsFilesIn(r)) files.push_back(f);
      } else {
        files.push_back(r);
      }
    }
    return FromManifest(manifest, files, options, groups, error);
  }
  if (inputs.empty()) {
    *error = "no campaign given (a manifest, a campaign folder, or FITS files / folders)";
    return false;
  }
  std::vector<std::string> files;
  std::vector<std::pair<std::string, std::vector<std::string>>> settings;  // subfolders
  for (const std::string& input : inputs) {
    if (fs::is_directory(input, ec)) {
      const std::vector<std::string> direct = FitsFilesIn(input);
      files.insert(files.end(), direct.begin(), direct.end());
      if (inputs.size() == 1) {
        // A campaign folder: each subfolder holding FITS files is a setting.
        std::vector<fs::path> subfolders;
        for (const auto& entry : fs::directory_iterator(input, ec)) {
          if (entry.is_directory()) subfolders.push_back(entry.path());
        }
        std::sort(subfolders.begin(), subfolders.end());
        for (const fs::path& sub : subfolders) {
          std::vector<std::string> inside = FitsFilesIn(sub);
          if (!inside.empty()) settings.push_back({sub.filename().string(), inside});
        }
      }
    } else if (fs::exists(input, ec)) {
      files.push_back(input);
    } else {
      *error = "no such file or folder: " + input;
      return false;
    }
  }
  if (files.empty() && settings.empty()) {
    *error = "no FITS files found in the inputs (nor a manifest, nor subfolders of FITS files)";
    return false;
  }
  for (const auto& [name, members] : settings) {
    std::vector<InputFile> resolved;
    if (!ResolveInputFiles(members, nullptr, options.flags, options.config, &resolved, error)) {
      return false;
    }
    std::vector<Placed> placed = PlaceAll(resolved);
    const auto bad = std::find_if(placed.begin(), placed.end(),
                                  [](const Placed& p) { return !p.problem.empty(); });
    if (bad != placed.end()) {
      CampaignGroup g = FailedFile(*bad);
      g.name = name;
      g.files = members;
      g.inputs = resolved;
      groups->push_back(std::move(g));
      continue;
    }
    groups->push_back(MakeGroup(name, placed));
  }
  if (!files.empty()) {
    std::vector<InputFile> resolved;
    if (!ResolveInputFiles(files, nullptr, options.flags, options.config, &resolved, error)) {
      return false;
    }
    GroupByMetadata(PlaceAll(resolved), groups);
  }
  return true;
}

}  // namespace ccdpsf::trend
