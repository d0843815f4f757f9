#pragma once
// Binary PLY read in two halves, so that the I/O thread only moves bytes: read()
// takes raw byte ranges of the body off the disk (I/O thread), decode() turns each
// range into vertices or triangles in bulk (a compute thread, one range at a time in
// read order, carrying a record cut by a range's end over to the next range).
// The two halves touch disjoint state, so read() of range k+1 may run while range k
// is decoded.
//
// Offered for uncompressed binary (LE or BE) PLY whose body is exactly a vertex
// element of fixed-size records followed by an optional face element (any layout:
// "list uchar int" triangles take a fixed-stride fast path, other lists and extra
// properties a per-record scan). Anything else (ascii, .zst, OBJ, other elements,
// lists in vertices) gets nullptr from open_ply_bulk_reader: use the streaming
// MeshReader (io/mesh_stream.hpp).
//
// Errors are those of the streaming reader, word for word and at the same byte
// offsets (non-finite coordinates, bad indices, bad list counts, truncation), each
// raised by decode() when it reaches the record, so the first bad record in file
// order is the one reported. Header errors are raised by open_ply_bulk_reader.
// A truncated body is seen by decode() on the range read() marks `last`.
//
// Encoding (the writing half): encode_ply_vertices / encode_ply_triangles make the
// exact bytes io::MeshWriter's PLY writer writes for a batch, on any thread; the I/O
// thread then appends them with MeshWriter::write_encoded_*.
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "io/mesh_stream.hpp"
#include "io/ply_header.hpp"
#include "io/polygon_fan.hpp"
#include "util/memory.hpp"

namespace qemflow::io {

// One raw byte range of a PLY body.
struct RawChunk {
  enum class Part : uint8_t { vertices, faces };
  Part part = Part::vertices;
  uint64_t offset = 0;  // file offset of bytes[0]
  size_t size = 0;
  bool last = false;    // the part ends with this range (or the file does)
  std::unique_ptr<char[]> bytes;
  void clear() {
    bytes.reset();
    size = 0;
  }
};

class PlyBulkReader {
 public:
  PlyBulkReader(const std::filesystem::path& path, PlyHeader header, uint64_t file_size);
  ~PlyBulkReader();
  PlyBulkReader(const PlyBulkReader&) = delete;
  PlyBulkReader& operator=(const PlyBulkReader&) = delete;

  const MeshInfo& info() const { return info_; }
  const std::string& name() const { return name_; }
  // True when x, y and z are all declared float: every coordinate is a float exactly.
  bool float_coordinates() const;

  // ---- I/O thread ----
  // The next range, about `max_bytes` (whole vertex records; at least one record).
  // False once every range has been handed out (the chunk is then empty).
  bool read(RawChunk& chunk, size_t max_bytes);
  // True once every vertex range has been handed out (the next read is faces).
  bool past_vertices() const { return part_ == RawChunk::Part::faces || ended_; }
  uint64_t bytes_read() const { return bytes_read_; }

  // ---- one compute thread at a time, ranges in read order ----
  // Fills `batch` (cleared first) with the range's vertices or triangles.
  void decode(const RawChunk& chunk, MeshBatch& batch);
  // A faces range (of a mesh whose vertex count fits u32): its triangles as u32 index
  // triples, 12 bytes each, at `triangles` (resized to them), not as 24-byte Triangles;
  // the id of the first in `first_triangle`. The same checks and errors as decode().
  void decode_triangles32(const RawChunk& chunk, Bytes& triangles, uint64_t& first_triangle);
  // The same as PLY face records, "3 a b c" (ply_triangle_bytes each, the bytes the
  // writer's encode_ply_triangles makes): what a re-encode writes out unchanged.
  void decode_ply_triangles(const RawChunk& chunk, Bytes& triangles, uint64_t& first_triangle);
  // A faces range whose bytes already are those PLY face records (a little-endian
  // file's "list uchar int" or "uint" triangles, every index below the vertex count):
  // checked where they lie, with decode()'s errors, and taken as decoded, the first's
  // id in `first_triangle` and how many in `count`. False, and nothing taken, when the
  // range holds anything else (a polygon, a record cut by either end, bytes past the
  // faces, big-endian indices): decode_ply_triangles then decodes it.
  bool check_ply_triangles(const RawChunk& chunk, uint64_t& first_triangle, uint64_t& count);
  // A vertices range of a file whose vertices are just "float x, y, z": its positions
  // straight to xyz[3 * first, 3 * (first + count)), where `first` is the range's first
  // vertex and xyz has room for `capacity` vertices, with no Point batch between (the
  // resident re-encode's vertex array). The same checks and errors as decode(). False,
  // and nothing decoded, for any other layout or a range past `capacity`.
  bool decode_float_vertices(const RawChunk& chunk, float* xyz, uint64_t capacity, uint64_t& first, uint64_t& count);
  // The same into `xyz` alone, resized to the range's vertices (the out-of-core load's
  // vertex frames): false, and nothing decoded, for any other layout.
  bool decode_float_vertices(const RawChunk& chunk, UninitializedVector<float>& xyz, uint64_t& first, uint64_t& count);
  // A faces range as (face id, a, b, c) u32 records, 16 bytes each, ids from the
  // range's first triangle (returned in `first_triangle`): the out-of-core re-encode's
  // local face records, with no Triangle batch between. As decode_triangles32 otherwise.
  void decode_id_triangles32(const RawChunk& chunk, Bytes& records, uint64_t& first_triangle);

 private:
  template <bool Swap> void decode_vertices(const RawChunk& chunk, MeshBatch& batch);
  void put_float_vertices(const RawChunk& chunk, size_t n, float* out, uint64_t& first, uint64_t& count);
  [[noreturn]] void non_finite(const RawChunk& chunk, size_t i, const Point& v) const;
  void vertices_decoded(const RawChunk& chunk, size_t count);
  template <bool Swap, class Out> void decode_faces(const RawChunk& chunk, uint64_t& first_triangle, Out out);
  // Whether the faces are "list uchar int" (or uint) alone: 13-byte records while
  // their count byte says 3.
  bool fixed_triangles() const;
  // Up to `limit` such records from `p` (at file offset `offset`, the first being face
  // faces_done_), each index checked, to out.set(used + i, ...) while the count byte
  // says 3; returns how many.
  template <bool Swap, class Out>
  size_t fast_triangles(const char* p, size_t limit, uint64_t offset, Out& out, size_t used) const;
  // decode_faces into u32 records (the decode_*32 and PLY record forms): Error(internal)
  // naming `what` unless a faces range of a mesh whose indices fit u32.
  template <class Out> void decode_u32_faces(const char* what, const RawChunk& chunk, uint64_t& first_triangle, Out out);
  template <bool Swap, class Out> size_t face_record(const char* record, size_t left, uint64_t offset, size_t& needed,
                                                     Out& out, size_t& used_triangles);
  template <bool Swap, class Out>
  void fan_indices(PolygonFan& fan, PlyType type, const char* p, size_t count, uint64_t offset, Out& out,
                   size_t& used) const;
  template <bool Swap, class Out> void polygon_indices(const char* p, size_t count, Out& out, size_t& used);
  [[noreturn]] void bad_index(int64_t index, uint64_t offset) const;
  [[noreturn]] void truncated_polygon(size_t found_after) const;
  [[noreturn]] void truncated(const std::string& element_name, uint64_t element_count, uint64_t record,
                              uint64_t offset, size_t needed, size_t found) const;

  std::string name_;
  PlyHeader header_;
  MeshInfo info_;
  int fd_ = -1;
  uint64_t file_size_ = 0;
  uint64_t vertex_count_ = 0;
  uint64_t face_count_ = 0;
  size_t vertex_record_ = 0;
  uint64_t vertices_begin_ = 0, faces_begin_ = 0;

  // read() side
  RawChunk::Part part_ = RawChunk::Part::vertices;
  uint64_t position_ = 0;
  bool ended_ = false;
  uint64_t bytes_read_ = 0;

  // decode() side
  uint64_t vertices_done_ = 0;
  uint64_t faces_done_ = 0;
  uint64_t triangles_done_ = 0;
  std::vector<char> carry_;  // a face record (or a streamed polygon's index) cut by the end of the previous range
  uint64_t carry_offset_ = 0;
  // A polygon read as a stream (ply_binary::streamed_polygon_vertices): its fan, the
  // indices still to come, and its record's offset and length, for errors.
  PolygonFan fan_;
  uint64_t polygon_left_ = 0;
  uint64_t polygon_offset_ = 0;
  uint64_t polygon_length_ = 0;
};

// A bulk reader for `path`, or nullptr when its name or body layout is not one the
// bulk path serves (see above). Throws what the streaming reader's open throws for
// a bad header.
std::unique_ptr<PlyBulkReader> open_ply_bulk_reader(const std::filesystem::path& path);

// PLY body bytes as the PLY writer makes them: xyz as float (12 bytes a vertex) or
// double (24); faces as "3 a b c" with uchar count and 32-bit indices (13 bytes).
// Each returns the bytes written at `out`; encode_ply_triangles also returns the
// largest index seen (for the writer's index check).
size_t encode_ply_vertices(const Point* points, size_t count, bool double_precision, char* out);
size_t encode_ply_triangles(const Triangle* triangles, size_t count, char* out, uint64_t& max_index);
size_t encode_ply_triangles(const uint32_t* triangles, size_t count, char* out, uint64_t& max_index);
inline constexpr size_t ply_triangle_bytes = 13;
// One PLY face record "3 a b c" (ply_triangle_bytes, encode_ply_triangles' bytes) at
// `at`, as two overlapping 8-byte stores: bytes 0-7 (3, a, b's low three bytes), then
// bytes 5-12 (b, c).
inline void put_ply_triangle(uint32_t a, uint32_t b, uint32_t c, std::byte* at) {
  static_assert(std::endian::native == std::endian::little);  // as the PLY writer's own encode
  const uint64_t head = 3 | uint64_t(a) << 8 | uint64_t(b) << 40;
  const uint64_t tail = uint64_t(b) | uint64_t(c) << 32;
  std::memcpy(at, &head, sizeof head);
  std::memcpy(at + 5, &tail, sizeof tail);
}

}  // namespace qemflow::io
