#pragma once
// Integer cells of a uniform grid (origin 0, cube edge `cell_size`) and a hash for
// using them as keys. Shared by the sampler and the proximity graph, as in PPDS.
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <vector>

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

// Cell -> uint32_t map with open addressing (linear probing, grows at half load):
// the partition kernels look cells up millions of times, and node-based maps spend
// that time in cache misses. Iteration order is never used, so it cannot leak into
// results.
class CellMap {
 public:
  static constexpr uint32_t absent = UINT32_MAX;
  explicit CellMap(size_t expected = 16) { rehash(capacity_for(expected)); }
  size_t size() const { return size_; }
  uint32_t find(const Cell& cell) const {
    for (size_t at = slot(cell);; at = (at + 1) & mask_) {
      if (values_[at] == absent) return absent;
      if (keys_[at] == cell) return values_[at];
    }
  }
  // The value stored for `cell`, storing `value` first if the cell is new.
  uint32_t insert(const Cell& cell, uint32_t value) {
    if (2 * (size_ + 1) > keys_.size()) rehash(keys_.size() * 2);
    for (size_t at = slot(cell);; at = (at + 1) & mask_) {
      if (values_[at] == absent) {
        keys_[at] = cell;
        values_[at] = value;
        ++size_;
        return value;
      }
      if (keys_[at] == cell) return values_[at];
    }
  }

 private:
  static size_t capacity_for(size_t expected) {
    size_t capacity = 16;
    while (capacity < 2 * expected) capacity *= 2;
    return capacity;
  }
  size_t slot(const Cell& cell) const { return CellHash{}(cell) & mask_; }
  void rehash(size_t capacity) {
    std::vector<Cell> keys(capacity);
    std::vector<uint32_t> values(capacity, absent);
    keys.swap(keys_);
    values.swap(values_);
    mask_ = capacity - 1;
    size_ = 0;
    for (size_t i = 0; i < keys.size(); ++i)
      if (values[i] != absent) insert(keys[i], values[i]);
  }
  std::vector<Cell> keys_;
  std::vector<uint32_t> values_;
  size_t mask_ = 0;
  size_t size_ = 0;
};

// Calls visit(cell) for the 27 cells around `centre` (itself included).
template <class Visit>
void for_each_neighbour_cell(const Cell& centre, Visit&& visit) {
  for (int64_t dx = -1; dx <= 1; ++dx)
    for (int64_t dy = -1; dy <= 1; ++dy)
      for (int64_t dz = -1; dz <= 1; ++dz) visit(Cell{centre[0] + dx, centre[1] + dy, centre[2] + dz});
}

}  // namespace qemflow::nodes::partition
