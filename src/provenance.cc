#include "ccdpsf/provenance.h"

#include <Eigen/Core>

#include "ccdpsf/atomic_file.h"
#include "ceres/version.h"
#include "fitsio.h"

#ifndef CCDPSF_VERSION
#define CCDPSF_VERSION "unknown"
#endif

namespace ccdpsf {

nlohmann::json SoftwareVersions() {
  float cfitsio_version = 0.0f;
  fits_get_version(&cfitsio_version);
  char cfitsio[32];
  std::snprintf(cfitsio, sizeof(cfitsio), "%.3f", cfitsio_version);
  return {{"ccdpsf", CCDPSF_VERSION},
          {"ceres", CERES_VERSION_STRING},
          {"eigen", std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) +
                        "." + std::to_string(EIGEN_MINOR_VERSION)},
          {"cfitsio", cfitsio},
          {"compiler", __VERSION__}};
}

bool WriteRunRecord(const std::string& dir, const std::string& command,
                    const nlohmann::json& options, unsigned long long seed, std::string* error) {
  nlohmann::json record = {{"command", command},
                           {"options", options},
                           {"seed", seed},
                           {"software", SoftwareVersions()}};
  return WriteTextFileAtomically(dir + "/run.json", record.dump(2) + "\n", error);
}

}  // namespace ccdpsf
