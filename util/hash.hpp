#pragma once
// Counter-based hashing: every "random" choice in qemflow (generator noise, compare's
// samples, the partition's dart throwing) is a pure function of integers, so results
// never depend on thread count, batch order or the standard library's engines.
#include <cstdint>

namespace qemflow {

// SplitMix64's finaliser: a bijection on 64 bits with full avalanche.
inline uint64_t mix64(uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  x ^= x >> 31;
  return x;
}

// The top 53 bits of a hash as a double in [0, 1).
inline double unit_double(uint64_t bits) { return static_cast<double>(bits >> 11) * 0x1.0p-53; }

}  // namespace qemflow
