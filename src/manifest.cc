// Manifest reading (manifest.h).
#include "ccdpsf/manifest.h"

#include <filesystem>
#include <set>
#include <sstream>

#include "ccdpsf/input_file.h"
#include "nlohmann/json.hpp"
#include "internal/text.h"

namespace ccdpsf {
namespace {

using internal::Printable;
using internal::Trim;

namespace fs = std::filesystem;
using nlohmann::json;



// Splits one CSV line into fields; double quotes protect commas, "" inside quotes is one
// quote. False on an unterminated quote.
bool SplitCsv(const std::string& line, std::vector<std::string>* fields) {
  fields->clear();
  std::string field;
  bool quoted = false, was_quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        field += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        field += c;
      }
    } else if (c == '"' && Trim(field).empty()) {
      quoted = was_quoted = true;
      field.clear();
    } else if (c == ',') {
      fields->push_back(was_quoted ? field : Trim(field));
      field.clear();
      was_quoted = false;
    } else {
      field += c;
    }
  }
  if (quoted) return false;
  fields->push_back(was_quoted ? field : Trim(field));
  return true;
}

std::string Resolve(const fs::path& base, const std::string& file) {
  const fs::path p(file);
  return p.is_absolute() ? p.string() : (base / p).lexically_normal().string();
}

std::string CanonicalKey(const std::string& file) {
  std::error_code ec;
  const fs::path c = fs::weakly_canonical(fs::path(file), ec);
  return ec ? fs::path(file).lexically_normal().string() : c.string();
}

// Adds a row whose file is resolved already; its bad-pixel mask, a path too, is resolved
// here against the manifest's folder `base` (as its file is, and as the README says).
bool AddRow(Manifest* m, ManifestRow row, const fs::path& base, const std::string& where,
            std::set<std::string>* seen, std::string* error) {
  if (row.file.empty()) {
    *error = where + ": no file";
    return false;
  }
  if (const GivenValue* mask = row.values.Find("bad_pixel_mask"); mask != nullptr && mask->text) {
    const std::string resolved = Resolve(base, *mask->text), source = mask->source;
    row.values.SetText("bad_pixel_mask", resolved, source);
  }
  if (!seen->insert(CanonicalKey(row.file)).second) {
    *error = where + ": file '" + Printable(row.file) + "' is listed twice";
    return false;
  }
  m->rows.push_back(std::move(row));
  return true;
}

bool LoadCsv(const std::string& text, const std::string& name, const fs::path& base, Manifest* m,
             std::string* error) {
  std::istringstream in(text);
  std::string line;
  std::vector<std::string> header;
  std::vector<std::string> fields;
  std::set<std::string> seen;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    // A spreadsheet saving "CSV UTF-8" starts the file with a byte-order mark, which is not
    // part of the first column's name.
    if (line_number == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) line.erase(0, 3);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const std::string trimmed = Trim(line);
    if (trimmed.empty() || trimmed[0] == '#') continue;
    const std::string where = "manifest " + name + " line " + std::to_string(line_number);
    if (!SplitCsv(line, &fields)) {
      *error = where + ": unterminated quote";
      return false;
    }
    if (header.empty()) {
      header = fields;
      std::set<std::string> columns;
      bool has_file = false;
      for (const std::string& c : header) {
        if (c != "file" && c != "setting" && !IsMetadataQuantity(c)) {
          *error = where + ": unknown column '" + Printable(c) +
                   "' (file, setting, or a quantity: gain_e_per_adu, read_noise_e, bias_adu, "
                   "bias_section, data_section, saturation_adu, pixel_um, wavelength_nm, "
                   "exptime_s, focus_position_um, spot_x_px, spot_y_px, search_region, hdu, "
                   "bad_pixel_mask)";
          return false;
        }
        if (!columns.insert(c).second) {
          *error = where + ": column '" + c + "' appears twice";
          return false;
        }
        has_file = has_file || c == "file";
      }
      if (!has_file) {
        *error = where + ": the header row has no 'file' column";
        return false;
      }
      continue;
    }
    if (fields.size() != header.size()) {
      *error = where + ": " + std::to_string(fields.size()) + " fields, the header has " +
               std::to_string(header.size());
      return false;
    }
    ManifestRow row;
    for (size_t i = 0; i < header.size(); ++i) {
      const std::string& column = header[i];
      const std::string& cell = fields[i];
      if (column == "file") {
        if (!cell.empty()) row.file = Resolve(base, cell);
      } else if (column == "setting") {
        row.setting = cell;
      } else if (!cell.empty()) {
        std::string why;
        if (!row.values.SetFromText(column, cell, where, &why)) {
          *error = where + ": " + why;
          return false;
        }
      }
    }
    if (!AddRow(m, std::move(row), base, where, &seen, error)) return false;
  }
  if (header.empty()) {
    *error = "manifest " + name + " is empty (it needs a header row with a 'file' column)";
    return false;
  }
  if (m->rows.empty()) {
    *error = "manifest " + name + " lists no files";
    return false;
  }
  return true;
}

// A JSON value of one quantity, for GivenMetadata::SetFromText.
bool JsonCell(const json& v, std::string* text) {
  if (v.is_number()) {
    std::ostringstream s;
    s.precision(17);
    s << v.get<double>();
    *text = s.str();
    return true;
  }
  if (v.is_string()) {
    *text = v.get<std::string>();
    return true;
  }
  return false;
}

// Reads the quantity keys of a JSON object into *values; other keys must be in `allowed`.
bool JsonQuantities(const json& object, const std::string& where,
                    const std::set<std::string>& allowed, GivenMetadata* values,
                    std::string* error) {
  for (auto it = object.begin(); it != object.end(); ++it) {
    if (allowed.count(it.key())) continue;
    if (!IsMetadataQuantity(it.key())) {
      *error = where + ": unknown key '" + Printable(it.key()) + "'";
      return false;
    }
    std::string text;
    if (!JsonCell(it.value(), &text)) {
      *error = where + ": '" + it.key() + "' must be a number or a string";
      return false;
    }
    std::string why;
    if (!values->SetFromText(it.key(), text, where, &why)) {
      *error = where + ": " + why;
      return false;
    }
  }
  return true;
}

bool LoadJson(const std::string& text, const std::string& name, const fs::path& base,
              Manifest* m, std::string* error) {
  const json j = json::parse(text, nullptr, false, true);
  if (j.is_discarded() || !j.is_object()) {
    *error = "manifest " + name + " is not a JSON object";
    return false;
  }
  std::set<std::string> seen;
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (it.key() != "exposures" && it.key() != "groups") {
      *error = "manifest " + name + ": unknown key '" + Printable(it.key()) +
               "' (exposures, or groups)";
      return false;
    }
  }
  if (j.contains("exposures") == j.contains("groups")) {
    *error = "manifest " + name + " needs one of 'exposures' (a list of rows) or 'groups'";
    return false;
  }
  if (j.contains("exposures")) {
    const json& list = j["exposures"];
    if (!list.is_array() || list.empty()) {
      *error = "manifest " + name + ": 'exposures' must be a non-empty list";
      return false;
    }
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string where = "manifest " + name + " entry " + std::to_string(i);
      const json& e = list[i];
      if (!e.is_object() || !e.contains("file") || !e["file"].is_string()) {
        *error = where + ": must be an object with \"file\": a string";
        return false;
      }
      ManifestRow row;
      row.file = Resolve(base, e["file"].get<std::string>());
      if (e.contains("setting")) {
        if (!e["setting"].is_string()) {
          *error = where + ": 'setting' must be a string";
          return false;
        }
        row.setting = e["setting"].get<std::string>();
      }
      if (!JsonQuantities(e, where, {"file", "setting"}, &row.values, error)) return false;
      if (!AddRow(m, std::move(row), base, where, &seen, error)) return false;
    }
    return true;
  }
  const json& groups = j["groups"];
  if (!groups.is_array() || groups.empty()) {
    *error = "manifest " + name + ": 'groups' must be a non-empty list";
    return false;
  }
  std::set<std::string> names;
  for (size_t i = 0; i < groups.size(); ++i) {
    const std::string where = "manifest " + name + " groups[" + std::to_string(i) + "]";
    const json& g = groups[i];
    if (!g.is_object() || !g.contains("name") || !g["name"].is_string()) {
      *error = where + ": must be an object with \"name\": a string";
      return false;
    }
    ManifestSetting setting;
    setting.name = g["name"].get<std::string>();
    if (!names.insert(setting.name).second) {
      *error = "manifest " + name + ": group name '" + Printable(setting.name) + "' appears twice";
      return false;
    }
    if (g.contains("nominal_peak_e")) {
      if (!g["nominal_peak_e"].is_number()) {
        *error = where + ": 'nominal_peak_e' must be a number";
        return false;
      }
      setting.nominal_peak_e = g["nominal_peak_e"].get<double>();
    }
    if (g.contains("focus_series")) {
      if (!g["focus_series"].is_boolean()) {
        *error = where + ": 'focus_series' must be true or false";
        return false;
      }
      setting.focus_series = g["focus_series"].get<bool>();
    }
    if (!g.contains("files") || !g["files"].is_array()) {
      *error = where + ": 'files' must be a list of file names";
      return false;
    }
    GivenMetadata shared;
    if (!JsonQuantities(g, where, {"name", "nominal_peak_e", "focus_series", "files"}, &shared,
                        error)) {
      return false;
    }
    if (const GivenValue* w = shared.Find("wavelength_nm");
        w == nullptr || !w->number || !(*w->number > 0)) {
      *error = where + ": 'wavelength_nm' must be a number > 0";
      return false;
    }
    for (const json& f : g["files"]) {
      if (!f.is_string()) {
        *error = where + ": 'files' must be a list of file names";
        return false;
      }
      ManifestRow row;
      row.file = Resolve(base, f.get<std::string>());
      row.setting = setting.name;
      row.values = shared;
      if (!AddRow(m, std::move(row), base, where, &seen, error)) return false;
    }
    m->settings.push_back(setting);
  }
  return true;
}

}  // namespace

bool IsManifestPath(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  return ext == ".csv" || ext == ".json" || ext == ".CSV" || ext == ".JSON";
}

const ManifestRow* Manifest::Find(const std::string& file) const {
  const std::string key = CanonicalKey(file);
  for (const ManifestRow& row : rows) {
    if (CanonicalKey(row.file) == key) return &row;
  }
  return nullptr;
}

bool LoadManifest(const std::string& path, Manifest* manifest, std::string* error) {
  *manifest = Manifest();
  manifest->path = path;
  std::string text;
  if (!ReadTextInput(path, "manifest", &text, error)) return false;
  const std::string name = fs::path(path).filename().string();
  const fs::path base = fs::path(path).parent_path();
  const std::string ext = fs::path(path).extension().string();
  if (ext == ".json" || ext == ".JSON") return LoadJson(text, name, base, manifest, error);
  if (ext == ".csv" || ext == ".CSV") return LoadCsv(text, name, base, manifest, error);
  *error = "manifest '" + path + "' must end in .csv or .json";
  return false;
}

bool ResolveInputFiles(const std::vector<std::string>& files, const Manifest* manifest,
                       const GivenMetadata& flags, const CalibrationOptions& config,
                       std::vector<InputFile>* inputs, std::string* error) {
  inputs->clear();
  std::vector<std::string> paths = files;
  if (paths.empty() && manifest != nullptr) {
    for (const ManifestRow& row : manifest->rows) paths.push_back(row.file);
  }
  if (paths.empty()) {
    *error = "no FITS files given (name them, or give --manifest)";
    return false;
  }
  for (const std::string& path : paths) {
    InputFile input;
    input.path = path;
    input.options = config;
    input.options.given = flags;
    if (manifest != nullptr) {
      const ManifestRow* row = manifest->Find(path);
      if (row == nullptr) {
        *error = "'" + path + "' is not in the manifest " + manifest->path +
                 " (name only files it lists, or none to take them all)";
        return false;
      }
      input.setting = row->setting;
      input.options.given.FillFrom(row->values);
    }
    input.options.given.FillFrom(config.given);
    inputs->push_back(std::move(input));
  }
  return true;
}

}  // namespace ccdpsf
