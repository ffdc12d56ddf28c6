// Deterministic random numbers. The samplers are written here rather than taken from
// <random>'s distributions, whose algorithms differ between standard libraries: the same seed
// must give the same bytes everywhere. The engine is std::mt19937_64, whose output sequence
// the C++ standard fixes.
#ifndef CCDPSF_RANDOM_H_
#define CCDPSF_RANDOM_H_

#include <cstdint>
#include <random>

namespace ccdpsf {

// A 64-bit seed derived from a parent seed and a stream index (SplitMix64 finaliser), so
// that stream k's numbers do not depend on how many other streams exist.
uint64_t DeriveSeed(uint64_t seed, uint64_t stream);

// Uniform on (0, 1): never exactly 0 or 1 (53 random bits, offset by half a step).
double Uniform01(std::mt19937_64& engine);

// Standard normal (Box-Muller; one value per call, the pair's second is discarded so that a
// call always consumes exactly two engine outputs).
double StandardNormal(std::mt19937_64& engine);

// Poisson deviate of mean `mean` >= 0: inversion by multiplication below 10, Hormann's
// transformed rejection with squeeze (PTRS, 1993) above.
int64_t Poisson(double mean, std::mt19937_64& engine);

}  // namespace ccdpsf

#endif  // CCDPSF_RANDOM_H_
