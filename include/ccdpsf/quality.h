// The verdict on a measurement: "ok", "suspect" or "invalid", with the reasons.
//
// Every stage that can see something wrong adds a finding: calibration (a saturated or
// clipped core, a spot that is not compact, a source beside the spot, a hot column, a peak
// near the ADC's full scale), the checks across the exposures of a set (compression of the
// peak, duplicates) and the fit (chi2/dof outside its expected range, parameters at prior
// bounds, a width that is only an upper limit, masked core pixels, an unconverged chain).
// A finding is a note (worth knowing, the measurement stands), suspect (the numbers may be
// wrong; look before using them) or invalid (the numbers do not measure the PSF). The
// verdict is the most severe finding; "ok" when there is none above a note.
#ifndef CCDPSF_QUALITY_H_
#define CCDPSF_QUALITY_H_

#include <string>
#include <vector>

#include "nlohmann/json.hpp"

namespace ccdpsf {

enum class Severity { kNote = 0, kSuspect = 1, kInvalid = 2 };

struct Finding {
  std::string code;  // stable identifier for scripts, e.g. "saturated_core"
  Severity severity = Severity::kNote;
  std::string message;  // one line for people
  int exposure = -1;    // the exposure it concerns in a set, -1 for the whole fit
};

struct Quality {
  std::vector<Finding> findings;

  void Add(const std::string& code, Severity severity, const std::string& message,
           int exposure = -1);
  // "ok", "suspect" or "invalid".
  std::string Verdict() const;
  Severity Worst() const;
  bool Has(const std::string& code) const;
  // {"verdict": ..., "reasons": [{"code", "severity", "message", "exposure"}...] (suspect
  // and invalid ones), "notes": [...]}
  nlohmann::json ToJson() const;
  // "suspect: reason; reason" or "ok" (notes left out), for the terminal.
  std::string OneLine() const;
};

std::string ToString(Severity severity);

}  // namespace ccdpsf

#endif  // CCDPSF_QUALITY_H_
