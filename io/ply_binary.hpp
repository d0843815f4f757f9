#pragma once
// Loads of binary PLY values (little- or big-endian, by the Swap flag), shared by the
// streaming reader (ply_reader.cpp) and the bulk decoder (ply_bulk.cpp). Internal to io/.
#include <bit>
#include <cstdint>
#include <cstring>
#include <string>

#include "io/ply_header.hpp"
#include "util/error.hpp"
#include "util/geometry.hpp"

namespace qemflow::io::ply_binary {

// A list may not make one record longer than this; a larger one is corrupt input
// rather than a polygon anyone meant to write.
constexpr size_t max_record_bytes = size_t{1} << 26;

// A binary face record that is only a list of at least this many indices is read as a
// stream (io/polygon_fan.hpp): its triangles leave in bounded batches and the record
// is never held whole. Its indices are checked as they arrive, so a bad index is named
// before a truncation later in the record. Below this (every "list uchar ..." record),
// a record is read whole, as it always was.
constexpr int64_t streamed_polygon_vertices = 256;

// The whitespace of an ASCII PLY's body, and all that may follow a PLY's last element.
inline bool is_space(char c) { return c == ' ' || c == '\n' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// The problem named when a PLY goes on after its last element: the header's counts do
// not match the body, and reading on as if they did would drop faces without a word.
inline std::string data_after_last_element(const PlyElement& last) {
  return "data after the last element (the header declares " + std::to_string(last.count) + " " + last.name +
         "; are its counts wrong?)";
}

// Bytes after a PLY's last element may only be whitespace (some writers end with a
// newline). Throws bad input at the first other byte; `offset` is the offset of p[0]
// in the file.
inline void check_trailing_bytes(const std::string& file, const char* p, size_t n, uint64_t offset,
                                 const PlyElement& last) {
  for (size_t i = 0; i < n; ++i) {
    if (!is_space(p[i])) throw_bad_input(file, "byte " + std::to_string(offset + i), data_after_last_element(last));
  }
}

template <bool Swap>
inline uint16_t load16(const char* p) {
  uint16_t v;
  std::memcpy(&v, p, 2);
  if constexpr (Swap) v = __builtin_bswap16(v);
  return v;
}
template <bool Swap>
inline uint32_t load32(const char* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  if constexpr (Swap) v = __builtin_bswap32(v);
  return v;
}
template <bool Swap>
inline uint64_t load64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  if constexpr (Swap) v = __builtin_bswap64(v);
  return v;
}

// Integer types only (the header checks that counts and indices are integers).
template <bool Swap>
inline int64_t load_integer(PlyType type, const char* p) {
  switch (type) {
    case PlyType::int8: return static_cast<int8_t>(*p);
    case PlyType::uint8: return static_cast<uint8_t>(*p);
    case PlyType::int16: return static_cast<int16_t>(load16<Swap>(p));
    case PlyType::uint16: return load16<Swap>(p);
    case PlyType::int32: return static_cast<int32_t>(load32<Swap>(p));
    case PlyType::uint32: return load32<Swap>(p);
    default: return 0;
  }
}

template <bool Swap>
inline double load_real(PlyType type, const char* p) {
  switch (type) {
    case PlyType::float32: return std::bit_cast<float>(load32<Swap>(p));
    case PlyType::float64: return std::bit_cast<double>(load64<Swap>(p));
    default: return static_cast<double>(load_integer<Swap>(type, p));
  }
}

inline bool all_finite(const Point& p) {
  // Non-finite values give NaN here (inf - inf); finite ones give exactly 0.
  double zero = (p[0] - p[0]) + (p[1] - p[1]) + (p[2] - p[2]);
  return zero == 0;
}

// Where x, y, z sit in a fixed-size vertex record.
struct VertexLayout {
  size_t record = 0;
  size_t offsets[3] = {0, 0, 0};
  PlyType types[3] = {PlyType::float32, PlyType::float32, PlyType::float32};
  bool packed_floats = false;  // exactly "float x, float y, float z"
};

inline VertexLayout vertex_layout(const PlyHeader& header) {
  const PlyElement& element = header.elements[header.vertex_element];
  VertexLayout layout;
  layout.record = element.fixed_record_size();
  for (int axis = 0; axis < 3; ++axis) {
    size_t property = header.coordinate_property[axis];
    layout.types[axis] = element.properties[property].type;
    for (size_t i = 0; i < property; ++i) layout.offsets[axis] += size_of(element.properties[i].type);
  }
  layout.packed_floats = layout.record == 12 && layout.types[0] == PlyType::float32 &&
                         layout.types[1] == PlyType::float32 && layout.types[2] == PlyType::float32 &&
                         layout.offsets[0] == 0 && layout.offsets[1] == 4 && layout.offsets[2] == 8;
  return layout;
}

// `count` whole records at p to points (no checks).
template <bool Swap>
void decode_vertex_records(const VertexLayout& layout, const char* p, size_t count, Point* out) {
  if (layout.packed_floats) {
    for (size_t i = 0; i < count; ++i, p += 12) {
      out[i] = {std::bit_cast<float>(load32<Swap>(p)), std::bit_cast<float>(load32<Swap>(p + 4)),
                std::bit_cast<float>(load32<Swap>(p + 8))};
    }
    return;
  }
  for (size_t i = 0; i < count; ++i, p += layout.record) {
    out[i] = {load_real<Swap>(layout.types[0], p + layout.offsets[0]),
              load_real<Swap>(layout.types[1], p + layout.offsets[1]),
              load_real<Swap>(layout.types[2], p + layout.offsets[2])};
  }
}

// Length of the binary record at p if all of it is within `available`; otherwise 0
// and `needed` is how many bytes are known to be required. The list count of
// property `list_property`, if any, is at *list_offset. A negative or implausible
// count calls bad(problem) (which throws), problem being what follows "ELEMENT N".
template <bool Swap, class Bad>
size_t record_length(const PlyElement& element, const char* p, size_t available, size_t& needed,
                     size_t* list_offset, size_t list_property, Bad&& bad) {
  size_t position = 0;
  for (size_t i = 0; i < element.properties.size(); ++i) {
    const PlyProperty& property = element.properties[i];
    if (!property.is_list) {
      position += size_of(property.type);
      continue;
    }
    size_t count_size = size_of(property.count_type);
    if (position + count_size > available) {
      needed = position + count_size;
      return 0;
    }
    if (i == list_property) *list_offset = position;
    int64_t count = load_integer<Swap>(property.count_type, p + position);
    if (count < 0) bad("has a negative list count " + std::to_string(count));
    position += count_size + static_cast<size_t>(count) * size_of(property.type);
    if (position > max_record_bytes) bad("has an implausible list of " + std::to_string(count) + " items");
  }
  if (position > available) {
    needed = position;
    return 0;
  }
  return position;
}

}  // namespace qemflow::io::ply_binary
