// Four doubles in one vector register, for the renderer's hand-vectorised loops.
#ifndef CCDPSF_INTERNAL_VEC4_H_
#define CCDPSF_INTERNAL_VEC4_H_

#include <cstring>

namespace ccdpsf::internal {

// A GCC/Clang vector extension: one AVX register with -march=x86-64-v3, two SSE2 registers
// without. Scalars broadcast in arithmetic with it.
typedef double Vec4 __attribute__((vector_size(32)));

// Unaligned load and store (memcpy compiles to one vector move).
inline Vec4 LoadVec4(const double* p) {
  Vec4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void StoreVec4(double* p, const Vec4& v) { std::memcpy(p, &v, sizeof v); }

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_VEC4_H_
