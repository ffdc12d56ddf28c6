#include "ccdpsf/trend/campaign.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "ccdpsf/fits_io.h"
#include "internal/json_reader.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

bool LoadManifest(const std::string& path, std::vector<CampaignGroup>* groups,
                  std::string* error) {
  std::ifstream in(path);
  if (!in) {
    *error = "cannot read campaign manifest " + path;
    return false;
  }
  std::stringstream text;
  text << in.rdbuf();
  const json j = json::parse(text.str(), nullptr, false, true);
  if (j.is_discarded() || !j.is_object()) {
    *error = path + " is not a JSON object";
    return false;
  }
  internal::JsonReader top(j, path, error);
  if (!j.contains("groups") || !j["groups"].is_array() || j["groups"].empty()) {
    *error = path + ": 'groups' must be a non-empty list";
    return false;
  }
  top.Get("groups");
  top.RejectUnknownKeys();
  if (!top.ok()) return false;
  const fs::path base = fs::path(path).parent_path();
  std::set<std::string> names;
  for (size_t i = 0; i < j["groups"].size(); ++i) {
    const json& g = j["groups"][i];
    internal::JsonReader r(g, "groups[" + std::to_string(i) + "]", error);
    CampaignGroup group;
    r.String("name", &group.name, true);
    r.Number("wavelength_nm", &group.wavelength_nm, true);
    if (r.Has("nominal_peak_e")) {
      double v = 0;
      r.Number("nominal_peak_e", &v);
      group.nominal_peak_e = v;
    }
    if (r.Has("exptime_s")) {
      double v = 0;
      r.Number("exptime_s", &v);
      group.exptime_s = v;
    }
    if (r.Has("focus_series")) {
      const json& v = r.Get("focus_series");
      if (!v.is_boolean()) r.Fail("'" + r.Path("focus_series") + "' must be true or false");
      else group.focus_series = v.get<bool>();
    }
    std::vector<std::string> files;
    if (!r.Has("files")) {
      r.Fail("'" + r.Path("files") + "' is required");
    } else {
      const json& list = r.Get("files");
      bool strings = list.is_array();
      for (const json& f : list) strings = strings && f.is_string();
      if (!strings) r.Fail("'" + r.Path("files") + "' must be a list of file names");
      else files = list.get<std::vector<std::string>>();
    }
    r.RejectUnknownKeys();
    if (!r.ok()) return false;
    if (!(group.wavelength_nm > 0)) {
      *error = r.Path("wavelength_nm") + " must be > 0";
      return false;
    }
    if (!names.insert(group.name).second) {
      *error = path + ": group name '" + group.name + "' appears twice";
      return false;
    }
    for (const std::string& f : files) {
      group.files.push_back(fs::path(f).is_absolute() ? f : (base / f).string());
    }
    if (group.files.empty()) group.problem = "the manifest lists no files for this group";
    groups->push_back(std::move(group));
  }
  return true;
}

std::string FormatValue(double v) {
  std::ostringstream out;
  out << v;
  return out.str();
}

bool LoadFolders(const std::vector<std::string>& inputs, std::vector<CampaignGroup>* groups,
                 std::string* error) {
  std::vector<std::string> files;
  for (const std::string& input : inputs) {
    std::error_code ec;
    if (fs::is_directory(input, ec)) {
      std::vector<std::string> found;
      for (const auto& entry : fs::directory_iterator(input, ec)) {
        const std::string ext = entry.path().extension().string();
        if (entry.is_regular_file() && (ext == ".fits" || ext == ".fit" || ext == ".fts")) {
          found.push_back(entry.path().string());
        }
      }
      std::sort(found.begin(), found.end());
      files.insert(files.end(), found.begin(), found.end());
    } else if (fs::exists(input, ec)) {
      files.push_back(input);
    } else {
      *error = "no such file or folder: " + input;
      return false;
    }
  }
  if (files.empty()) {
    *error = "no FITS files found in the inputs (nor a manifest.json)";
    return false;
  }
  // (wavelength, exposure time) -> files; exposure time NaN-safe through its text form.
  struct Key {
    double wavelength;
    double exptime;
    bool operator<(const Key& o) const {
      if (wavelength != o.wavelength) return wavelength < o.wavelength;
      return exptime < o.exptime;
    }
  };
  std::map<Key, CampaignGroup> by_setting;
  std::map<Key, std::set<double>> focus_values;
  for (const std::string& f : files) {
    std::string why;
    const std::optional<FitsImage> image = ReadFitsImage(f, &why);
    std::optional<double> wavelength;
    if (image) wavelength = FindNumber(image->header, "WAVELEN");
    if (!image || !wavelength || !(*wavelength > 0)) {
      CampaignGroup bad;
      bad.name = fs::path(f).stem().string();
      bad.wavelength_nm = NAN;
      bad.files = {f};
      bad.problem = image ? f + ": no valid WAVELEN keyword, so its setting is unknown" : why;
      groups->push_back(std::move(bad));
      continue;
    }
    const double exptime = FindNumber(image->header, "EXPTIME").value_or(-1.0);
    const Key key{*wavelength, exptime};
    CampaignGroup& g = by_setting[key];
    if (g.files.empty()) {
      g.wavelength_nm = *wavelength;
      if (exptime >= 0) g.exptime_s = exptime;
      g.name = FormatValue(*wavelength) + "nm" +
               (exptime >= 0 ? "_" + FormatValue(exptime) + "s" : std::string());
    }
    g.files.push_back(f);
    if (auto focus = FindNumber(image->header, "FOCUSPOS")) focus_values[key].insert(*focus);
  }
  for (auto& [key, g] : by_setting) {
    g.focus_series = focus_values[key].size() >= 3;
    if (g.focus_series) g.name += "_focus";
    groups->push_back(std::move(g));
  }
  return true;
}

}  // namespace

bool LoadCampaign(const std::vector<std::string>& inputs, std::vector<CampaignGroup>* groups,
                  std::string* error) {
  groups->clear();
  if (inputs.empty()) {
    *error = "no campaign given (a manifest, or FITS files / folders)";
    return false;
  }
  std::error_code ec;
  if (inputs.size() == 1) {
    const fs::path p(inputs[0]);
    if (fs::is_directory(p, ec) && fs::exists(p / "manifest.json", ec)) {
      return LoadManifest((p / "manifest.json").string(), groups, error);
    }
    if (p.extension() == ".json") return LoadManifest(p.string(), groups, error);
  }
  return LoadFolders(inputs, groups, error);
}

}  // namespace ccdpsf::trend
