// Verdicts (quality.h).
#include "ccdpsf/quality.h"

#include <algorithm>

namespace ccdpsf {

std::string ToString(Severity severity) {
  switch (severity) {
    case Severity::kNote:
      return "note";
    case Severity::kSuspect:
      return "suspect";
    case Severity::kInvalid:
      return "invalid";
  }
  return "invalid";
}

void Quality::Add(const std::string& code, Severity severity, const std::string& message,
                  int exposure) {
  // The same finding reported twice (e.g. by two exposures' identical checks) stays one.
  for (const Finding& f : findings) {
    if (f.code == code && f.message == message && f.exposure == exposure) return;
  }
  findings.push_back({code, severity, message, exposure});
}

Severity Quality::Worst() const {
  Severity worst = Severity::kNote;
  for (const Finding& f : findings) worst = std::max(worst, f.severity);
  return worst;
}

std::string Quality::Verdict() const {
  const Severity worst = Worst();
  return worst == Severity::kNote ? "ok" : ToString(worst);
}

bool Quality::Has(const std::string& code) const {
  for (const Finding& f : findings) {
    if (f.code == code) return true;
  }
  return false;
}

nlohmann::json Quality::ToJson() const {
  nlohmann::json reasons = nlohmann::json::array(), notes = nlohmann::json::array();
  // Most severe first, then in the order found.
  std::vector<Finding> sorted = findings;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const Finding& a, const Finding& b) { return a.severity > b.severity; });
  for (const Finding& f : sorted) {
    nlohmann::json j = {{"code", f.code}, {"severity", ToString(f.severity)}, {"message", f.message}};
    if (f.exposure >= 0) j["exposure"] = f.exposure;
    (f.severity == Severity::kNote ? notes : reasons).push_back(j);
  }
  return {{"verdict", Verdict()}, {"reasons", reasons}, {"notes", notes}};
}

std::string Quality::OneLine() const {
  std::string out = Verdict();
  std::vector<Finding> sorted = findings;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const Finding& a, const Finding& b) { return a.severity > b.severity; });
  bool first = true;
  for (const Finding& f : sorted) {
    if (f.severity == Severity::kNote) continue;
    out += first ? ": " : "; ";
    out += f.message;
    first = false;
  }
  return out;
}

}  // namespace ccdpsf
