#pragma once
// Counter-based random numbers: every random choice of the partition kernels is a
// pure function of (seed, counter...), so results never depend on thread count,
// batch order or library versions (no std:: distributions anywhere).
#include <cstdint>

namespace qemflow::nodes::partition {

// SplitMix64's finaliser: a bijective 64-bit mix with full avalanche.
inline uint64_t mix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

inline uint64_t counter_hash(uint64_t seed, uint64_t a, uint64_t b) {
  return mix64(mix64(mix64(seed) ^ a) ^ (b * 0xD1B54A32D192ED03ull));
}

// The top 53 bits as a double in [0, 1).
inline double unit_interval(uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

}  // namespace qemflow::nodes::partition
