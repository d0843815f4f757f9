#pragma once
// The PLY header: elements, their properties and the body encoding, parsed from the
// lines before end_header. The reader uses it to walk the body; errors name the
// header line ("FILE: line 3: ...", Error(bad_input)).
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "io/mesh_stream.hpp"

namespace qemflow::io {

class ByteSource;

enum class PlyType : uint8_t { int8, uint8, int16, uint16, int32, uint32, float32, float64 };

size_t size_of(PlyType type);
bool is_integer(PlyType type);
std::optional<PlyType> parse_ply_type(std::string_view name);  // "uchar", "uint8", ...
const char* ply_type_name(PlyType type);

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::float32;  // the value type (list items for a list)
  bool is_list = false;
  PlyType count_type = PlyType::uint8;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;
  uint64_t line = 0;  // header line that declared it
  // Bytes per record when every property is a scalar (binary), else 0.
  size_t fixed_record_size() const;
};

struct PlyHeader {
  MeshFormat format = MeshFormat::ply_binary_le;
  std::vector<PlyElement> elements;
  uint64_t line_count = 0;     // lines in the header, end_header included
  uint64_t byte_count = 0;     // bytes in the header, so the body starts here
  // Roles, resolved by resolve_roles(): which element holds what.
  size_t vertex_element = 0;
  std::optional<size_t> face_element;
  size_t coordinate_property[3] = {0, 0, 0};  // x, y, z within the vertex element
  size_t index_property = 0;                  // vertex_indices within the face element
};

// Reads and consumes the header from `source`; validates that there is a vertex
// element with scalar x, y, z and, if there is a face element, an integer list
// named vertex_indices (or vertex_index) after the vertices.
PlyHeader read_ply_header(ByteSource& source);

}  // namespace qemflow::io
