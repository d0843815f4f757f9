#include "io/ply_bulk.hpp"

#include <fcntl.h>
#include <emmintrin.h>
#include <smmintrin.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "io/byte_source.hpp"
#include "io/mesh_file_kind.hpp"
#include "io/ply_binary.hpp"
#include "io/polygon_fan.hpp"
#include "util/error.hpp"

namespace qemflow::io {

using namespace ply_binary;

namespace {

std::string byte_place(uint64_t offset) { return "byte " + std::to_string(offset); }

// Reads up to `size` bytes at `offset`; fewer only at the end of the file.
size_t read_at(int fd, const std::string& name, uint64_t offset, char* out, size_t size) {
  size_t got = 0;
  while (got < size) {
    ssize_t n = ::pread(fd, out + got, size - got, off_t(offset + got));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw_bad_input(name, byte_place(offset + got), std::string("cannot read: ") + std::strerror(errno));
    if (n == 0) break;
    got += size_t(n);
  }
  return got;
}

// Where decode_faces puts triangles: as Triangles, or as u32 triples (12 bytes).
struct WideTriangles {
  std::vector<Triangle>& v;
  size_t size() const { return v.size(); }
  void resize(size_t n) { v.resize(n); }
  void set(size_t i, uint64_t a, uint64_t b, uint64_t c) { v[i] = {a, b, c}; }
};
struct Triangles32 {
  Bytes& v;
  uint32_t* at = reinterpret_cast<uint32_t*>(v.data());  // stores through std::byte would alias every member read
  size_t size() const { return v.size() / 12; }
  void resize(size_t n) {
    v.resize(n * 12);
    at = reinterpret_cast<uint32_t*>(v.data());
  }
  void set(size_t i, uint64_t a, uint64_t b, uint64_t c) {
    at[3 * i] = uint32_t(a);
    at[3 * i + 1] = uint32_t(b);
    at[3 * i + 2] = uint32_t(c);
  }
};

// (face id, a, b, c) as u32s (16 bytes), ids counted from `first`: the out-of-core
// re-encode's local face records, with no Triangle batch between.
struct IdTriangles32 {
  Bytes& v;
  uint64_t first;
  uint32_t* at = reinterpret_cast<uint32_t*>(v.data());  // as Triangles32's
  size_t size() const { return v.size() / 16; }
  void resize(size_t n) {
    v.resize(n * 16);
    at = reinterpret_cast<uint32_t*>(v.data());
  }
  void set(size_t i, uint64_t a, uint64_t b, uint64_t c) {
    at[4 * i] = uint32_t(first + i);
    at[4 * i + 1] = uint32_t(a);
    at[4 * i + 2] = uint32_t(b);
    at[4 * i + 3] = uint32_t(c);
  }
};

// PLY face records (13 bytes), as the writer encodes them.
// The data pointer is kept apart, as Triangles32's: its byte stores may alias anything,
// so v.data() would be loaded again after each record.
struct PlyTriangles {
  Bytes& v;
  std::byte* at = v.data();
  size_t size() const { return v.size() / ply_triangle_bytes; }
  void resize(size_t n) {
    v.resize(n * ply_triangle_bytes);
    at = v.data();
  }
  void set(size_t i, uint64_t a, uint64_t b, uint64_t c) {
    put_ply_triangle(uint32_t(a), uint32_t(b), uint32_t(c), at + i * ply_triangle_bytes);
  }
};

}  // namespace

PlyBulkReader::PlyBulkReader(const std::filesystem::path& path, PlyHeader header, uint64_t file_size)
    : name_(path.string()), header_(std::move(header)), file_size_(file_size) {
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw_bad_input(name_, "cannot open", std::strerror(errno));
  const PlyElement& vertices = header_.elements[header_.vertex_element];
  vertex_count_ = vertices.count;
  face_count_ = header_.face_element ? header_.elements[*header_.face_element].count : 0;
  vertex_record_ = vertices.fixed_record_size();
  vertices_begin_ = header_.byte_count;
  faces_begin_ = vertices_begin_ + vertex_count_ * vertex_record_;
  info_.format = header_.format;
  info_.zstd = false;
  info_.vertex_count = vertex_count_;
  info_.polygon_count = face_count_;
  info_.file_size = file_size_;
  position_ = vertices_begin_;
  if (vertex_count_ == 0) part_ = RawChunk::Part::faces;
  bytes_read_ = header_.byte_count;
}

PlyBulkReader::~PlyBulkReader() {
  if (fd_ >= 0) ::close(fd_);
}

bool PlyBulkReader::read(RawChunk& chunk, size_t max_bytes) {
  chunk.clear();
  if (ended_) return false;
  chunk.part = part_;
  chunk.offset = position_;
  size_t want;
  if (part_ == RawChunk::Part::vertices) {
    want = std::max<size_t>(max_bytes / vertex_record_, 1) * vertex_record_;
    want = size_t(std::min<uint64_t>(want, faces_begin_ - position_));
  } else {
    if (!header_.face_element) {  // no faces: only whitespace may follow the vertices
      ended_ = true;
      char tail[4096];
      for (uint64_t at = position_; at < file_size_;) {
        const size_t n = read_at(fd_, name_, at, tail, size_t(std::min<uint64_t>(sizeof tail, file_size_ - at)));
        if (n == 0) break;
        check_trailing_bytes(name_, tail, n, at, header_.elements[header_.vertex_element]);
        at += n;
      }
      return false;
    }
    want = std::max<size_t>(max_bytes, 1);
  }
  chunk.bytes = std::make_unique_for_overwrite<char[]>(want);
  chunk.size = read_at(fd_, name_, position_, chunk.bytes.get(), want);
  position_ += chunk.size;
  bytes_read_ += chunk.size;
  const bool short_read = chunk.size < want;
  if (part_ == RawChunk::Part::vertices) {
    chunk.last = short_read || position_ == faces_begin_;
    if (short_read) ended_ = true;
    if (position_ == faces_begin_) part_ = RawChunk::Part::faces;
  } else {
    chunk.last = short_read || position_ >= file_size_;
    if (chunk.last) ended_ = true;
  }
  return true;
}

void PlyBulkReader::truncated(const std::string& element_name, uint64_t element_count, uint64_t record,
                              uint64_t offset, size_t needed, size_t found) const {
  throw_bad_input(name_, byte_place(offset),
                  "file ends inside " + element_name + " " + std::to_string(record) + " of " +
                      std::to_string(element_count) + " (needed " + std::to_string(needed) +
                      " more bytes, found " + std::to_string(found) + ")");
}

void PlyBulkReader::decode(const RawChunk& chunk, MeshBatch& batch) {
  batch.clear();
  const bool swap = header_.format == MeshFormat::ply_binary_be;
  if (chunk.part == RawChunk::Part::vertices) {
    if (swap) decode_vertices<true>(chunk, batch);
    else decode_vertices<false>(chunk, batch);
  } else {
    batch.first_vertex = vertex_count_;
    if (swap) decode_faces<true>(chunk, batch.first_triangle, WideTriangles{batch.triangles});
    else decode_faces<false>(chunk, batch.first_triangle, WideTriangles{batch.triangles});
  }
}

template <class Out>
void PlyBulkReader::decode_u32_faces(const char* what, const RawChunk& chunk, uint64_t& first_triangle, Out out) {
  if (chunk.part != RawChunk::Part::faces || vertex_count_ > UINT32_MAX) {
    throw Error(ErrorKind::internal, std::string(what) + ": not a faces range of a mesh with u32 indices");
  }
  if (header_.format == MeshFormat::ply_binary_be) decode_faces<true>(chunk, first_triangle, out);
  else decode_faces<false>(chunk, first_triangle, out);
}

void PlyBulkReader::decode_triangles32(const RawChunk& chunk, Bytes& triangles, uint64_t& first_triangle) {
  decode_u32_faces("decode_triangles32", chunk, first_triangle, Triangles32{triangles});
}

void PlyBulkReader::decode_ply_triangles(const RawChunk& chunk, Bytes& triangles, uint64_t& first_triangle) {
  decode_u32_faces("decode_ply_triangles", chunk, first_triangle, PlyTriangles{triangles});
}

bool PlyBulkReader::fixed_triangles() const {
  if (!header_.face_element) return false;
  const PlyElement& element = header_.elements[*header_.face_element];
  const PlyProperty& list = element.properties[header_.index_property];
  return element.properties.size() == 1 && list.count_type == PlyType::uint8 &&
         (list.type == PlyType::int32 || list.type == PlyType::uint32);
}

namespace {
// Where fast_triangles puts nothing: the records are checked where they lie.
struct CheckedInPlace {
  void set(size_t, uint64_t, uint64_t, uint64_t) {}
};

// Whether each of the n (>= 1) 13-byte records at p is "3 a b c" (little-endian) with
// every index at most `largest`: the quick yes of the common case, four instructions a
// record where fast_triangles' loop took eighteen. One unaligned load holds a record's
// three indices and, in its last lane's low byte, the next record's count byte; the
// largest of those lanes (the count byte xor 3, so 0 when it is 3) is compared once at
// the end. On a no, fast_triangles finds which record and what to report.
__attribute__((target("sse4.1"))) bool ply_triangles_below(const char* p, size_t n, uint32_t largest) {
  if (static_cast<uint8_t>(p[0]) != 3) return false;
  const __m128i keep = _mm_setr_epi32(-1, -1, -1, 0xff), three = _mm_setr_epi32(0, 0, 0, 3);
  __m128i most = _mm_setzero_si128();
#pragma GCC unroll 4
  for (size_t i = 0; i + 1 < n; ++i) {  // the last record's load would pass the end
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 13 * i + 1));
    most = _mm_max_epu32(most, _mm_xor_si128(_mm_and_si128(v, keep), three));
  }
  uint32_t last[3];
  std::memcpy(last, p + 13 * (n - 1) + 1, sizeof last);
  const __m128i limit = _mm_setr_epi32(int(largest), int(largest), int(largest), 0);
  return _mm_movemask_epi8(_mm_cmpeq_epi32(_mm_max_epu32(most, limit), limit)) == 0xffff &&
         std::max({last[0], last[1], last[2]}) <= largest;
}
}  // namespace

bool PlyBulkReader::check_ply_triangles(const RawChunk& chunk, uint64_t& first_triangle, uint64_t& count) {
  if (chunk.part != RawChunk::Part::faces || header_.format != MeshFormat::ply_binary_le || !fixed_triangles() ||
      vertex_count_ > UINT32_MAX || !carry_.empty() || polygon_left_ > 0 || chunk.size % ply_triangle_bytes != 0) {
    return false;
  }
  const uint64_t n = chunk.size / ply_triangle_bytes;
  // The last range must end the faces exactly; anything else (bytes past the faces, a
  // file that ends early) is decode's to report.
  if (faces_done_ + n > face_count_ || (chunk.last && faces_done_ + n < face_count_)) return false;
  if (n == 0) return false;
  static const bool sse41 = __builtin_cpu_supports("sse4.1");
  const char* p = chunk.bytes.get();
  if (!(sse41 && vertex_count_ > 0 && ply_triangles_below(p, size_t(n), uint32_t(vertex_count_ - 1)))) {
    CheckedInPlace none;
    if (fast_triangles<false>(p, size_t(n), chunk.offset, none, 0) < n) return false;  // a polygon
  }
  first_triangle = triangles_done_;
  count = n;
  faces_done_ += n;
  triangles_done_ += n;
  return true;
}

void PlyBulkReader::decode_id_triangles32(const RawChunk& chunk, Bytes& records, uint64_t& first_triangle) {
  decode_u32_faces("decode_id_triangles32", chunk, first_triangle, IdTriangles32{records, triangles_done_});
}

template <bool Swap>
void PlyBulkReader::decode_vertices(const RawChunk& chunk, MeshBatch& batch) {
  const VertexLayout layout = vertex_layout(header_);
  const size_t record = layout.record;
  batch.first_vertex = vertices_done_;
  batch.first_triangle = 0;
  const size_t count = size_t(std::min<uint64_t>(chunk.size / record, vertex_count_ - vertices_done_));
  batch.vertices.resize(count);
  Point* out = batch.vertices.data();
  decode_vertex_records<Swap>(layout, chunk.bytes.get(), count, out);
  for (size_t i = 0; i < count; ++i) {
    if (!all_finite(out[i])) non_finite(chunk, i, out[i]);
  }
  vertices_decoded(chunk, count);
}

void PlyBulkReader::non_finite(const RawChunk& chunk, size_t i, const Point& v) const {
  throw_bad_input(name_, byte_place(chunk.offset + i * vertex_record_),
                  "vertex " + std::to_string(vertices_done_ + i) + " has a non-finite coordinate (" +
                      std::to_string(v[0]) + ", " + std::to_string(v[1]) + ", " + std::to_string(v[2]) + ")");
}

void PlyBulkReader::vertices_decoded(const RawChunk& chunk, size_t count) {
  const PlyElement& element = header_.elements[header_.vertex_element];
  vertices_done_ += count;
  if (chunk.last && vertices_done_ < vertex_count_) {
    truncated(element.name, element.count, vertices_done_, chunk.offset + count * vertex_record_, vertex_record_,
              chunk.size - count * vertex_record_);
  }
}

bool PlyBulkReader::decode_float_vertices(const RawChunk& chunk, float* xyz, uint64_t capacity, uint64_t& first,
                                          uint64_t& count) {
  if (chunk.part != RawChunk::Part::vertices || !vertex_layout(header_).packed_floats) return false;
  const size_t n = size_t(std::min<uint64_t>(chunk.size / 12, vertex_count_ - vertices_done_));
  if (vertices_done_ + n > capacity) return false;
  put_float_vertices(chunk, n, xyz + 3 * vertices_done_, first, count);
  return true;
}

bool PlyBulkReader::decode_float_vertices(const RawChunk& chunk, UninitializedVector<float>& xyz, uint64_t& first,
                                          uint64_t& count) {
  if (chunk.part != RawChunk::Part::vertices || !vertex_layout(header_).packed_floats) return false;
  const size_t n = size_t(std::min<uint64_t>(chunk.size / 12, vertex_count_ - vertices_done_));
  xyz.resize(3 * n);
  put_float_vertices(chunk, n, xyz.data(), first, count);
  return true;
}

void PlyBulkReader::put_float_vertices(const RawChunk& chunk, size_t n, float* out, uint64_t& first,
                                       uint64_t& count) {
  const char* p = chunk.bytes.get();
  uint32_t* bits = reinterpret_cast<uint32_t*>(out);
  // All exponent bits set: infinite or NaN. One branch-free sweep (fused with the copy
  // of a little-endian file, four floats a step: -O2 leaves the loop scalar), then the first one.
  const size_t floats = 3 * n, whole = floats / 4 * 4;
  const __m128i exponent = _mm_set1_epi32(0x7f800000);
  __m128i any = _mm_setzero_si128();
  if (header_.format == MeshFormat::ply_binary_be) {
    for (size_t i = 0; i < floats; ++i) bits[i] = load32<true>(p + 4 * i);
    for (size_t i = 0; i < whole; i += 4) {
      const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(bits + i));
      any = _mm_or_si128(any, _mm_cmpeq_epi32(_mm_and_si128(v, exponent), exponent));
    }
  } else {
    for (size_t i = 0; i < whole; i += 4) {
      const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 4 * i));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(bits + i), v);
      any = _mm_or_si128(any, _mm_cmpeq_epi32(_mm_and_si128(v, exponent), exponent));
    }
    std::memcpy(bits + whole, p + 4 * whole, 4 * (floats - whole));
  }
  bool finite = _mm_movemask_epi8(any) == 0;
  for (size_t i = whole; i < floats; ++i) finite &= (bits[i] & 0x7f800000u) != 0x7f800000u;
  if (!finite) {
    for (size_t i = 0; i < n; ++i) {
      const Point v{out[3 * i], out[3 * i + 1], out[3 * i + 2]};
      if (!all_finite(v)) non_finite(chunk, i, v);
    }
  }
  first = vertices_done_;
  count = n;
  vertices_decoded(chunk, n);
}

// The face record at `record` (`left` bytes available, file offset `offset`): its
// length once all of it is there, its triangles appended at out[used...]; else 0 and
// `needed`, the bytes known to be required. The same checks, in the same order and
// words, as the streaming reader's binary_faces.
template <bool Swap, class Out>
size_t PlyBulkReader::face_record(const char* record, size_t left, uint64_t offset, size_t& needed, Out& out,
                                  size_t& used) {
  const PlyElement& element = header_.elements[*header_.face_element];
  const PlyProperty& list = element.properties[header_.index_property];
  const size_t count_size = size_of(list.count_type);
  const size_t index_size = size_of(list.type);
  auto face_name = [this] { return "face " + std::to_string(faces_done_); };
  size_t list_offset = 0;
  size_t length = 0;
  if (element.properties.size() == 1) {
    if (left < count_size) {
      needed = count_size;
      return 0;
    }
    int64_t count = load_integer<Swap>(list.count_type, record);
    if (count < 3) {
      throw_bad_input(name_, byte_place(offset),
                      face_name() + " has " + std::to_string(count) + " vertices (a face needs at least 3)");
    }
    length = count_size + size_t(count) * index_size;
    if (length > max_record_bytes) {
      throw_bad_input(name_, byte_place(offset),
                      face_name() + " has an implausible " + std::to_string(count) + " vertices");
    }
    if (count >= streamed_polygon_vertices) {  // decode_faces reads its indices as they come
      polygon_left_ = uint64_t(count);
      polygon_offset_ = offset;
      polygon_length_ = length;
      return count_size;
    }
  } else {
    length = record_length<Swap>(element, record, left, needed, &list_offset, header_.index_property,
                                 [&](const std::string& problem) {
                                   throw_bad_input(name_, byte_place(offset), element.name + " " +
                                                                                 std::to_string(faces_done_) + " " + problem);
                                 });
    if (length == 0) return 0;
  }
  if (length > left) {
    needed = length;
    return 0;
  }
  int64_t count = load_integer<Swap>(list.count_type, record + list_offset);
  if (count < 3) {
    throw_bad_input(name_, byte_place(offset),
                    face_name() + " has " + std::to_string(count) + " vertices (a face needs at least 3)");
  }
  if (out.size() < used + size_t(count)) out.resize(2 * out.size() + size_t(count));
  PolygonFan fan;
  fan_indices<Swap>(fan, list.type, record + list_offset + count_size, size_t(count), offset, out, used);
  ++faces_done_;
  return length;
}

void PlyBulkReader::bad_index(int64_t index, uint64_t offset) const {
  throw_bad_input(name_, byte_place(offset),
                  "face " + std::to_string(faces_done_) + " has vertex index " + std::to_string(index) +
                      " but the file has " + std::to_string(vertex_count_) + " vertices");
}

// Checks `count` indices of `type` at p and adds them to `fan`, its triangles at
// out[used...] (room made by the caller); `offset` is their record's, for errors.
template <bool Swap, class Out>
void PlyBulkReader::fan_indices(PolygonFan& fan, PlyType type, const char* p, size_t count, uint64_t offset,
                                Out& out, size_t& used) const {
  const size_t index_size = size_of(type);
  for (size_t i = 0; i < count; ++i) {
    int64_t index = load_integer<Swap>(type, p + i * index_size);
    if (index < 0 || uint64_t(index) >= vertex_count_) bad_index(index, offset);
    fan.add(uint64_t(index), [&](uint64_t a, uint64_t b, uint64_t c) { out.set(used++, a, b, c); });
  }
}

// `count` whole indices of the streamed polygon at p, its triangles appended at out[used...].
template <bool Swap, class Out>
void PlyBulkReader::polygon_indices(const char* p, size_t count, Out& out, size_t& used) {
  const PlyElement& element = header_.elements[*header_.face_element];
  const PlyType type = element.properties[header_.index_property].type;
  if (out.size() < used + count) out.resize(std::max(used + count, out.size() + out.size() / 2));
  fan_indices<Swap>(fan_, type, p, count, polygon_offset_, out, used);
  polygon_left_ -= count;
  if (polygon_left_ == 0) {
    fan_.reset();
    ++faces_done_;
  }
}

void PlyBulkReader::truncated_polygon(size_t found_after) const {
  const PlyElement& element = header_.elements[*header_.face_element];
  const size_t index_size = size_of(element.properties[header_.index_property].type);
  truncated(element.name, element.count, faces_done_, polygon_offset_, polygon_length_,
            polygon_length_ - polygon_left_ * index_size + found_after);
}

template <bool Swap, class Out>
size_t PlyBulkReader::fast_triangles(const char* p, size_t limit, uint64_t offset, Out& out, size_t used) const {
  const PlyProperty& list = header_.elements[*header_.face_element].properties[header_.index_property];
  const bool signed_index = list.type == PlyType::int32;
  // In a local: the records' byte stores may alias the member.
  const uint64_t vertex_count = vertex_count_;
  size_t i = 0;
  for (; i < limit; ++i) {
    const char* r = p + i * 13;
    if (static_cast<uint8_t>(*r) != 3) break;
    uint32_t a = load32<Swap>(r + 1), b = load32<Swap>(r + 5), c = load32<Swap>(r + 9);
    // For signed int, negative values become huge as uint32 and fail this test too.
    if (a >= vertex_count || b >= vertex_count || c >= vertex_count) {
      uint32_t bad = a >= vertex_count ? a : b >= vertex_count ? b : c;
      int64_t shown = signed_index ? int64_t{static_cast<int32_t>(bad)} : int64_t{bad};
      throw_bad_input(name_, byte_place(offset + i * 13),
                      "face " + std::to_string(faces_done_ + i) + " has vertex index " + std::to_string(shown) +
                          " but the file has " + std::to_string(vertex_count_) + " vertices");
    }
    out.set(used + i, a, b, c);
  }
  return i;
}

template <bool Swap, class Out>
void PlyBulkReader::decode_faces(const RawChunk& chunk, uint64_t& first_triangle, Out out) {
  first_triangle = triangles_done_;
  out.resize(0);
  if (!header_.face_element) return;
  const PlyElement& element = header_.elements[*header_.face_element];
  const PlyProperty& list = element.properties[header_.index_property];
  const bool fast = fixed_triangles();
  out.resize(chunk.size / 13 + 8);
  size_t used = 0;
  const char* p = chunk.bytes.get();
  size_t pos = 0;
  size_t needed = 0;
  auto finish = [&] { out.resize(used); triangles_done_ += used; };
  const size_t index_size = size_of(list.type);
  // A streamed polygon whose index was cut by the previous range's end: that index first.
  if (polygon_left_ > 0 && !carry_.empty()) {
    const size_t take = std::min(index_size - carry_.size(), chunk.size);
    carry_.insert(carry_.end(), p, p + take);
    pos = take;
    if (carry_.size() < index_size) {
      if (chunk.last) truncated_polygon(carry_.size());
      return finish();
    }
    polygon_indices<Swap>(carry_.data(), 1, out, used);
    carry_.clear();
  }
  // A record cut by the end of the previous range: completed from this one.
  while (!carry_.empty() && faces_done_ < face_count_) {
    if (face_record<Swap>(carry_.data(), carry_.size(), carry_offset_, needed, out, used) > 0) {
      carry_.clear();
      break;
    }
    size_t take = std::min(needed - carry_.size(), chunk.size - pos);
    if (take == 0) {
      if (chunk.last) truncated(element.name, element.count, faces_done_, carry_offset_, needed, carry_.size());
      return finish();
    }
    carry_.insert(carry_.end(), p + pos, p + pos + take);
    pos += take;
  }
  while (faces_done_ < face_count_ && pos < chunk.size) {
    if (polygon_left_ > 0) {
      const size_t fit = size_t(std::min<uint64_t>(polygon_left_, (chunk.size - pos) / index_size));
      if (fit == 0) {  // an index cut by the range's end
        carry_.assign(p + pos, p + chunk.size);
        pos = chunk.size;
        break;
      }
      polygon_indices<Swap>(p + pos, fit, out, used);
      pos += fit * index_size;
      continue;
    }
    if (fast) {
      size_t limit = size_t(std::min<uint64_t>(face_count_ - faces_done_, (chunk.size - pos) / 13));
      if (out.size() < used + limit) out.resize(used + limit);
      const size_t i = fast_triangles<Swap>(p + pos, limit, chunk.offset + pos, out, used);
      used += i;
      faces_done_ += i;
      pos += i * 13;
      if (faces_done_ == face_count_ || pos == chunk.size) break;
    }
    size_t length = face_record<Swap>(p + pos, chunk.size - pos, chunk.offset + pos, needed, out, used);
    if (length == 0) {
      carry_.assign(p + pos, p + chunk.size);
      carry_offset_ = chunk.offset + pos;
      if (chunk.last) truncated(element.name, element.count, faces_done_, carry_offset_, needed, carry_.size());
      pos = chunk.size;
      break;
    }
    pos += length;
  }
  if (faces_done_ == face_count_ && pos < chunk.size) {
    check_trailing_bytes(name_, p + pos, chunk.size - pos, chunk.offset + pos, element);
  }
  if (chunk.last && polygon_left_ > 0) truncated_polygon(carry_.size());
  if (chunk.last && faces_done_ < face_count_) {
    // The file ends exactly between records.
    face_record<Swap>(p, 0, chunk.offset + chunk.size, needed, out, used);
    truncated(element.name, element.count, faces_done_, chunk.offset + chunk.size, needed, 0);
  }
  finish();
}

bool PlyBulkReader::float_coordinates() const {
  const VertexLayout layout = vertex_layout(header_);
  return layout.types[0] == PlyType::float32 && layout.types[1] == PlyType::float32 &&
         layout.types[2] == PlyType::float32;
}

std::unique_ptr<PlyBulkReader> open_ply_bulk_reader(const std::filesystem::path& path) {
  MeshFileKind kind = mesh_file_kind(path);
  if (kind.obj || kind.zstd) return nullptr;
  ByteSource source(path, false, size_t{1} << 16);
  PlyHeader header = read_ply_header(source);
  if (header.format == MeshFormat::ply_ascii || header.vertex_element != 0) return nullptr;
  if (header.elements[0].fixed_record_size() == 0) return nullptr;
  if (header.elements.size() > 2 || (header.elements.size() == 2 && header.face_element != 1)) return nullptr;
  return std::make_unique<PlyBulkReader>(path, std::move(header), source.file_size());
}

size_t encode_ply_vertices(const Point* points, size_t count, bool double_precision, char* out) {
  if (double_precision) {
    std::memcpy(out, points, count * sizeof(Point));
    return count * sizeof(Point);
  }
  for (size_t i = 0; i < count; ++i, out += 12) {
    const float xyz[3] = {static_cast<float>(points[i][0]), static_cast<float>(points[i][1]),
                          static_cast<float>(points[i][2])};
    std::memcpy(out, xyz, 12);
  }
  return count * 12;
}

namespace {
template <class Index>
size_t encode_triangles(const Index* ids, size_t count, char* out, uint64_t& max_index) {
  uint64_t largest = 0;
  for (size_t i = 0; i < count; ++i, out += 13, ids += 3) {
    const uint32_t abc[3] = {static_cast<uint32_t>(ids[0]), static_cast<uint32_t>(ids[1]),
                             static_cast<uint32_t>(ids[2])};
    largest = std::max({largest, uint64_t(ids[0]), uint64_t(ids[1]), uint64_t(ids[2])});
    out[0] = 3;
    std::memcpy(out + 1, abc, 12);
  }
  max_index = std::max(max_index, largest);
  return count * 13;
}
}  // namespace

size_t encode_ply_triangles(const Triangle* triangles, size_t count, char* out, uint64_t& max_index) {
  return encode_triangles(reinterpret_cast<const uint64_t*>(triangles), count, out, max_index);
}
size_t encode_ply_triangles(const uint32_t* triangles, size_t count, char* out, uint64_t& max_index) {
  return encode_triangles(triangles, count, out, max_index);
}

}  // namespace qemflow::io
