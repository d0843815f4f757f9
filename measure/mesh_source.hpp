#pragma once
// MeshSource: a mesh that can be scanned from its start any number of times, either a
// file (through io::open_mesh_reader, re-opened per scan, never held in memory) or
// caller-owned vectors. The measure passes (topology, distances) are written once
// against this interface, so the in-memory entry points and the file commands run
// the same code.
//
// Contract:
// - scan() delivers vertices and triangles in stream order, as consecutive runs with
//   their global index of the first element. Every triangle's indices refer to
//   vertices already delivered (scan checks this, and finite coordinates, and throws
//   Error(bad_input) "NAME: face N: PROBLEM" otherwise), so consumers may trust them.
// - A scan holds only one reader batch in memory.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "io/mesh_stream.hpp"
#include "util/geometry.hpp"

namespace qemflow::measure {

struct MeshScan {
  std::function<void(uint64_t first_vertex, std::span<const Point>)> on_vertices;
  std::function<void(uint64_t first_triangle, std::span<const Triangle>)> on_triangles;
};

class MeshSource {
 public:
  virtual ~MeshSource() = default;
  virtual const std::string& name() const = 0;
  // Triangle count if known before scanning (e.g. a PLY header of triangles), else empty.
  virtual std::optional<uint64_t> triangle_count_hint() const = 0;
  virtual void scan(const MeshScan& scan) const = 0;
};

// A file; opens it once now (so a missing or malformed header fails here).
std::unique_ptr<MeshSource> file_mesh_source(const std::filesystem::path& path);
// Caller-owned vectors; they must outlive the source.
std::unique_ptr<MeshSource> memory_mesh_source(const std::vector<Point>& points,
                                               const std::vector<Triangle>& triangles,
                                               std::string name = "<memory mesh>");

// A whole mesh in memory (for SIMPLIFIED, which is small by assumption).
struct Mesh {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};
Mesh load_mesh(const MeshSource& source);

// Vertex positions of a streamed mesh, at 12 B per vertex while every coordinate is
// exactly a float (true of float PLY/OBJ files) and 24 B once any is not, so stored
// positions are always exact. This is the one cost of `compare` that grows with
// ORIGINAL.
class PositionStore {
 public:
  void append(std::span<const Point> points);
  Point operator[](uint64_t i) const {
    if (exact_float_) return {narrow_[3 * i], narrow_[3 * i + 1], narrow_[3 * i + 2]};
    return wide_[i];
  }
  uint64_t size() const { return exact_float_ ? narrow_.size() / 3 : wide_.size(); }
  uint64_t memory_bytes() const { return narrow_.capacity() * sizeof(float) + wide_.capacity() * sizeof(Point); }

 private:
  bool exact_float_ = true;
  std::vector<float> narrow_;
  std::vector<Point> wide_;
};

}  // namespace qemflow::measure
