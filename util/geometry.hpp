#pragma once
// The element types that flow between readers, writers, generator and pipeline.
#include <array>
#include <cstdint>

namespace qemflow {

using Point = std::array<double, 3>;      // a vertex position, exact for float and double inputs
using Triangle = std::array<uint64_t, 3>; // vertex indices (global, 0-based)

}  // namespace qemflow
