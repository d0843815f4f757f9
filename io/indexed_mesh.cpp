#include "io/indexed_mesh.hpp"

namespace qemflow::io {

IndexedMesh read_mesh(const std::filesystem::path& path) {
  auto reader = open_mesh_reader(path);
  IndexedMesh mesh;
  if (reader->info().vertex_count) mesh.vertices.reserve(*reader->info().vertex_count);
  if (reader->info().polygon_count) mesh.triangles.reserve(*reader->info().polygon_count);
  MeshBatch batch;
  while (reader->next(batch, size_t{1} << 18)) {
    mesh.vertices.insert(mesh.vertices.end(), batch.vertices.begin(), batch.vertices.end());
    mesh.triangles.insert(mesh.triangles.end(), batch.triangles.begin(), batch.triangles.end());
  }
  return mesh;
}

void write_mesh(const std::filesystem::path& path, const IndexedMesh& mesh,
                const WriteOptions& options) {
  auto writer = open_mesh_writer(path, mesh.vertices.size(), mesh.triangles.size(), options);
  writer->write_vertices(mesh.vertices.data(), mesh.vertices.size());
  writer->write_triangles(mesh.triangles.data(), mesh.triangles.size());
  writer->commit();
}

}  // namespace qemflow::io
