#include "measure/bvh.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <tbb/parallel_for.h>

#include "measure/point_triangle.hpp"
#include "util/error.hpp"

namespace qemflow::measure {
namespace {

constexpr uint32_t kLeafTarget = 4;     // SAH may stop splitting at or below this
constexpr uint32_t kLeafMax = 16;       // never keep a leaf larger than this
constexpr int kBins = 16;
constexpr int kMedianDepth = 48;        // below this depth always split by object median
constexpr int kStackSize = 128;         // > kMedianDepth + log2(2^32) + 1

struct Box {
  double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                  std::numeric_limits<double>::infinity()};
  double hi[3] = {-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                  -std::numeric_limits<double>::infinity()};
  void grow(const Point& p) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  }
  void grow(const Box& b) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], b.lo[k]);
      hi[k] = std::max(hi[k], b.hi[k]);
    }
  }
  double half_area() const {
    if (hi[0] < lo[0]) return 0;
    const double dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
    return dx * dy + dy * dz + dz * dx;
  }
};

// Float bounds that still contain the double bounds.
float round_down(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}
float round_up(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) < x) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

struct Builder {
  const std::vector<TriangleCorners>& triangles;
  std::vector<Box> boxes;
  std::vector<Point> centroids;
  std::vector<uint32_t> order;

  struct Range {
    uint32_t node, begin, end;
    int depth;
    Box box, centroid_box;  // of the range's triangles and of their centroids
  };

  Range make_range(uint32_t node, uint32_t begin, uint32_t end, int depth) const {
    Range r{node, begin, end, depth, {}, {}};
    for (uint32_t i = begin; i < end; ++i) {
      r.box.grow(boxes[order[i]]);
      r.centroid_box.grow(centroids[order[i]]);
    }
    return r;
  }

  static void set_box(TriangleBvh::Node& n, const Box& box) {
    for (int k = 0; k < 3; ++k) {
      n.lo[k] = round_down(box.lo[k]);
      n.hi[k] = round_up(box.hi[k]);
    }
  }

  // Splits r into left and right (returning true), or returns false when r should be
  // a leaf. The children's boxes come from the bins when SAH splits; a median split
  // measures them again.
  bool split(const Range& r, Range& left_range, Range& right_range) {
    const uint32_t begin = r.begin, end = r.end;
    const int depth = r.depth;
    const uint32_t count = end - begin;
    if (count <= kLeafTarget) return false;
    const Box& centroid_box = r.centroid_box;
    int axis = 0;
    for (int k = 1; k < 3; ++k)
      if (centroid_box.hi[k] - centroid_box.lo[k] > centroid_box.hi[axis] - centroid_box.lo[axis]) axis = k;
    const double extent = centroid_box.hi[axis] - centroid_box.lo[axis];
    const uint32_t mid = begin + count / 2;
    auto median_split = [&] {
      std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                       [&](uint32_t a, uint32_t b) {
                         if (centroids[a][axis] != centroids[b][axis]) return centroids[a][axis] < centroids[b][axis];
                         return a < b;
                       });
      left_range = make_range(0, begin, mid, depth + 1);
      right_range = make_range(0, mid, end, depth + 1);
      return true;
    };
    if (!(extent > 0)) return count <= kLeafMax ? false : median_split();
    if (depth >= kMedianDepth) return median_split();

    const double scale = kBins / extent;
    auto bin_of = [&](uint32_t t) {
      int b = static_cast<int>((centroids[t][axis] - centroid_box.lo[axis]) * scale);
      return std::clamp(b, 0, kBins - 1);
    };
    Box bin_box[kBins], bin_centroids[kBins];
    uint32_t bin_count[kBins] = {};
    for (uint32_t i = begin; i < end; ++i) {
      const int b = bin_of(order[i]);
      ++bin_count[b];
      bin_box[b].grow(boxes[order[i]]);
      bin_centroids[b].grow(centroids[order[i]]);
    }
    double right_area[kBins];
    uint32_t right_count[kBins];
    Box all;
    uint32_t n = 0;
    for (int b = kBins - 1; b > 0; --b) {
      all.grow(bin_box[b]);
      n += bin_count[b];
      right_area[b] = all.half_area();
      right_count[b] = n;
    }
    all.grow(bin_box[0]);
    Box left;
    uint32_t left_count = 0;
    double best_cost = std::numeric_limits<double>::infinity();
    int best_bin = -1;
    for (int b = 1; b < kBins; ++b) {  // split between bins b-1 and b
      left.grow(bin_box[b - 1]);
      left_count += bin_count[b - 1];
      if (left_count == 0 || right_count[b] == 0) continue;
      const double cost = left.half_area() * left_count + right_area[b] * right_count[b];
      if (cost < best_cost) {
        best_cost = cost;
        best_bin = b;
      }
    }
    if (best_bin < 0) return count <= kLeafMax ? false : median_split();
    // Leaf cost ~ count triangle tests; a split costs a box test plus the SAH estimate.
    const double parent_area = all.half_area();
    if (count <= kLeafMax && parent_area > 0 && best_cost / parent_area + 1.0 >= count) return false;
    auto it = std::partition(order.begin() + begin, order.begin() + end,
                             [&](uint32_t t) { return bin_of(t) < best_bin; });
    const auto at = static_cast<uint32_t>(it - order.begin());
    if (at == begin || at == end) return median_split();
    left_range = {0, begin, at, depth + 1, {}, {}};
    right_range = {0, at, end, depth + 1, {}, {}};
    for (int b = 0; b < kBins; ++b) {
      Range& side = b < best_bin ? left_range : right_range;
      side.box.grow(bin_box[b]);
      side.centroid_box.grow(bin_centroids[b]);
    }
    return true;
  }

  // Builds the subtree of `root` depth-first into `nodes`. Ranges with at most
  // `stop_below` triangles are not split but returned in `frontier` (in tree order).
  void build(std::vector<TriangleBvh::Node>& nodes, Range root, uint32_t stop_below, std::vector<Range>* frontier) {
    std::vector<Range> tasks{root};
    while (!tasks.empty()) {
      const Range r = tasks.back();
      tasks.pop_back();
      auto& node = nodes[r.node];
      set_box(node, r.box);
      node.first = r.begin;
      node.count = r.end - r.begin;
      if (frontier && node.count <= stop_below) {
        frontier->push_back(r);
        continue;
      }
      Range left, right;
      if (!split(r, left, right)) continue;  // leaf
      const auto first = static_cast<uint32_t>(nodes.size());
      nodes.push_back({});
      nodes.push_back({});
      nodes[r.node].first = first;
      nodes[r.node].count = 0;
      left.node = first;
      right.node = first + 1;
      tasks.push_back(right);
      tasks.push_back(left);
    }
  }

  // The top of the tree is split sequentially until ranges are small enough to build
  // independently; those subtrees are built in parallel into their own arrays and
  // appended in tree order, so the result is the same tree as a sequential build.
  std::vector<TriangleBvh::Node> run() {
    const auto count = static_cast<uint32_t>(triangles.size());
    std::vector<TriangleBvh::Node> nodes;
    if (count == 0) return nodes;
    order.resize(count);
    std::iota(order.begin(), order.end(), 0u);
    boxes.resize(count);
    centroids.resize(count);
    tbb::parallel_for(uint32_t{0}, count, [&](uint32_t t) {
      const auto& c = triangles[t];
      for (const Point& p : c) boxes[t].grow(p);
      for (int k = 0; k < 3; ++k) centroids[t][k] = (c[0][k] + c[1][k] + c[2][k]) / 3.0;
    });
    nodes.reserve(2 * ((count + kLeafTarget - 1) / kLeafTarget) + 1);
    nodes.push_back({});
    constexpr uint32_t kParallelBelow = 1u << 14;
    std::vector<Range> frontier;
    build(nodes, make_range(0, 0, count, 0), std::max(kParallelBelow, count / 64), &frontier);

    std::vector<std::vector<TriangleBvh::Node>> subtrees(frontier.size());
    tbb::parallel_for(size_t{0}, frontier.size(), [&](size_t i) {
      subtrees[i].push_back({});
      Range root = frontier[i];
      root.node = 0;
      build(subtrees[i], root, 0, nullptr);
    });
    for (size_t i = 0; i < frontier.size(); ++i) {
      // Subtree node j > 0 lands at offset + j - 1; its root replaces the frontier node.
      const auto offset = static_cast<uint32_t>(nodes.size());
      auto relocate = [&](TriangleBvh::Node n) {
        if (n.count == 0) n.first = offset + n.first - 1;
        return n;
      };
      nodes[frontier[i].node] = relocate(subtrees[i][0]);
      for (size_t j = 1; j < subtrees[i].size(); ++j) nodes.push_back(relocate(subtrees[i][j]));
      std::vector<TriangleBvh::Node>().swap(subtrees[i]);
    }
    return nodes;
  }
};

inline double box_squared_distance(const TriangleBvh::Node& n, const Point& q) {
  double d2 = 0;
  for (int k = 0; k < 3; ++k) {
    const double lo = n.lo[k], hi = n.hi[k];
    const double d = q[k] < lo ? lo - q[k] : (q[k] > hi ? q[k] - hi : 0.0);
    d2 += d * d;
  }
  return d2;
}

}  // namespace

TriangleBvh TriangleBvh::build(std::vector<TriangleCorners> triangles, std::vector<uint64_t> ids) {
  if (triangles.size() >= std::numeric_limits<uint32_t>::max())
    throw Error(ErrorKind::internal, "TriangleBvh: more than 2^32-1 triangles in one tree");
  if (!ids.empty() && ids.size() != triangles.size())
    throw Error(ErrorKind::internal, "TriangleBvh: ids and triangles differ in length");
  Builder builder{triangles, {}, {}, {}};
  TriangleBvh bvh;
  bvh.nodes_ = builder.run();
  bvh.triangles_.resize(triangles.size());
  bvh.ids_.resize(triangles.size());
  for (size_t i = 0; i < builder.order.size(); ++i) {
    const uint32_t t = builder.order[i];
    bvh.triangles_[i] = triangles[t];
    bvh.ids_[i] = ids.empty() ? t : ids[t];
  }
  return bvh;
}

void TriangleBvh::nearest_from(const Point& query, uint32_t guess, Hit& hit) const {
  const auto& t = triangles_[guess];
  const Point closest = closest_point_on_triangle(query, t[0], t[1], t[2]);
  const double d2 = squared_distance(query, closest);
  if (!nearest(query, d2, hit)) hit = {d2, guess, closest};
}

bool TriangleBvh::nearest(const Point& query, Hit& hit) const {
  return nearest(query, std::numeric_limits<double>::infinity(), hit);
}

bool TriangleBvh::nearest(const Point& query, double bound_squared, Hit& hit) const {
  if (nodes_.empty()) return false;
  struct Entry {
    uint32_t node;
    double d2;
  };
  Entry stack[kStackSize];
  int top = 0;
  double best = bound_squared;
  bool found = false;
  uint32_t node = 0;
  double node_d2 = box_squared_distance(nodes_[0], query);
  while (true) {
    if (node_d2 < best) {
      const Node& n = nodes_[node];
      if (n.count > 0) {
        for (uint32_t i = n.first; i < n.first + n.count; ++i) {
          const auto& t = triangles_[i];
          const Point c = closest_point_on_triangle(query, t[0], t[1], t[2]);
          const double d2 = squared_distance(query, c);
          if (d2 < best) {
            best = d2;
            found = true;
            hit.squared_distance = d2;
            hit.primitive = i;
            hit.closest = c;
          }
        }
      } else {
        const double left = box_squared_distance(nodes_[n.first], query);
        const double right = box_squared_distance(nodes_[n.first + 1], query);
        const bool left_first = left <= right;
        const uint32_t near_node = left_first ? n.first : n.first + 1;
        const uint32_t far_node = left_first ? n.first + 1 : n.first;
        const double near_d2 = left_first ? left : right, far_d2 = left_first ? right : left;
        if (far_d2 < best) stack[top++] = {far_node, far_d2};
        node = near_node;
        node_d2 = near_d2;
        continue;
      }
    }
    if (top == 0) break;
    --top;
    node = stack[top].node;
    node_d2 = stack[top].d2;
  }
  return found;
}

size_t TriangleBvh::memory_bytes() const {
  return nodes_.capacity() * sizeof(Node) + triangles_.capacity() * sizeof(TriangleCorners) +
         ids_.capacity() * sizeof(uint64_t);
}

}  // namespace qemflow::measure
