#pragma once
// TriangleBvh: a compact bounding-volume hierarchy over triangles, for exact
// nearest-point queries (Metro-style distance sampling, nearest-face lookups).
//
// Contract:
// - build() takes the triangles by value (3 corners each, plus an optional caller id
//   per triangle) and stores them in leaf order, so a leaf's triangles are contiguous.
//   Build is sequential and deterministic: the same input gives the same tree.
// - Nodes are 32 bytes: float boxes rounded outwards (so they still contain every
//   corner exactly) and one index + count. Children of an inner node are adjacent.
//   Splits are binned SAH (16 bins on the longest centroid axis), falling back to an
//   object-median split when SAH cannot separate or the tree gets deep.
// - nearest(q, bound) finds the triangle closest to q among those strictly closer
//   than sqrt(bound); it is exact (Ericson's closest point on every candidate) and
//   prunes a subtree only when its box is no closer than the best found so far.
//   The returned squared distance is the minimum over all triangles, whatever the
//   traversal order; queries are const and safe to run concurrently.
// - Memory: 72 B of corners + 8 B id per triangle, about 32 B of nodes per triangle.
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "measure/point_triangle.hpp"
#include "util/geometry.hpp"

namespace qemflow::measure {

using TriangleCorners = std::array<Point, 3>;

class TriangleBvh {
 public:
  struct Hit {
    double squared_distance = 0;
    uint32_t primitive = 0;  // index in BVH order: pass to triangle() / id()
    Point closest{};
  };

  TriangleBvh() = default;
  // `ids` is empty (ids are then the input positions) or one per triangle.
  static TriangleBvh build(std::vector<TriangleCorners> triangles, std::vector<uint64_t> ids = {});

  // True and fills `hit` when some triangle is strictly closer than sqrt(bound_squared).
  bool nearest(const Point& query, double bound_squared, Hit& hit) const;
  bool nearest(const Point& query, Hit& hit) const;
  // Same minimum as nearest(query, hit), warm-started from a triangle likely to be
  // close (e.g. the previous query's hit): its exact distance is the first bound.
  void nearest_from(const Point& query, uint32_t guess, Hit& hit) const;
  // Calls visit(primitive, squared_distance) for every triangle with squared distance
  // <= radius_squared, in tree order.
  template <class Visit>
  void for_each_within(const Point& query, double radius_squared, const Visit& visit) const;

  size_t size() const { return triangles_.size(); }
  bool empty() const { return triangles_.empty(); }
  const TriangleCorners& triangle(uint32_t primitive) const { return triangles_[primitive]; }
  uint64_t id(uint32_t primitive) const { return ids_[primitive]; }
  size_t node_count() const { return nodes_.size(); }
  size_t memory_bytes() const;

  struct Node {
    float lo[3];
    float hi[3];
    uint32_t first;  // inner: index of the left child (right = first + 1); leaf: first triangle
    uint32_t count;  // 0 for an inner node
  };

 private:
  std::vector<Node> nodes_;
  std::vector<TriangleCorners> triangles_;
  std::vector<uint64_t> ids_;
};

template <class Visit>
void TriangleBvh::for_each_within(const Point& query, double radius_squared, const Visit& visit) const {
  if (nodes_.empty()) return;
  uint32_t stack[256];  // two entries per level at most; depth stays below 128
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[stack[--top]];
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double lo = n.lo[k], hi = n.hi[k];
      const double d = query[k] < lo ? lo - query[k] : (query[k] > hi ? query[k] - hi : 0.0);
      d2 += d * d;
    }
    if (d2 > radius_squared) continue;
    if (n.count == 0) {
      stack[top++] = n.first + 1;
      stack[top++] = n.first;
      continue;
    }
    for (uint32_t i = n.first; i < n.first + n.count; ++i) {
      const auto& t = triangles_[i];
      const double t2 = squared_distance(query, closest_point_on_triangle(query, t[0], t[1], t[2]));
      if (t2 <= radius_squared) visit(i, t2);
    }
  }
}

}  // namespace qemflow::measure
