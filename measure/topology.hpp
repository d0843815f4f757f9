#pragma once
// Topology statistics of a triangle mesh: the counters `qemflow compare` and
// `qemflow info` print, and the checks the decimator's tests make on its output.
//
// Definitions (edges are undirected vertex pairs):
// - boundary edge: exactly 1 incident face; non-manifold edge: more than 2.
// - oriented_duplicate_edges: directed edges (u->v) used by more than one face, i.e.
//   neighbours with inconsistent winding (MANIFEST.md's "Orient." column).
// - non-manifold vertex: its incident faces form more than one fan (faces around a
//   vertex are in one fan when linked through edges at that vertex), e.g. a bow-tie.
// - degenerate face: a repeated vertex index, or exactly zero area.
// - duplicate face: same vertex set as an earlier face (counted once per extra copy).
// - connected components: of faces sharing vertices; unreferenced vertices are counted
//   separately and are not components.
// Faces with a repeated index contribute no edges and no fans (they have no proper
// edges), but do count as faces, degenerate faces, and for duplicates and components.
//
// Memory: the edge, fan and duplicate counts are exact and never hold more than about
// `memory_cap` bytes of records: with K = ceil(faces * bytes_per_face / cap) passes
// over the source, pass p keeps only the records whose hash % K == p (a mesh that
// fits takes one pass). `Scope::full` also keeps a union-find parent (4 or 8 B) and
// one float position (12 B, 24 B for non-float coordinates) per vertex for
// components and zero-area faces; `Scope::edges` (for `info`) keeps nothing per vertex.
#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "measure/mesh_source.hpp"
#include "util/geometry.hpp"

namespace qemflow::measure {

struct BoundingBox {
  Point lo{0, 0, 0};
  Point hi{0, 0, 0};
  bool empty = true;
  void grow(const Point& p);
  double diagonal() const;
};

struct TopologyStats {
  uint64_t vertices = 0;
  uint64_t faces = 0;
  BoundingBox bbox;  // of all vertices, referenced or not
  uint64_t edges = 0;
  uint64_t boundary_edges = 0;
  uint64_t non_manifold_edges = 0;
  uint64_t oriented_duplicate_edges = 0;
  // Scope::full only (empty under Scope::edges):
  std::optional<uint64_t> unreferenced_vertices;
  std::optional<uint64_t> non_manifold_vertices;
  std::optional<uint64_t> degenerate_faces;
  std::optional<uint64_t> duplicate_faces;
  std::optional<uint64_t> connected_components;
  uint32_t passes = 0;  // scans of the source used for the partitioned counts
};

struct TopologyOptions {
  enum class Scope { edges, full };
  Scope scope = Scope::full;
  uint64_t memory_cap = uint64_t{1} << 30;  // bytes of edge/fan/face records per pass
};

// In-memory mesh: every counter, in one pass. Indices must be < points.size().
TopologyStats topology(const std::vector<Point>& points, const std::vector<Triangle>& triangles);

// Streamed: scans `source` 1 + K times at most (see above).
TopologyStats topology(const MeshSource& source, const TopologyOptions& options = {});

}  // namespace qemflow::measure
