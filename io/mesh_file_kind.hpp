#pragma once
// Which reader/writer a file name selects: ".ply" or ".obj", each optionally
// followed by ".zst" (case-insensitive). Anything else is Error(usage).
#include <filesystem>

namespace qemflow::io {

struct MeshFileKind {
  bool obj = false;   // else PLY
  bool zstd = false;
};

MeshFileKind mesh_file_kind(const std::filesystem::path& path);

}  // namespace qemflow::io
