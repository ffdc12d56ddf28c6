// Strict reading of JSON configuration objects: unknown keys and wrong types are errors
// that name the offending key path, so a user's typo never falls back to a default.
#ifndef CCDPSF_INTERNAL_JSON_READER_H_
#define CCDPSF_INTERNAL_JSON_READER_H_

#include <cmath>
#include <set>
#include <string>

#include "nlohmann/json.hpp"

namespace ccdpsf::internal {

class JsonReader {
 public:
  // `path` names the object in messages, e.g. "detector" or "exposures[2]".
  JsonReader(const nlohmann::json& object, std::string path, std::string* error)
      : object_(object), path_(std::move(path)), error_(error) {
    if (!object_.is_object()) Fail("must be a JSON object");
  }

  bool ok() const { return ok_; }
  bool Has(const std::string& key) const { return ok_ && object_.contains(key); }
  const nlohmann::json& Get(const std::string& key) {
    seen_.insert(key);
    return object_.at(key);
  }
  std::string Path(const std::string& key) const {
    return path_.empty() ? key : path_ + "." + key;
  }

  // Reads a finite number if present (required: error if absent).
  void Number(const std::string& key, double* out, bool required = false) {
    if (!ok_) return;
    seen_.insert(key);
    if (!object_.contains(key)) {
      if (required) Fail("'" + Path(key) + "' is required");
      return;
    }
    const nlohmann::json& v = object_.at(key);
    if (!v.is_number() || !std::isfinite(v.get<double>())) {
      Fail("'" + Path(key) + "' must be a finite number");
      return;
    }
    *out = v.get<double>();
  }

  void Integer(const std::string& key, long long* out, bool required = false) {
    if (!ok_) return;
    seen_.insert(key);
    if (!object_.contains(key)) {
      if (required) Fail("'" + Path(key) + "' is required");
      return;
    }
    const nlohmann::json& v = object_.at(key);
    if (!v.is_number_integer()) {
      Fail("'" + Path(key) + "' must be an integer");
      return;
    }
    *out = v.get<long long>();
  }

  void String(const std::string& key, std::string* out, bool required = false) {
    if (!ok_) return;
    seen_.insert(key);
    if (!object_.contains(key)) {
      if (required) Fail("'" + Path(key) + "' is required");
      return;
    }
    const nlohmann::json& v = object_.at(key);
    if (!v.is_string()) {
      Fail("'" + Path(key) + "' must be a string");
      return;
    }
    *out = v.get<std::string>();
  }

  // Call last: fails on any key that was never asked for.
  void RejectUnknownKeys() {
    if (!ok_) return;
    for (auto it = object_.begin(); it != object_.end(); ++it) {
      if (!seen_.count(it.key())) {
        Fail("unknown key '" + Path(it.key()) + "'");
        return;
      }
    }
  }

  void Fail(const std::string& message) {
    if (!ok_) return;
    ok_ = false;
    *error_ = message;
  }

 private:
  const nlohmann::json& object_;
  std::string path_;
  std::string* error_;
  std::set<std::string> seen_;
  bool ok_ = true;
};

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_JSON_READER_H_
