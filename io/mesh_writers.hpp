#pragma once
// The concrete writers behind open_mesh_writer (see mesh_stream.hpp). zstd_level 0
// writes uncompressed. Contract violations by the caller (more elements than
// declared, counts short at commit, a triangle index past the declared vertices,
// PLY triangles before all vertices) are Error(internal).
#include <filesystem>
#include <memory>

#include "io/mesh_stream.hpp"

namespace qemflow::io {

std::unique_ptr<MeshWriter> open_ply_writer(const std::filesystem::path& path, uint64_t vertex_count,
                                            uint64_t triangle_count, const WriteOptions& options,
                                            int zstd_level);
std::unique_ptr<MeshWriter> open_obj_writer(const std::filesystem::path& path, uint64_t vertex_count,
                                            uint64_t triangle_count, const WriteOptions& options,
                                            int zstd_level);

}  // namespace qemflow::io
