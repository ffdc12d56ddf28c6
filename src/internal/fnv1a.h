// FNV-1a, 64 bits: the tool's one checksum of bytes, for telling contents apart (the same
// frame under two names, a run's signature) and for catching damage (a checkpoint with a
// flipped bit). Each byte is mixed in by a xor and a multiplication by an odd prime, so any
// change of a single byte changes the value. Not a guard against deliberate forgery.
#ifndef CCDPSF_INTERNAL_FNV1A_H_
#define CCDPSF_INTERNAL_FNV1A_H_

#include <cstddef>
#include <cstdint>

namespace ccdpsf::internal {

class Fnv1a {
 public:
  void Add(const void* data, size_t bytes) {
    const unsigned char* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < bytes; ++i) {
      hash_ ^= p[i];
      hash_ *= 1099511628211ULL;
    }
  }
  uint64_t value() const { return hash_; }

 private:
  uint64_t hash_ = 1469598103934665603ULL;
};

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_FNV1A_H_
