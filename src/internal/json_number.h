// A double as a JSON value for the result files: NaN and infinities, which JSON cannot hold,
// become null.
#ifndef CCDPSF_INTERNAL_JSON_NUMBER_H_
#define CCDPSF_INTERNAL_JSON_NUMBER_H_

#include <cmath>

#include "nlohmann/json.hpp"

namespace ccdpsf::internal {

inline nlohmann::json JsonNumber(double value) {
  return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json();
}

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_JSON_NUMBER_H_
