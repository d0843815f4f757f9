#pragma once
// A whole mesh in memory, for small meshes (tests, the in-core decimator, tools).
// read_mesh/write_mesh are thin loops over open_mesh_reader/open_mesh_writer, so
// they accept the same formats and throw the same errors.
#include <filesystem>
#include <vector>

#include "io/mesh_stream.hpp"
#include "util/geometry.hpp"

namespace qemflow::io {

struct IndexedMesh {
  std::vector<Point> vertices;
  std::vector<Triangle> triangles;
};

IndexedMesh read_mesh(const std::filesystem::path& path);
void write_mesh(const std::filesystem::path& path, const IndexedMesh& mesh,
                const WriteOptions& options = {});

}  // namespace qemflow::io
