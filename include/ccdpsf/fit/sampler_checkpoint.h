// The ensemble sampler's state on disk, so that a killed run resumes where it stopped.
//
// A checkpoint holds everything the next step depends on: the walkers' positions, log
// densities and aux values, their acceptance counts (stretch, independence and conditional moves),
// each walker's random engine, the chain so far and where the convergence checks stand. A run
// resumed from it ends with exactly the chain of an uninterrupted run (the sampler's determinism,
// ensemble_sampler.h, does the rest). `fingerprint` identifies the run (options, seed, dimensions
// and the initial positions): a checkpoint of another run is never used.
//
// File format (little-endian as the machine writes it; read back on the same machine kind):
// the 8 bytes "CCDPSFMC", a uint32 version, then the fields below in order, each vector as a
// uint64 count followed by its values, each engine as its text form (std::mt19937_64's
// operator<<) with a uint64 length. Written atomically (atomic_file.h).
#ifndef CCDPSF_FIT_SAMPLER_CHECKPOINT_H_
#define CCDPSF_FIT_SAMPLER_CHECKPOINT_H_

#include <cstdint>
#include <string>
#include <vector>

namespace ccdpsf::fit {

struct SamplerCheckpoint {
  uint64_t fingerprint = 0;
  int32_t steps = 0;          // steps taken; the chain holds this many
  int32_t next_check = 0;     // the step of the next convergence check
  double previous_max_tau = 0;  // what the last check passed to Check() (+inf at the first)
  std::vector<double> positions;               // [walker * dim + k]
  std::vector<double> log_prob;                // [walker]
  std::vector<int64_t> accepted;               // [walker], stretch moves
  std::vector<int64_t> independence_proposed;  // [walker]
  std::vector<int64_t> independence_accepted;  // [walker]
  std::vector<double> conditional_acceptance;  // [walker]
  std::vector<double> aux;                     // [walker * aux_dim + i]
  std::vector<std::string> engines;            // [walker], text form
  std::vector<double> chain;                   // SamplerResult::chain so far
  std::vector<double> chain_log_prob;          // SamplerResult::log_prob so far
};

bool WriteSamplerCheckpoint(const std::string& path, const SamplerCheckpoint& checkpoint,
                            std::string* error);

// False with a reason if the file is missing, not a checkpoint, cut short, or damaged (the
// checksum at its end, over every byte before it, does not match).
bool ReadSamplerCheckpoint(const std::string& path, SamplerCheckpoint* checkpoint,
                           std::string* error);

}  // namespace ccdpsf::fit

#endif  // CCDPSF_FIT_SAMPLER_CHECKPOINT_H_
