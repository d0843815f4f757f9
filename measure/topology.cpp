#include "measure/topology.hpp"

#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "measure/surface_sampler.hpp"
#include "measure/vec3.hpp"
#include "util/error.hpp"

namespace qemflow::measure {

void BoundingBox::grow(const Point& p) {
  if (empty) {
    lo = hi = p;
    empty = false;
    return;
  }
  for (int k = 0; k < 3; ++k) {
    lo[k] = std::min(lo[k], p[k]);
    hi[k] = std::max(hi[k], p[k]);
  }
}

double BoundingBox::diagonal() const { return empty ? 0.0 : std::sqrt(squared_distance(lo, hi)); }

namespace {

// An undirected edge with the direction its face walks it: key = (lo, hi << 1 | dir).
struct EdgeRecord {
  uint64_t lo, hi_dir;
  auto operator<=>(const EdgeRecord&) const = default;
};
// A face seen from one corner: the corner's vertex and the face's other two.
struct FanRecord {
  uint64_t vertex, a, b;
  auto operator<=>(const FanRecord&) const = default;
};
struct FaceRecord {  // sorted vertex set
  uint64_t v[3];
  auto operator<=>(const FaceRecord&) const = default;
};

bool repeats_index(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }
uint64_t edge_hash(uint64_t lo, uint64_t hi) { return mix64(lo * 0x9e3779b97f4a7c15ULL ^ mix64(hi)); }
uint64_t face_hash(const FaceRecord& f) { return mix64(f.v[0] ^ mix64(f.v[1] ^ mix64(f.v[2]))); }

uint64_t bytes_per_face(TopologyOptions::Scope scope) {
  return scope == TopologyOptions::Scope::full
             ? 3 * sizeof(EdgeRecord) + 3 * sizeof(FanRecord) + sizeof(FaceRecord)
             : 3 * sizeof(EdgeRecord);
}

class UnionFind {
 public:
  void add(uint64_t count) {
    if (count > std::numeric_limits<uint32_t>::max())
      throw Error(ErrorKind::resource, "topology: more than 2^32-1 vertices");
    for (uint64_t i = parent_.size(); i < count; ++i) parent_.push_back(static_cast<uint32_t>(i));
  }
  uint32_t find(uint32_t x) {
    while (parent_[x] != x) {
      parent_[x] = parent_[parent_[x]];
      x = parent_[x];
    }
    return x;
  }
  void unite(uint32_t a, uint32_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    if (a < b) std::swap(a, b);
    parent_[a] = b;
  }
  bool is_root(uint32_t x) const { return parent_[x] == x; }

 private:
  std::vector<uint32_t> parent_;
};

// Per-pass record buffers for one partition of the edge/fan/face key spaces.
struct Partition {
  uint64_t index = 0, count = 1;
  bool full = true;
  std::vector<EdgeRecord> edges;
  std::vector<FanRecord> fans;
  std::vector<FaceRecord> faces;

  uint64_t bytes() const {
    return edges.size() * sizeof(EdgeRecord) + fans.size() * sizeof(FanRecord) + faces.size() * sizeof(FaceRecord);
  }
  void release() {
    std::vector<EdgeRecord>().swap(edges);
    std::vector<FanRecord>().swap(fans);
    std::vector<FaceRecord>().swap(faces);
  }
  bool mine(uint64_t hash) const { return hash % count == index; }

  void collect(const Triangle& t) {
    if (full) {
      FaceRecord f{{t[0], t[1], t[2]}};
      std::sort(f.v, f.v + 3);
      if (mine(face_hash(f))) faces.push_back(f);
    }
    if (repeats_index(t)) return;
    for (int k = 0; k < 3; ++k) {
      const uint64_t u = t[k], v = t[(k + 1) % 3];
      const uint64_t lo = std::min(u, v), hi = std::max(u, v);
      if (mine(edge_hash(lo, hi))) edges.push_back({lo, hi << 1 | (u > v ? 1u : 0u)});
      if (full && mine(mix64(u))) fans.push_back({u, t[(k + 1) % 3], t[(k + 2) % 3]});
    }
  }

  void count_into(TopologyStats& stats) {
    tbb::parallel_sort(edges.begin(), edges.end());
    for (size_t i = 0; i < edges.size();) {
      size_t j = i;
      uint64_t directions[2] = {0, 0};
      while (j < edges.size() && edges[j].lo == edges[i].lo && (edges[j].hi_dir >> 1) == (edges[i].hi_dir >> 1))
        ++directions[edges[j++].hi_dir & 1];
      const uint64_t incident = j - i;
      ++stats.edges;
      stats.boundary_edges += incident == 1;
      stats.non_manifold_edges += incident > 2;
      stats.oriented_duplicate_edges += (directions[0] > 1) + (directions[1] > 1);
      i = j;
    }
    if (!full) return;

    tbb::parallel_sort(faces.begin(), faces.end());
    for (size_t i = 1; i < faces.size(); ++i) *stats.duplicate_faces += faces[i] == faces[i - 1];

    tbb::parallel_sort(fans.begin(), fans.end());
    std::vector<uint64_t> neighbours;
    std::vector<uint32_t> parent;
    for (size_t i = 0; i < fans.size();) {
      size_t j = i;
      while (j < fans.size() && fans[j].vertex == fans[i].vertex) ++j;
      // Faces around the vertex are linked when they share a neighbour (an edge at
      // the vertex): count connected components of the link graph.
      neighbours.clear();
      for (size_t k = i; k < j; ++k) {
        neighbours.push_back(fans[k].a);
        neighbours.push_back(fans[k].b);
      }
      std::sort(neighbours.begin(), neighbours.end());
      neighbours.erase(std::unique(neighbours.begin(), neighbours.end()), neighbours.end());
      parent.resize(neighbours.size());
      for (uint32_t k = 0; k < parent.size(); ++k) parent[k] = k;
      auto find = [&](uint32_t x) {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
      };
      auto local = [&](uint64_t v) {
        return static_cast<uint32_t>(std::lower_bound(neighbours.begin(), neighbours.end(), v) - neighbours.begin());
      };
      size_t components = neighbours.size();
      for (size_t k = i; k < j; ++k) {
        const uint32_t a = find(local(fans[k].a)), b = find(local(fans[k].b));
        if (a != b) {
          parent[std::max(a, b)] = std::min(a, b);
          --components;
        }
      }
      *stats.non_manifold_vertices += components > 1;
      i = j;
    }
  }
};

}  // namespace

TopologyStats topology(const std::vector<Point>& points, const std::vector<Triangle>& triangles) {
  return topology(*memory_mesh_source(points, triangles),
                  {TopologyOptions::Scope::full, std::numeric_limits<uint64_t>::max()});
}

TopologyStats topology(const MeshSource& source, const TopologyOptions& options) {
  const bool full = options.scope == TopologyOptions::Scope::full;
  const uint64_t per_face = bytes_per_face(options.scope);
  const uint64_t cap = std::max<uint64_t>(options.memory_cap, 1 << 20);
  auto passes_for = [&](uint64_t faces) {
    // 20% headroom for uneven hash partitions.
    const long double bytes = static_cast<long double>(faces) * per_face * 1.2L;
    return std::max<uint64_t>(1, static_cast<uint64_t>(std::ceil(bytes / cap)));
  };

  TopologyStats stats;
  // Whole-mesh state, filled in the first scan only.
  PositionStore positions;
  UnionFind components;
  std::vector<bool> referenced;
  bool global_done = false;

  const uint64_t first_estimate = passes_for(source.triangle_count_hint().value_or(0));
  uint64_t pass_count = first_estimate;
  bool capped = true;
  for (uint64_t p = 0; p < pass_count; ++p) {
    Partition part;
    part.index = p;
    part.count = pass_count;
    part.full = full;
    if (auto hint = source.triangle_count_hint(); hint && capped) {
      const uint64_t expected = *hint / pass_count + *hint / (8 * pass_count) + 16;
      part.edges.reserve(3 * expected);
      if (full) {
        part.fans.reserve(3 * expected);
        part.faces.reserve(expected);
      }
    }
    bool overflow = false;
    uint64_t faces_seen = 0;
    MeshScan scan;
    scan.on_vertices = [&](uint64_t first, std::span<const Point> points) {
      if (global_done) return;
      stats.vertices = first + points.size();
      for (const Point& q : points) stats.bbox.grow(q);
      if (full) {
        positions.append(points);
        components.add(stats.vertices);
        referenced.resize(stats.vertices, false);
      }
    };
    scan.on_triangles = [&](uint64_t first, std::span<const Triangle> triangles) {
      faces_seen = first + triangles.size();
      if (!global_done && full) {
        for (const Triangle& t : triangles) {
          for (uint64_t v : t) referenced[v] = true;
          components.unite(static_cast<uint32_t>(t[0]), static_cast<uint32_t>(t[1]));
          components.unite(static_cast<uint32_t>(t[1]), static_cast<uint32_t>(t[2]));
          const bool zero_area = squared_length(triangle_normal(positions[t[0]], positions[t[1]], positions[t[2]])) == 0;
          *stats.degenerate_faces += repeats_index(t) || zero_area;
        }
      }
      if (overflow) return;
      for (const Triangle& t : triangles) part.collect(t);
      if (capped && part.bytes() > cap) {
        overflow = true;  // the size estimate was wrong: finish the scan for counts only
        part.release();
      }
    };
    if (!global_done && full) {
      stats.unreferenced_vertices = 0;
      stats.degenerate_faces = 0;
      stats.connected_components = 0;
    }
    if (p == 0) {
      stats.edges = stats.boundary_edges = stats.non_manifold_edges = stats.oriented_duplicate_edges = 0;
      if (full) stats.non_manifold_vertices = stats.duplicate_faces = 0;
    }
    source.scan(scan);
    ++stats.passes;
    if (!global_done) {
      stats.faces = faces_seen;
      if (full) {
        for (uint64_t v = 0; v < stats.vertices; ++v) {
          if (!referenced[v]) ++*stats.unreferenced_vertices;
          else if (components.is_root(static_cast<uint32_t>(v))) ++*stats.connected_components;
        }
      }
      global_done = true;
    }
    if (overflow) {
      // Restart the partitioned counts with enough passes for the real face count;
      // a key space too skewed to split (e.g. one face repeated millions of times)
      // eventually lifts the cap rather than looping.
      const uint64_t needed = passes_for(stats.faces);
      pass_count = std::max(2 * pass_count, needed);
      if (pass_count > 64 * std::max(first_estimate, needed)) {
        pass_count = needed;
        capped = false;
      }
      p = static_cast<uint64_t>(-1);
      continue;
    }
    part.count_into(stats);
  }
  return stats;
}

}  // namespace qemflow::measure
