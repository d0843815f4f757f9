#pragma once
// Streaming Wavefront OBJ reader (see mesh_stream.hpp for the contract): 'v' and 'f'
// lines; every other statement is ignored. Errors name the line.
#include <filesystem>
#include <memory>

#include "io/mesh_stream.hpp"

namespace qemflow::io {

std::unique_ptr<MeshReader> open_obj_reader(const std::filesystem::path& path, bool zstd);

}  // namespace qemflow::io
