#include <algorithm>
#include <cctype>
#include <string>

#include "io/mesh_file_kind.hpp"
#include "io/mesh_writers.hpp"
#include "io/obj_reader.hpp"
#include "io/ply_reader.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

bool ends_with(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() && text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

MeshFileKind mesh_file_kind(const std::filesystem::path& path) {
  std::string name = path.filename().string();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  MeshFileKind kind;
  if (ends_with(name, ".zst")) {
    kind.zstd = true;
    name.resize(name.size() - 4);
  }
  if (ends_with(name, ".obj")) {
    kind.obj = true;
  } else if (!ends_with(name, ".ply")) {
    throw Error(ErrorKind::usage, path.string() +
                                      ": unknown mesh file type (expected .ply or .obj, "
                                      "optionally followed by .zst)");
  }
  return kind;
}

std::unique_ptr<MeshReader> open_mesh_reader(const std::filesystem::path& path) {
  MeshFileKind kind = mesh_file_kind(path);
  return kind.obj ? open_obj_reader(path, kind.zstd) : open_ply_reader(path, kind.zstd);
}

std::unique_ptr<MeshWriter> open_mesh_writer(const std::filesystem::path& path,
                                             uint64_t vertex_count, uint64_t triangle_count,
                                             const WriteOptions& options) {
  MeshFileKind kind = mesh_file_kind(path);
  int level = kind.zstd ? std::max(1, options.zstd_level) : 0;
  return kind.obj ? open_obj_writer(path, vertex_count, triangle_count, options, level)
                  : open_ply_writer(path, vertex_count, triangle_count, options, level);
}

void MeshWriter::write_encoded_vertices(const char*, size_t) {
  throw Error(ErrorKind::internal, "mesh writer misuse: pre-encoded vertices for a format without them");
}
void MeshWriter::write_encoded_triangles(const char*, size_t, uint64_t) {
  throw Error(ErrorKind::internal, "mesh writer misuse: pre-encoded triangles for a format without them");
}

}  // namespace qemflow::io
