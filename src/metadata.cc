// Per-exposure metadata: quantity names, the keyword map, given values and their resolution.
#include "ccdpsf/metadata.h"

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <sstream>

#include "ccdpsf/input_file.h"

#include "internal/text.h"

namespace ccdpsf {
namespace {

using internal::Trim;
using internal::ToUpper;
using internal::FormatNumber;
using internal::Printable;

using nlohmann::json;

struct QuantityInfo {
  const char* name;
  bool numeric;
  const char* keyword;  // default keyword, "" for none
  // A numeric quantity's range: [low, high], the low end excluded when `low_open` (a gain
  // of 0). Wide enough for any lab's values, narrow enough that arithmetic on them stays
  // finite (a bias of 1e300 ADU squared is not).
  double low = 0, high = 0;
  bool low_open = false;
};

// The table of metadata.h, in its order.
const std::vector<QuantityInfo>& Table() {
  static const std::vector<QuantityInfo> table = {
      {"gain_e_per_adu", true, "GAIN", 0, 1e6, true},
      {"read_noise_e", true, "RDNOISE", 0, 1e6},
      {"bias_adu", true, "BIASLVL", -1e12, 1e12},
      {"bias_section", false, "BIASSEC"},
      {"data_section", false, "DATASEC"},
      {"saturation_adu", true, "SATURATE", -1e12, 1e12},
      {"pixel_um", true, "PIXSIZE", 0, 1e4, true},
      {"wavelength_nm", true, "WAVELEN", 0, 1e6, true},
      {"exptime_s", true, "EXPTIME", 0, 1e8},
      {"focus_position_um", true, "FOCUSPOS", -1e9, 1e9},
      {"spot_x_px", true, "", -1e9, 1e9},
      {"spot_y_px", true, "", -1e9, 1e9},
      {"search_region", false, ""},
      {"hdu", false, ""},
      {"bad_pixel_mask", false, ""}};
  return table;
}

const QuantityInfo* Info(const std::string& name) {
  for (const QuantityInfo& q : Table()) {
    if (name == q.name) return &q;
  }
  return nullptr;
}



// A FITS keyword name: 1-8 characters of A-Z, 0-9, '-' and '_' (FITS standard 4.0, 4.1.2.1).
// HIERARCH names are longer; they are allowed as written.
bool ValidKeywordName(const std::string& name) {
  if (name.empty()) return false;
  if (name.rfind("HIERARCH ", 0) == 0) return name.size() > 9;
  if (name.size() > 8) return false;
  for (char c : name) {
    if (!(std::isupper(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) ||
          c == '-' || c == '_')) {
      return false;
    }
  }
  return true;
}

std::optional<double> ParseFinite(const std::string& text) {
  const std::string t = Trim(text);
  if (t.empty()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(t.c_str(), &end);
  if (end == t.c_str() || *end != '\0' || !std::isfinite(v)) return std::nullopt;
  return v;
}


// The keyword rule of `quantity` when the header holds that keyword, else nullptr.
const KeywordRule* MappedKeyword(const KeywordMap& keywords, const FitsHeader& header,
                                 const std::string& quantity) {
  const KeywordRule* rule = keywords.Find(quantity);
  if (rule == nullptr) return nullptr;
  for (const FitsKey& key : header) {
    if (ToUpper(key.name) == rule->keyword) return rule;
  }
  return nullptr;
}

}  // namespace

const std::vector<std::string>& MetadataQuantities() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> out;
    for (const QuantityInfo& q : Table()) out.push_back(q.name);
    return out;
  }();
  return names;
}

bool IsMetadataQuantity(const std::string& name) { return Info(name) != nullptr; }

bool IsNumericQuantity(const std::string& name) {
  const QuantityInfo* q = Info(name);
  return q != nullptr && q->numeric;
}

// ---------------------------------------------------------------------------------------
// KeywordMap

KeywordMap::KeywordMap() {
  for (const QuantityInfo& q : Table()) {
    if (q.keyword[0] != '\0') rules_[q.name] = {q.keyword, 1.0};
  }
}

const KeywordRule* KeywordMap::Find(const std::string& quantity) const {
  const auto it = rules_.find(quantity);
  return it == rules_.end() ? nullptr : &it->second;
}

bool KeywordMap::Set(const std::string& quantity, const KeywordRule& rule, std::string* error) {
  const QuantityInfo* q = Info(quantity);
  if (q == nullptr || quantity == "hdu" || quantity == "bad_pixel_mask") {
    *error = "keyword map: '" + Printable(quantity) +
             "' is not a quantity read from headers (gain_e_per_adu, read_noise_e, bias_adu, "
             "bias_section, data_section, saturation_adu, pixel_um, wavelength_nm, exptime_s, "
             "focus_position_um, spot_x_px, spot_y_px, search_region)";
    return false;
  }
  if (rule.keyword.empty() || rule.keyword == "-") {
    rules_.erase(quantity);
    return true;
  }
  const std::string name = ToUpper(rule.keyword);
  if (!ValidKeywordName(name)) {
    *error = "keyword map: '" + Printable(rule.keyword) + "' (for " + quantity +
             ") is not a FITS keyword name (1-8 of A-Z 0-9 - _)";
    return false;
  }
  if (!(std::isfinite(rule.scale) && rule.scale != 0.0)) {
    *error = "keyword map: the scale for " + quantity + " must be a finite non-zero number";
    return false;
  }
  if (!q->numeric && rule.scale != 1.0) {
    *error = "keyword map: " + quantity + " is a section, it takes no scale";
    return false;
  }
  rules_[quantity] = {name, rule.scale};
  return true;
}

bool KeywordMap::Overlay(const json& rules, std::string* error) {
  if (!rules.is_object()) {
    *error = "keyword map must be a JSON object {\"quantity\": \"KEYWORD\", ...}";
    return false;
  }
  for (auto it = rules.begin(); it != rules.end(); ++it) {
    KeywordRule rule;
    const json& v = it.value();
    if (v.is_string()) {
      rule.keyword = v.get<std::string>();
    } else if (v.is_object()) {
      for (auto f = v.begin(); f != v.end(); ++f) {
        if (f.key() != "keyword" && f.key() != "scale") {
          *error = "keyword map: unknown key '" + Printable(f.key()) + "' for " + it.key() +
                   " (keyword, scale)";
          return false;
        }
      }
      if (!v.contains("keyword") || !v["keyword"].is_string()) {
        *error = "keyword map: " + it.key() + " needs \"keyword\": a string";
        return false;
      }
      rule.keyword = v["keyword"].get<std::string>();
      if (v.contains("scale")) {
        if (!v["scale"].is_number()) {
          *error = "keyword map: the scale for " + it.key() + " must be a number";
          return false;
        }
        rule.scale = v["scale"].get<double>();
      }
    } else if (v.is_null()) {
      rule.keyword = "";
    } else {
      *error = "keyword map: " + it.key() + " must be a keyword name or {\"keyword\":, \"scale\":}";
      return false;
    }
    if (!Set(it.key(), rule, error)) return false;
  }
  return true;
}

bool KeywordMap::OverlayText(const std::string& text, std::string* error) {
  std::stringstream s(text);
  std::string item;
  while (std::getline(s, item, ',')) {
    item = Trim(item);
    if (item.empty()) continue;
    const size_t eq = item.find('=');
    if (eq == std::string::npos) {
      *error = "keyword map: '" + Printable(item) + "' is not quantity=KEYWORD";
      return false;
    }
    KeywordRule rule;
    const std::string quantity = Trim(item.substr(0, eq));
    std::string keyword = Trim(item.substr(eq + 1));
    const size_t star = keyword.find('*');
    if (star != std::string::npos) {
      const std::optional<double> scale = ParseFinite(keyword.substr(star + 1));
      if (!scale) {
        *error = "keyword map: '" + Printable(item) + "' has a malformed scale";
        return false;
      }
      rule.scale = *scale;
      keyword = Trim(keyword.substr(0, star));
    }
    rule.keyword = keyword;
    if (!Set(quantity, rule, error)) return false;
  }
  return true;
}

bool KeywordMap::OverlayFileOrText(const std::string& text, std::string* error) {
  // A file of that name (whatever its type: a FIFO is refused, not taken for map text).
  std::error_code ec;
  if (std::filesystem::exists(text, ec)) {
    std::string content;
    if (!ReadTextInput(text, "keyword map", &content, error)) return false;
    const json j = json::parse(content, nullptr, false, true);
    if (j.is_discarded()) {
      *error = "keyword map '" + text + "' is not valid JSON";
      return false;
    }
    if (!Overlay(j, error)) {
      *error = "'" + text + "': " + *error;
      return false;
    }
    return true;
  }
  return OverlayText(text, error);
}

json KeywordMap::ToJson() const {
  json out = json::object();
  for (const auto& [quantity, rule] : rules_) {
    if (rule.scale == 1.0) {
      out[quantity] = rule.keyword;
    } else {
      out[quantity] = {{"keyword", rule.keyword}, {"scale", rule.scale}};
    }
  }
  return out;
}

// ---------------------------------------------------------------------------------------
// GivenMetadata

bool GivenMetadata::Has(const std::string& quantity) const {
  const GivenValue* v = Find(quantity);
  return v != nullptr && v->has();
}

const GivenValue* GivenMetadata::Find(const std::string& quantity) const {
  const auto it = values_.find(quantity);
  return it == values_.end() ? nullptr : &it->second;
}

void GivenMetadata::SetNumber(const std::string& quantity, double value,
                              const std::string& source) {
  GivenValue& v = values_[quantity];
  v.number = value;
  v.text.reset();
  v.source = source;
}

void GivenMetadata::SetText(const std::string& quantity, const std::string& value,
                            const std::string& source) {
  GivenValue& v = values_[quantity];
  v.text = value;
  v.number.reset();
  v.source = source;
}

void GivenMetadata::FillFrom(const GivenMetadata& lower) {
  for (const auto& [quantity, value] : lower.values_) {
    if (!Has(quantity) && value.has()) values_[quantity] = value;
  }
}

bool CheckQuantityValue(const std::string& quantity, double value, std::string* error) {
  const QuantityInfo* q = Info(quantity);
  if (q == nullptr || !q->numeric) return true;
  const bool above_low = q->low_open ? value > q->low : value >= q->low;
  if (std::isfinite(value) && above_low && value <= q->high) return true;
  const std::string got = ", got " + FormatNumber(value);
  if (q->low != 0.0) {
    *error = quantity + " must be finite and within [" + FormatNumber(q->low) + ", " +
             FormatNumber(q->high) + "]" + got;
  } else if (!std::isfinite(value) || !above_low) {
    *error = quantity + " must be " + (q->low_open ? "positive" : "non-negative") +
             " and finite" + got;
  } else {
    *error = quantity + " must be at most " + FormatNumber(q->high) + got;
  }
  return false;
}

bool GivenMetadata::SetFromText(const std::string& quantity, const std::string& text,
                                const std::string& source, std::string* error) {
  const QuantityInfo* q = Info(quantity);
  if (q == nullptr) {
    *error = "unknown quantity '" + Printable(quantity) + "'";
    return false;
  }
  const std::string t = Trim(text);
  if (q->numeric) {
    const std::optional<double> v = ParseFinite(t);
    if (!v) {
      *error = quantity + " must be a finite number, got '" + Printable(t) + "'";
      return false;
    }
    SetNumber(quantity, *v, source);
  } else {
    if (t.empty()) {
      *error = quantity + " must not be empty";
      return false;
    }
    SetText(quantity, t, source);
  }
  return true;
}

json MetadataRecordJson(const MetadataRecord& record) {
  json out = json::object();
  for (const std::string& name : MetadataQuantities()) {
    const auto it = record.find(name);
    if (it == record.end()) continue;
    const MetadataEntry& e = it->second;
    json value = nullptr;
    if (!e.text.empty()) {
      value = e.text;
    } else if (std::isfinite(e.number)) {
      value = e.number;
    }
    out[name] = {{"value", value}, {"source", e.source}};
  }
  return out;
}

namespace {

// Whether two cards hold the same value: as numbers when both are (2 and 2.0 agree).
bool SameValue(const FitsKey& a, const FitsKey& b) {
  const std::optional<double> x = FindNumber({a}, a.name), y = FindNumber({b}, b.name);
  if (x && y) return *x == *y;
  return a.value == b.value;
}

// A header that gives `keyword` twice with different values contradicts itself: which card
// a reader believes is arbitrary (CFITSIO and this reader take the first). The message, or
// "" if every card of that name agrees.
std::string Contradiction(const FitsHeader& header, const std::string& keyword,
                          const std::string& quantity) {
  const std::string wanted = ToUpper(keyword);
  const FitsKey* first = nullptr;
  for (const FitsKey& key : header) {
    if (ToUpper(key.name) != wanted) continue;
    if (first == nullptr) {
      first = &key;
    } else if (!SameValue(key, *first)) {
      return "keyword " + keyword + " (" + quantity +
             ") is given twice with different values: the header contradicts itself";
    }
  }
  return "";
}

}  // namespace

bool ResolveNumber(const GivenMetadata& given, const KeywordMap& keywords,
                   const FitsHeader& header, const std::string& quantity,
                   std::optional<double>* value, std::string* source, std::string* error) {
  value->reset();
  if (const GivenValue* v = given.Find(quantity); v != nullptr && v->number) {
    *value = *v->number;
    *source = v->source.empty() ? "option" : v->source;
    return true;
  }
  const KeywordRule* rule = MappedKeyword(keywords, header, quantity);
  if (rule == nullptr) return true;
  if (const std::string c = Contradiction(header, rule->keyword, quantity); !c.empty()) {
    *error = c;
    return false;
  }
  const std::optional<double> number = FindNumber(header, rule->keyword);
  if (!number || !std::isfinite(*number)) {
    *error = "keyword " + rule->keyword + " (" + quantity + ") is not a finite number";
    return false;
  }
  *value = *number * rule->scale;
  *source = "keyword " + rule->keyword;
  if (rule->scale != 1.0) {
    std::ostringstream s;
    s << " x " << rule->scale;
    *source += s.str();
  }
  return true;
}

bool ResolveText(const GivenMetadata& given, const KeywordMap& keywords, const FitsHeader& header,
                 const std::string& quantity, std::optional<std::string>* value,
                 std::string* source, std::string* error) {
  value->reset();
  if (const GivenValue* v = given.Find(quantity); v != nullptr && v->text) {
    *value = *v->text;
    *source = v->source.empty() ? "option" : v->source;
    return true;
  }
  const KeywordRule* rule = MappedKeyword(keywords, header, quantity);
  if (rule == nullptr) return true;
  if (const std::string c = Contradiction(header, rule->keyword, quantity); !c.empty()) {
    *error = c;
    return false;
  }
  const std::optional<std::string> text = FindString(header, rule->keyword);
  if (!text) {
    *error = "keyword " + rule->keyword + " (" + quantity + ") is not a string";
    return false;
  }
  *value = *text;
  *source = "keyword " + rule->keyword;
  return true;
}

}  // namespace ccdpsf
