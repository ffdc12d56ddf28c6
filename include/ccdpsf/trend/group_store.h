// Finished groups of a trend run kept on disk, so that a killed run redoes only the groups
// it had not finished (`ccdpsf trend --resume`).
//
// Each finished group's result is written, atomically, to <dir>/<key>.json as soon as the
// group is done. The key is a hash of what decides the result: the run's signature (its
// options, given by the caller), the group's name and index (its MCMC seed) and each file's
// path, size and modification time. A changed file, option or seed gives another key, so a
// stale result is never reused. Numbers are stored as JSON numbers that read back to the
// same doubles (NaN and infinities as strings), so a resumed trend equals an uninterrupted one.
#ifndef CCDPSF_TREND_GROUP_STORE_H_
#define CCDPSF_TREND_GROUP_STORE_H_

#include <string>

#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::trend {

// The file name (hex hash + ".json") under which group `index` of a run is kept.
std::string GroupStoreName(const std::string& run_signature, const CampaignGroup& group,
                           int index);

// Everything of `result` but its group, as stored; and back into *result, whose `group` the
// caller has set (false, result untouched, for another format or group). Also how `grid`'s
// processes send their results to the first.
nlohmann::json GroupResultJson(const GroupResult& result);
bool GroupResultFromJson(const nlohmann::json& j, GroupResult* result);

// Writes everything of `result` but its group (which the caller has). False with a reason.
bool SaveGroupResult(const std::string& path, const GroupResult& result, std::string* error);

// Reads a result written by SaveGroupResult into *result, whose `group` the caller has set.
// False (result untouched) if the file is missing, incomplete or of another format.
bool LoadGroupResult(const std::string& path, GroupResult* result);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_GROUP_STORE_H_
