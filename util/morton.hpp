#pragma once
// Morton (Z-order) codes: a coordinate's bits spread to every third bit, so three
// lanes interleave by shifts and ors (a few operations, where a loop over the bits took
// three per bit and axis).
#include <cstdint>

namespace qemflow {

// x's low 21 bits, two zero bits after each (a Morton code's lane).
inline uint64_t spread_bits21(uint64_t x) {
  x &= 0x1fffff;
  x = (x | x << 32) & 0x1f00000000ffffull;
  x = (x | x << 16) & 0x1f0000ff0000ffull;
  x = (x | x << 8) & 0x100f00f00f00f00full;
  x = (x | x << 4) & 0x10c30c30c30c30c3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}

}  // namespace qemflow
