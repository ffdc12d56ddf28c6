#include "ccdpsf/ptc_prior.h"

#include <cmath>
#include <cstdio>

#include "ccdpsf/input_file.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {
namespace {

using nlohmann::json;

// The shortest text of a JSON value for a message (null, a number, "...").
std::string Shown(const json& value) {
  const std::string text = value.dump();
  return text.size() <= 40 ? text : text.substr(0, 37) + "...";
}

}  // namespace

bool ParsePtcPrior(const std::string& text, const std::string& path, fit::GaussianPrior* prior,
                   std::string* error) {
  const std::string file = "'" + path + "'";
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) {
    *error = file + " is not a ptc.json (`ccdpsf ptc` writes one): it is not valid JSON";
    return false;
  }
  auto not_ptc = [&](const std::string& what) {
    *error = file + " is not a ptc.json (`ccdpsf ptc` writes one): " + what;
    return false;
  };
  if (!j.is_object() || !j.contains("a") || !j["a"].is_object()) return not_ptc("no \"a\" object");
  if (!j.contains("a_covariance") || !j["a_covariance"].is_object()) {
    return not_ptc("no \"a_covariance\" object");
  }
  const json& cov = j["a_covariance"];
  if (!cov.contains("names") || !cov["names"].is_array() || !cov.contains("matrix") ||
      !cov["matrix"].is_array()) {
    return not_ptc("\"a_covariance\" needs \"names\" and \"matrix\"");
  }
  const json& names = cov["names"];
  const json& matrix = cov["matrix"];
  const size_t lags = names.size();
  if (matrix.size() != lags) return not_ptc("\"a_covariance.matrix\" is not names x names");
  for (const json& row : matrix) {
    if (!row.is_array() || row.size() != lags) {
      return not_ptc("\"a_covariance.matrix\" is not names x names");
    }
  }
  fit::GaussianPrior out;
  out.source = path;
  std::vector<size_t> at;  // each lag's row in a_covariance
  for (const char* lag : kPtcPriorLags) {
    const std::string a = std::string("a.") + lag;
    if (!j["a"].contains(lag) || !j["a"][lag].is_object()) return not_ptc("no \"" + a + "\"");
    const json& entry = j["a"][lag];
    if (!entry.contains("median") || !entry.contains("sd")) {
      return not_ptc("\"" + a + "\" needs \"median\" and \"sd\"");
    }
    const json& median = entry["median"];
    const json& sd = entry["sd"];
    if (!median.is_number() || !std::isfinite(median.get<double>())) {
      *error = file + ": " + a + ".median must be a finite number [1/e-] (got " + Shown(median) +
               ")";
      return false;
    }
    if (!sd.is_number() || !(sd.get<double>() > 0.0) || !std::isfinite(sd.get<double>())) {
      *error = file + ": " + a + ".sd must be a positive finite number [1/e-] (got " +
               Shown(sd) + "): the flats did not measure " + lag;
      return false;
    }
    size_t row = lags;
    for (size_t i = 0; i < lags; ++i) {
      if (names[i].is_string() && names[i].get<std::string>() == lag) row = i;
    }
    if (row == lags) return not_ptc("\"a_covariance.names\" has no \"" + std::string(lag) + "\"");
    at.push_back(row);
    out.names.push_back(std::string("boundary_shift.") + lag);
    out.mean.push_back(median.get<double>());
  }
  const size_t n = at.size();
  for (size_t r = 0; r < n; ++r) {
    for (size_t c = 0; c < n; ++c) {
      const json& v = matrix[at[r]][at[c]];
      if (!v.is_number() || !std::isfinite(v.get<double>())) {
        *error = file + ": a_covariance between " + std::string(kPtcPriorLags[r]) + " and " +
                 kPtcPriorLags[c] + " must be a finite number (got " + Shown(v) + ")";
        return false;
      }
      out.covariance.push_back(v.get<double>());
    }
  }
  // The sds and the matrix are one fit's (ptc.cc): a file where they disagree was edited, and
  // which of the two was meant cannot be told.
  for (size_t r = 0; r < n; ++r) {
    const double sd = j["a"][kPtcPriorLags[r]]["sd"].get<double>();
    const double var = out.covariance[r * n + r];
    if (!(std::fabs(var - sd * sd) <= 1e-6 * sd * sd)) {
      char text[200];
      std::snprintf(text, sizeof text,
                    ": a_covariance's variance of %s (%.6g) is not a.%s.sd squared (%.6g)",
                    kPtcPriorLags[r], var, kPtcPriorLags[r], sd * sd);
      *error = file + text;
      return false;
    }
  }
  std::string why;
  if (!fit::CheckGaussianPrior(out, &why)) {
    *error = file + ": the covariance of a_10, a_01, a_11 (a_covariance) is not positive "
                    "definite, or not symmetric: not a Gaussian prior";
    return false;
  }
  *prior = out;
  return true;
}

bool ReadPtcPrior(const std::string& path, fit::GaussianPrior* prior, std::string* error) {
  std::string text;
  if (!ReadTextInput(path, "--ptc file", &text, error)) return false;
  return ParsePtcPrior(text, path, prior, error);
}

}  // namespace ccdpsf
