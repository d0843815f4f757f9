#pragma once
// Streaming PLY reader (ascii, binary little- and big-endian; see mesh_stream.hpp
// for the contract). Exposed for tests and tools that want the parsed header.
#include <filesystem>
#include <memory>

#include "io/mesh_stream.hpp"

namespace qemflow::io {

std::unique_ptr<MeshReader> open_ply_reader(const std::filesystem::path& path, bool zstd);

}  // namespace qemflow::io
