#pragma once
// Counter-based random numbers: every random choice of the partition kernels is a
// pure function of (seed, counter...), so results never depend on thread count,
// batch order or library versions (no std:: distributions anywhere).
#include <cstdint>

#include "util/hash.hpp"

namespace qemflow::nodes::partition {

// SplitMix64's full step: the golden-ratio increment, then the finaliser.
inline uint64_t mix64(uint64_t x) { return qemflow::mix64(x + 0x9E3779B97F4A7C15ull); }

inline uint64_t counter_hash(uint64_t seed, uint64_t a, uint64_t b) {
  return mix64(mix64(mix64(seed) ^ a) ^ (b * 0xD1B54A32D192ED03ull));
}

inline double unit_interval(uint64_t h) { return unit_double(h); }

}  // namespace qemflow::nodes::partition
