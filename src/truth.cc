#include "ccdpsf/truth.h"

#include <cmath>
#include <filesystem>
#include <limits>
#include <map>

#include "ccdpsf/input_file.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

bool ReadTruth(const std::string& path, std::optional<TruthFile>* truth, std::string* error) {
  std::string text;
  if (!ReadTextInput(path, "the truth file", &text, error)) return false;
  json document = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (!document.is_object()) {
    *error = "the truth file '" + path + "' is not a JSON object";
    return false;
  }
  *truth = TruthFile{path, std::move(document)};
  return true;
}

// The number at `j[key]`, NaN when absent or not a number.
double NumberAt(const json& j, const std::string& key) {
  if (!j.is_object()) return kNaN;
  auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : kNaN;
}

std::string BaseName(const std::string& path) { return fs::path(path).filename().string(); }

// Parses "x_px_3" as ("x_px", 3); index -1 when there is no "_K" suffix.
std::pair<std::string, int> SplitIndexed(const std::string& name) {
  const size_t dot = name.rfind('_');
  if (dot == std::string::npos || dot + 1 >= name.size()) return {name, -1};
  int index = 0;
  for (size_t i = dot + 1; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return {name, -1};
    index = index * 10 + (name[i] - '0');
  }
  return {name.substr(0, dot), index};
}

}  // namespace

bool FindTruth(const std::string& given, const std::vector<std::string>& inputs,
               std::optional<TruthFile>* truth, std::string* error) {
  truth->reset();
  if (!given.empty()) return ReadTruth(given, truth, error);
  std::optional<fs::path> folder;
  for (const std::string& input : inputs) {
    std::error_code ec;
    const fs::path p(input);
    const fs::path here = fs::is_directory(p, ec) ? p : p.parent_path();
    const fs::path canonical = fs::weakly_canonical(here.empty() ? fs::path(".") : here, ec);
    if (ec) return true;
    if (folder && *folder != canonical) return true;  // several folders: no single truth
    folder = canonical;
  }
  if (!folder) return true;
  const fs::path candidate = *folder / "truth.json";
  std::error_code ec;
  if (!fs::is_regular_file(candidate, ec)) return true;
  return ReadTruth(candidate.string(), truth, error);
}

std::vector<double> FitParameterTruths(const json& truth, const std::vector<std::string>& names,
                                       const std::vector<std::string>& sources, bool flux_shared) {
  std::vector<double> out(names.size(), kNaN);
  const auto parameters = truth.find("parameters");
  if (parameters == truth.end() || !parameters->is_object()) return out;
  const bool effects = truth.contains("effects");

  // The truth's exposure for each fitted exposure (nullptr: none with that file name).
  std::map<std::string, const json*> by_file;
  if (truth.contains("exposures") && truth["exposures"].is_array()) {
    for (const json& e : truth["exposures"]) {
      if (e.is_object() && e.contains("file") && e["file"].is_string()) {
        by_file[BaseName(e["file"].get<std::string>())] = &e;
      }
    }
  }
  std::vector<const json*> matched;
  for (const std::string& source : sources) {
    auto it = by_file.find(BaseName(source));
    matched.push_back(it == by_file.end() ? nullptr : it->second);
  }

  for (size_t i = 0; i < names.size(); ++i) {
    const std::string& name = names[i];
    const auto [base, index] = SplitIndexed(name);
    if (name == "flux_e" || name == "peak_e") {
      if (matched.empty() || matched[0] == nullptr) continue;
      const double first = NumberAt(*matched[0], name);
      bool one_value = std::isfinite(first);
      if (flux_shared) {
        for (const json* e : matched) {
          one_value = one_value && e != nullptr && NumberAt(*e, name) == first;
        }
      }
      if (one_value) out[i] = first;
    } else if ((base == "x_px" || base == "y_px") && index >= 0) {
      if (static_cast<size_t>(index) < matched.size() && matched[index] != nullptr) {
        out[i] = NumberAt(*matched[index], base);
      }
    } else if (base == "flux_ratio" && index >= 0) {
      if (static_cast<size_t>(index) >= matched.size() || matched[0] == nullptr ||
          matched[index] == nullptr) {
        continue;
      }
      for (const char* key : {"flux_e", "peak_e"}) {
        const double f0 = NumberAt(*matched[0], key), fk = NumberAt(*matched[index], key);
        if (std::isfinite(f0) && std::isfinite(fk) && f0 > 0) out[i] = fk / f0;
      }
    } else if (index < 0) {
      // A shared parameter by its own name. Injected effects change the kernel the fit sees
      // (brighter-fatter, jitter, a defocus offset), so the kernel widths are not its truth.
      const bool kernel = name == "ccd_sigma_x_px" || name == "ccd_sigma_y_px" ||
                          name == "defocus_sigma_px" || name == "defocus_radius_px";
      if (kernel && effects) continue;
      out[i] = NumberAt(*parameters, name);
    }
  }
  return out;
}

}  // namespace ccdpsf
