#pragma once
// The decimator's local numbering: vertices along a Z-order (Morton) curve of their
// positions, faces by their smallest vertex in that order. The rounds visit vertices in
// local order and each visit reads its neighbours' and their faces' state: in this
// order a vertex's rings lie in a few nearby stretches of every array, however the
// input was numbered. Nothing computed depends on it (every order that matters is by
// global ids). The decimator's setup applies it (renumber_for_locality); a caller that
// writes its PatchInput in this order already (the out-of-core patch build) sets
// PatchInput::in_locality_order and saves the setup's permutes of every array.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <utility>

#include "nodes/decimate/quadric.hpp"
#include "util/memory.hpp"
#include "util/morton.hpp"
#include "util/radix_sort.hpp"

namespace qemflow::nodes {

struct PatchInput;

// The locality order of nv vertices, vertex i at position_of(i): old_of[j] is the
// vertex numbered j, ties in code in index order. Empty (the order left as given) for
// fewer than 2 vertices or without a finite extent.
template <class PositionOf>
UninitializedVector<uint32_t> locality_order(size_t nv, PositionOf&& position_of) {
  struct Bounds {
    Vec3 lo, hi;
  };
  Bounds none;
  none.lo.fill(std::numeric_limits<double>::infinity());
  none.hi.fill(-std::numeric_limits<double>::infinity());
  // An equal +0.0 / -0.0 keeps the earlier one, as a serial loop would: the blocks are
  // joined left to right.
  auto join = [](Bounds a, const Bounds& b) {
    for (int k = 0; k < 3; ++k) {
      a.lo[k] = std::min(a.lo[k], b.lo[k]);
      a.hi[k] = std::max(a.hi[k], b.hi[k]);
    }
    return a;
  };
  const Bounds box = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, nv, 4096), none,
      [&](const tbb::blocked_range<size_t>& r, Bounds b) {
        for (size_t v = r.begin(); v < r.end(); ++v) {
          const Vec3& p = position_of(v);
          for (int k = 0; k < 3; ++k) {
            const double x = p[k];
            if (std::isfinite(x)) {
              b.lo[k] = std::min(b.lo[k], x);
              b.hi[k] = std::max(b.hi[k], x);
            }
          }
        }
        return b;
      },
      join);
  const Vec3 lo = box.lo, hi = box.hi;
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  if (nv < 2 || !(extent > 0.0) || !std::isfinite(extent)) return {};
  const double scale = double((1u << 21) - 1) / extent;
  auto lane = [&](double x, int k) -> uint64_t {
    const double q = (x - lo[k]) * scale;  // in [0, 2^21 - 1] when finite
    return std::isfinite(q) ? spread_bits21(static_cast<uint64_t>(std::clamp(q, 0.0, double((1u << 21) - 1)))) : 0;
  };
  UninitializedVector<std::pair<uint64_t, uint32_t>> by_code(nv);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t v = r.begin(); v < r.end(); ++v) {
      const Vec3& p = position_of(v);
      by_code[v] = {lane(p[0], 0) | lane(p[1], 1) << 1 | lane(p[2], 2) << 2, uint32_t(v)};
    }
  });
  // Ties in code are in index order already: the stable radix sort gives std::sort's order.
  radix_sort_by_key(by_code, [](const std::pair<uint64_t, uint32_t>& x) { return x.first; });
  UninitializedVector<uint32_t> old_of(nv);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) old_of[i] = by_code[i].second;
  });
  return old_of;
}

// Orders `in`'s faces (their gids and owned flags with them) by their smallest vertex,
// ties in the given order: the faces' half of the locality order, once the vertices
// are numbered in it.
void order_faces_by_first_vertex(PatchInput& in);

}  // namespace qemflow::nodes
