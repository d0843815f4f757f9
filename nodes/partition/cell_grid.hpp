#pragma once
// Integer cells of a uniform grid (origin 0, cube edge `cell_size`) and a hash for
// using them as keys. Shared by the sampler and the proximity graph, as in PPDS.
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>

#include "nodes/partition/counter_hash.hpp"
#include "util/geometry.hpp"

namespace qemflow::nodes::partition {

using Cell = std::array<int64_t, 3>;

inline Cell cell_of(const Point& p, double inverse_cell_size) {
  return {static_cast<int64_t>(std::floor(p[0] * inverse_cell_size)),
          static_cast<int64_t>(std::floor(p[1] * inverse_cell_size)),
          static_cast<int64_t>(std::floor(p[2] * inverse_cell_size))};
}

struct CellHash {
  size_t operator()(const Cell& c) const {
    return static_cast<size_t>(
        mix64(static_cast<uint64_t>(c[0]) ^ mix64(static_cast<uint64_t>(c[1]) ^
                                                  mix64(static_cast<uint64_t>(c[2])))));
  }
};

// Calls visit(cell) for the 27 cells around `centre` (itself included).
template <class Visit>
void for_each_neighbour_cell(const Cell& centre, Visit&& visit) {
  for (int64_t dx = -1; dx <= 1; ++dx)
    for (int64_t dy = -1; dy <= 1; ++dy)
      for (int64_t dz = -1; dz <= 1; ++dz) visit(Cell{centre[0] + dx, centre[1] + dy, centre[2] + dz});
}

}  // namespace qemflow::nodes::partition
