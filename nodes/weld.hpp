#pragma once
// Position weld: vertices at exactly the same position (== on each coordinate, so
// -0.0 equals 0.0) become one. The representative of a group is its smallest input
// index, which also becomes the group's global vertex id (DESIGN.md §4), so the weld
// is the same in core and out of core.
#include <cstdint>
#include <span>
#include <vector>

#include "util/geometry.hpp"

namespace qemflow::nodes {

// representative[i] = smallest j with points[j] == points[i] (j <= i).
std::vector<uint64_t> weld_representatives(std::span<const Point> points);

}  // namespace qemflow::nodes
