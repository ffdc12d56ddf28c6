// What produced an output folder: the software versions and the resolved options.
#ifndef CCDPSF_PROVENANCE_H_
#define CCDPSF_PROVENANCE_H_

#include <string>

#include "nlohmann/json.hpp"

namespace ccdpsf {

// ccdpsf, Ceres, Eigen, CFITSIO and compiler versions.
nlohmann::json SoftwareVersions();

// Writes DIR/run.json: {"command":, "options": {...}, "seed":, "software": {...}}.
// Every subcommand calls this for its output folder.
bool WriteRunRecord(const std::string& dir, const std::string& command,
                    const nlohmann::json& options, unsigned long long seed, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_PROVENANCE_H_
