#include "ccdpsf/trend/group_store.h"

#include <sys/stat.h>

#include <cmath>
#include <cstdio>
#include <limits>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/input_file.h"
#include "internal/fnv1a.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {
namespace {

using nlohmann::json;

// 5: an intensity series' draws hold the intrinsic kernel too (SettingIntrinsicDrawKey), and
// its affected kernel with boundary_shift: a store of an earlier format is refitted.
constexpr int kFormat = 5;

uint64_t Hash(const std::string& text) {
  internal::Fnv1a h;
  h.Add(text.data(), text.size());
  return h.value();
}

// JSON has no NaN or infinity: those go as strings; every other double as a number, which
// nlohmann writes in the shortest form that reads back to the same double.
json Num(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return v;
}

bool ReadNum(const json& j, double* v) {
  if (j.is_number()) {
    *v = j.get<double>();
    return true;
  }
  if (!j.is_string()) return false;
  const std::string s = j.get<std::string>();
  if (s == "nan") *v = std::numeric_limits<double>::quiet_NaN();
  else if (s == "inf") *v = std::numeric_limits<double>::infinity();
  else if (s == "-inf") *v = -std::numeric_limits<double>::infinity();
  else return false;
  return true;
}

json SummaryToJson(const fit::Summary& s) {
  return json::array({Num(s.map), Num(s.laplace_sd), Num(s.median), Num(s.lo68), Num(s.hi68),
                      Num(s.lo997), Num(s.hi997)});
}

bool SummaryFromJson(const json& j, fit::Summary* s) {
  return j.is_array() && j.size() == 7 && ReadNum(j[0], &s->map) &&
         ReadNum(j[1], &s->laplace_sd) && ReadNum(j[2], &s->median) && ReadNum(j[3], &s->lo68) &&
         ReadNum(j[4], &s->hi68) && ReadNum(j[5], &s->lo997) && ReadNum(j[6], &s->hi997);
}

}  // namespace

std::string GroupStoreName(const std::string& run_signature, const CampaignGroup& group,
                           int index) {
  json key = {{"run", run_signature}, {"group", group.name}, {"index", index}};
  // An anchored fit depends on its defocus box, which depends on the series' fit.
  if (group.defocus_anchor) {
    const DefocusAnchor& a = *group.defocus_anchor;
    key["anchor"] = {a.series, a.focus_position_um, a.lower_px, a.upper_px};
  }
  for (const std::string& file : group.files) {
    struct stat st {};
    const bool ok = ::stat(file.c_str(), &st) == 0;
    key["files"].push_back({file, ok ? static_cast<long long>(st.st_size) : -1,
                            ok ? static_cast<long long>(st.st_mtim.tv_sec) : -1,
                            ok ? static_cast<long long>(st.st_mtim.tv_nsec) : -1});
  }
  char name[32];
  std::snprintf(name, sizeof(name), "%016llx.json",
                static_cast<unsigned long long>(Hash(key.dump())));
  return name;
}

nlohmann::json GroupResultJson(const GroupResult& r) {
  json findings = json::array();
  for (const Finding& f : r.quality.findings) {
    findings.push_back({f.code, static_cast<int>(f.severity), f.message, f.exposure});
  }
  json summaries = json::object();
  for (const auto& [name, s] : r.summaries) summaries[name] = SummaryToJson(s);
  json draws = json::object();
  for (const auto& [name, values] : r.draws) {
    json a = json::array();
    for (double v : values) a.push_back(Num(v));
    draws[name] = a;
  }
  json j = {{"format", kFormat},
            {"group", r.group.name},
            {"ok", r.ok},
            {"failure", r.failure},
            {"warnings", r.warnings},
            {"notes", r.notes},
            {"exposures", r.exposures},
            {"mcmc_ran", r.mcmc_ran},
            {"converged", r.converged},
            {"chi2_per_dof", Num(r.chi2_per_dof)},
            {"seconds", Num(r.seconds)},
            {"report_dir", r.report_dir},
            {"findings", findings},
            {"peak_e", SummaryToJson(r.peak_e)},
            {"summaries", summaries},
            {"draws", draws},
            {"unbounded_below", r.unbounded_below},
            {"ccd_split_unidentified", r.ccd_split_unidentified}};
  return j;
}

bool SaveGroupResult(const std::string& path, const GroupResult& r, std::string* error) {
  return WriteTextFileAtomically(path, GroupResultJson(r).dump() + "\n", error);
}

bool LoadGroupResult(const std::string& path, GroupResult* result) {
  std::string text, error;
  if (!ReadTextInput(path, "group result", &text, &error)) return false;
  return GroupResultFromJson(json::parse(text, nullptr, /*allow_exceptions=*/false), result);
}

bool GroupResultFromJson(const nlohmann::json& j, GroupResult* result) {
  // Checked by type first: json::value() throws when the key is there with another type
  // (a stored file is input, however it was damaged).
  if (!j.is_object()) return false;
  const auto format = j.find("format"), group = j.find("group");
  if (format == j.end() || !format->is_number_integer() || format->get<int64_t>() != kFormat ||
      group == j.end() || !group->is_string() ||
      group->get<std::string>() != result->group.name) {
    return false;
  }
  GroupResult r;
  r.group = result->group;
  try {
    r.ok = j.at("ok").get<bool>();
    r.failure = j.at("failure").get<std::string>();
    r.warnings = j.at("warnings").get<std::vector<std::string>>();
    r.notes = j.at("notes").get<std::vector<std::string>>();
    r.exposures = j.at("exposures").get<int>();
    r.mcmc_ran = j.at("mcmc_ran").get<bool>();
    r.converged = j.at("converged").get<bool>();
    r.report_dir = j.at("report_dir").get<std::string>();
    r.unbounded_below = j.at("unbounded_below").get<std::vector<std::string>>();
    r.ccd_split_unidentified = j.at("ccd_split_unidentified").get<bool>();
    if (!ReadNum(j.at("chi2_per_dof"), &r.chi2_per_dof) || !ReadNum(j.at("seconds"), &r.seconds) ||
        !SummaryFromJson(j.at("peak_e"), &r.peak_e)) {
      return false;
    }
    for (const json& f : j.at("findings")) {
      const int severity = f.at(1).get<int>();
      if (severity < 0 || severity > static_cast<int>(Severity::kInvalid)) return false;
      r.quality.findings.push_back({f.at(0).get<std::string>(), static_cast<Severity>(severity),
                                    f.at(2).get<std::string>(), f.at(3).get<int>()});
    }
    for (const auto& [name, s] : j.at("summaries").items()) {
      if (!SummaryFromJson(s, &r.summaries[name])) return false;
    }
    for (const auto& [name, values] : j.at("draws").items()) {
      std::vector<double>& d = r.draws[name];
      for (const json& v : values) {
        d.emplace_back();
        if (!ReadNum(v, &d.back())) return false;
      }
    }
  } catch (const json::exception&) {
    return false;
  }
  *result = std::move(r);
  return true;
}

}  // namespace ccdpsf::trend
