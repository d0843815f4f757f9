#include "measure/mesh_source.hpp"

#include <cmath>

#include "util/error.hpp"

namespace qemflow::measure {
namespace {

// Checks one run of a stream against the vertices delivered so far.
void check_vertices(const std::string& name, uint64_t first, std::span<const Point> points) {
  for (size_t i = 0; i < points.size(); ++i)
    for (double x : points[i])
      if (!std::isfinite(x))
        throw_bad_input(name, "vertex " + std::to_string(first + i), "coordinate is not finite");
}
void check_triangles(const std::string& name, uint64_t first, std::span<const Triangle> triangles,
                     uint64_t vertices_so_far) {
  for (size_t i = 0; i < triangles.size(); ++i)
    for (uint64_t v : triangles[i])
      if (v >= vertices_so_far)
        throw_bad_input(name, "face " + std::to_string(first + i),
                        "vertex index " + std::to_string(v) + " out of range (" +
                            std::to_string(vertices_so_far) + " vertices so far)");
}

class FileMeshSource final : public MeshSource {
 public:
  explicit FileMeshSource(const std::filesystem::path& path)
      : path_(path), name_(path.string()), first_reader_(io::open_mesh_reader(path)), info_(first_reader_->info()) {}

  const std::string& name() const override { return name_; }
  std::optional<uint64_t> triangle_count_hint() const override {
    // A PLY face count is a triangle count only if every polygon is a triangle; it is
    // still the right order of magnitude for sizing passes.
    return info_.polygon_count;
  }
  void scan(const MeshScan& scan) const override {
    std::unique_ptr<io::MeshReader> reader = first_reader_ ? std::move(first_reader_) : io::open_mesh_reader(path_);
    io::MeshBatch batch;
    uint64_t vertices = 0;
    while (reader->next(batch)) {
      if (!batch.vertices.empty()) {
        check_vertices(name_, batch.first_vertex, batch.vertices);
        vertices = batch.first_vertex + batch.vertices.size();
        if (scan.on_vertices) scan.on_vertices(batch.first_vertex, batch.vertices);
      }
      if (!batch.triangles.empty()) {
        check_triangles(name_, batch.first_triangle, batch.triangles, vertices);
        if (scan.on_triangles) scan.on_triangles(batch.first_triangle, batch.triangles);
      }
      batch.clear();
    }
  }

 private:
  std::filesystem::path path_;
  std::string name_;
  mutable std::unique_ptr<io::MeshReader> first_reader_;
  io::MeshInfo info_;
};

class MemoryMeshSource final : public MeshSource {
 public:
  MemoryMeshSource(const std::vector<Point>& points, const std::vector<Triangle>& triangles, std::string name)
      : points_(points), triangles_(triangles), name_(std::move(name)) {}
  const std::string& name() const override { return name_; }
  std::optional<uint64_t> triangle_count_hint() const override { return triangles_.size(); }
  void scan(const MeshScan& scan) const override {
    check_vertices(name_, 0, points_);
    check_triangles(name_, 0, triangles_, points_.size());
    if (scan.on_vertices && !points_.empty()) scan.on_vertices(0, points_);
    if (scan.on_triangles && !triangles_.empty()) scan.on_triangles(0, triangles_);
  }

 private:
  const std::vector<Point>& points_;
  const std::vector<Triangle>& triangles_;
  std::string name_;
};

}  // namespace

std::unique_ptr<MeshSource> file_mesh_source(const std::filesystem::path& path) {
  return std::make_unique<FileMeshSource>(path);
}

std::unique_ptr<MeshSource> memory_mesh_source(const std::vector<Point>& points,
                                               const std::vector<Triangle>& triangles, std::string name) {
  return std::make_unique<MemoryMeshSource>(points, triangles, std::move(name));
}

Mesh load_mesh(const MeshSource& source) {
  Mesh mesh;
  if (auto hint = source.triangle_count_hint()) mesh.triangles.reserve(*hint);
  source.scan({[&](uint64_t, std::span<const Point> p) { mesh.points.insert(mesh.points.end(), p.begin(), p.end()); },
               [&](uint64_t, std::span<const Triangle> t) {
                 mesh.triangles.insert(mesh.triangles.end(), t.begin(), t.end());
               }});
  return mesh;
}

void PositionStore::append(std::span<const Point> points) {
  if (exact_float_) {
    bool exact = true;
    for (const Point& p : points)
      for (double x : p) exact = exact && static_cast<double>(static_cast<float>(x)) == x;
    if (exact) {
      for (const Point& p : points)
        for (double x : p) narrow_.push_back(static_cast<float>(x));
      return;
    }
    // The first coordinate a float cannot hold: widen what we have, once.
    wide_.reserve(size() + points.size());
    for (size_t i = 0; i < narrow_.size(); i += 3) wide_.push_back({narrow_[i], narrow_[i + 1], narrow_[i + 2]});
    std::vector<float>().swap(narrow_);
    exact_float_ = false;
  }
  wide_.insert(wide_.end(), points.begin(), points.end());
}

}  // namespace qemflow::measure
