#include "io/mesh_stream.hpp"

namespace qemflow::io {

std::string to_string(MeshFormat format) {
  switch (format) {
    case MeshFormat::ply_ascii: return "PLY ascii";
    case MeshFormat::ply_binary_le: return "PLY binary little-endian";
    case MeshFormat::ply_binary_be: return "PLY binary big-endian";
    case MeshFormat::obj: return "Wavefront OBJ";
  }
  return "unknown";
}

}  // namespace qemflow::io
