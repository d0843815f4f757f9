#include <oneapi/tbb/parallel_for.h>
#include <emmintrin.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <optional>
#include <unordered_map>

#include <oneapi/tbb/parallel_sort.h>

#include "config/size.hpp"
#include "engine/blocks.hpp"
#include "engine/face_cells.hpp"
#include "engine/process_memory.hpp"
#include "engine/spill.hpp"
#include "engine/stream_pass.hpp"
#include "io/byte_source.hpp"
#include "io/mesh_file_kind.hpp"
#include "io/mesh_stream.hpp"
#include "io/ply_bulk.hpp"
#include "io/ply_header.hpp"
#include "util/error.hpp"
#include "util/hash.hpp"
#include "util/memory.hpp"

namespace qemflow::engine {

namespace {

struct CornerRef {
  uint64_t corner;  // face id * 3 + corner
  uint64_t vertex;
};
struct LocalFace {
  uint64_t id;
  Triangle vertices;
};
struct ResolvedCorner {
  uint64_t corner;
  uint64_t vertex;
  Point position;
};

// Weld keys: the bits of each coordinate with -0.0 as 0.0. Equal keys are equal
// positions (==) unless a coordinate is NaN, which never welds (as in core).
using PositionKey = std::array<uint64_t, 3>;
PositionKey position_key(const Point& p) {
  PositionKey key;
  for (int k = 0; k < 3; ++k) {
    double x = p[k] == 0.0 ? 0.0 : p[k];
    std::memcpy(&key[k], &x, sizeof x);
  }
  return key;
}
bool weldable(const Point& p) { return !std::isnan(p[0]) && !std::isnan(p[1]) && !std::isnan(p[2]); }
uint32_t weld_bucket(const Point& p, uint32_t buckets) {
  PositionKey k = position_key(p);
  return uint32_t(mix64(k[0] ^ mix64(k[1] ^ mix64(k[2] + 0x9E3779B97F4A7C15ull))) % buckets);
}
struct WeldRecord {
  Point position;
  uint64_t index;
};

// Welded ids: only the duplicates (index → representative, sorted by index) and a bit
// per vertex marking them. Read-only once finished (any thread).
struct WeldMap {
  std::vector<uint64_t> bits;
  std::vector<std::pair<uint64_t, uint64_t>> duplicates;
  void finish(uint64_t vertex_count) {
    std::sort(duplicates.begin(), duplicates.end());
    bits.assign((vertex_count + 63) / 64, 0);
    for (const auto& d : duplicates) bits[d.first >> 6] |= uint64_t{1} << (d.first & 63);
  }
  // Over n vertices sorted by (position, index): each one at the position of its
  // predecessor maps to the first of its run.
  template <class PositionAt, class IndexAt>
  void add_runs(uint64_t n, PositionAt position_at, IndexAt index_at) {
    uint64_t first = 0;
    for (uint64_t i = 1; i < n; ++i) {
      const Point p = position_at(i);
      if (weldable(p) && position_key(p) == position_key(position_at(first))) {
        duplicates.emplace_back(index_at(i), index_at(first));
      } else {
        first = i;
      }
    }
  }
  uint64_t operator()(uint64_t v) const {
    if (bits.empty() || !((bits[v >> 6] >> (v & 63)) & 1)) return v;
    return std::lower_bound(duplicates.begin(), duplicates.end(), std::pair<uint64_t, uint64_t>{v, 0})->second;
  }
};

// Faces around each welded vertex: a byte per vertex, saturating at 255; the exact
// count of those few is kept on the side. Counted by one thread (a sink).
struct DegreeCounter {
  std::vector<uint8_t> low;
  std::unordered_map<uint64_t, uint32_t> high;
  void add(uint64_t v) {
    if (low[v] < 255) {
      if (++low[v] == 255) high[v] = 255;
    } else {
      ++high[v];
    }
  }
  uint32_t operator[](uint64_t v) const { return low[v] < 255 ? low[v] : high.at(v); }
};

bool repeated(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }

// Lease per element of an input batch: the batch itself (24 bytes per vertex or
// triangle) plus what the transform makes of it (a compressed vertex frame, or a block
// record of up to 120 bytes and its cell) plus the reader library's own buffers.
constexpr uint64_t bytes_per_input_element = 160;
constexpr uint64_t min_input_lease = 64 * bytes_per_input_element;
constexpr uint64_t max_input_lease = 4ull << 20;
// The least the loader's reservation holds (its three spills at their minimum), and
// what it leaves the streamed items at least: loader_minimum_bytes() is their sum.
uint64_t reserve_minimum_bytes() { return 3 * BucketSpill::min_lease_bytes(sizeof(BlockFace)); }
constexpr uint64_t items_minimum_bytes = 4 * max_input_lease;
// How many faces ahead the face loops prefetch their vertex positions: enough to
// cover a miss to memory at a few ns a face.
constexpr size_t prefetch_faces_ahead = 16;
// Asks for vertex `at`'s position: in `xyz` (3 floats a vertex) when `floats`, else in
// `points`.
inline void prefetch_position(bool floats, const float* xyz, const Point* points, uint64_t at) {
  if (floats) {
    __builtin_prefetch(xyz + 3 * at);
  } else {
    __builtin_prefetch(points + at);
  }
}

// u32(a) then u32(b) at `out`, as one 8-byte store. Built in an array instead, the
// record went through the stack as 4-byte stores read back as 8 bytes, a failed store
// forward each face (a quarter of the resident face loop's time).
inline void put_u32_pair(std::byte* out, uint64_t a, uint64_t b) {
  static_assert(std::endian::native == std::endian::little);
  const uint64_t pair = uint64_t(uint32_t(a)) | uint64_t(uint32_t(b)) << 32;
  std::memcpy(out, &pair, sizeof pair);
}

// The vertex ids of an id_triangle32 record (face id, a, b, c as u32s).
inline std::array<uint32_t, 3> id_record_vertices(const std::byte* record) {
  std::array<uint32_t, 3> abc;
  std::memcpy(abc.data(), record + sizeof(uint32_t), sizeof abc);
  return abc;
}

struct Box {
  Point min{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
            std::numeric_limits<double>::infinity()};
  Point max{-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
            -std::numeric_limits<double>::infinity()};
  bool float_exact = true;
  void add(const Point& p) {
    for (int i = 0; i < 3; ++i) {
      min[i] = std::min(min[i], p[i]);
      max[i] = std::max(max[i], p[i]);
      float_exact = float_exact && double(float(p[i])) == p[i];
    }
  }
  // add(p) for n points given as xyz floats, in turn (floats are float-exact).
  // Four points a step in float lanes (the scalar loop was a chain of dependent
  // double min/max a coordinate, ~35 instructions a point): min and max are the same
  // values in float, whose comparisons are the doubles', in any order, but for which
  // zero of a tie between -0 and +0 came first; an axis whose bound is zero is done
  // again in turn.
  void add_floats(const float* xyz, size_t n) {
    const Box before = *this;
    const size_t whole = n / 4 * 4;
    if (whole > 0) {
      // Lanes of the three loads of four points: (x y z x), (y z x y), (z x y z).
      __m128 lo[3], hi[3];
      for (int k = 0; k < 3; ++k) {
        lo[k] = _mm_set1_ps(std::numeric_limits<float>::infinity());  // a NaN is then never taken, as in turn
        hi[k] = _mm_set1_ps(-std::numeric_limits<float>::infinity());
      }
      for (size_t j = 0; j < whole; j += 4) {
        for (int k = 0; k < 3; ++k) {
          const __m128 v = _mm_loadu_ps(xyz + 3 * j + 4 * k);
          lo[k] = _mm_min_ps(v, lo[k]);  // (v < lo) ? v : lo, as std::min(lo, v)
          hi[k] = _mm_max_ps(v, hi[k]);
        }
      }
      alignas(16) float l[3][4], h[3][4];
      for (int k = 0; k < 3; ++k) {
        _mm_store_ps(l[k], lo[k]);
        _mm_store_ps(h[k], hi[k]);
      }
      fold_lanes(l, h);
    }
    add_in_turn(xyz + 3 * whole, n - whole, {0, 1, 2});
    redo_zero_bounds(before, xyz, n);
  }
  // add(p) for each point in turn: the same min, max and float_exact. Two points a
  // step in double lanes, as add_floats (the scalar loop's dependent min, max and
  // float test a coordinate were half the out-of-core load's transform).
  void add(const Point* points, size_t n) {
    static_assert(sizeof(Point) == 3 * sizeof(double));
    const Box before = *this;
    const double* xyz = points[0].data();
    const size_t whole = n / 2 * 2;
    __m128d exact = _mm_castsi128_pd(_mm_set1_epi32(-1));
    if (whole > 0) {
      // Lanes of the three loads of two points: (x y), (z x), (y z).
      __m128d lo[3], hi[3];
      for (int k = 0; k < 3; ++k) {
        lo[k] = _mm_set1_pd(std::numeric_limits<double>::infinity());
        hi[k] = _mm_set1_pd(-std::numeric_limits<double>::infinity());
      }
      for (size_t j = 0; j < whole; j += 2) {
        for (int k = 0; k < 3; ++k) {
          const __m128d v = _mm_loadu_pd(xyz + 3 * j + 2 * k);
          lo[k] = _mm_min_pd(v, lo[k]);
          hi[k] = _mm_max_pd(v, hi[k]);
          exact = _mm_and_pd(exact, _mm_cmpeq_pd(_mm_cvtps_pd(_mm_cvtpd_ps(v)), v));  // NaN: not exact
        }
      }
      alignas(16) double l[3][2], h[3][2];
      for (int k = 0; k < 3; ++k) {
        _mm_store_pd(l[k], lo[k]);
        _mm_store_pd(h[k], hi[k]);
      }
      fold_lanes(l, h);
    }
    bool all_exact = _mm_movemask_pd(exact) == 3;
    for (size_t i = 3 * whole; i < 3 * n; ++i) all_exact &= double(float(xyz[i])) == xyz[i];
    add_in_turn(xyz + 3 * whole, n - whole, {0, 1, 2});
    redo_zero_bounds(before, xyz, n);
    float_exact = float_exact && all_exact;
  }
  // The lanes' bounds into the box: lane `lane` of load k holds axis (W k + lane) % 3.
  template <class T, int W>
  void fold_lanes(const T (&l)[3][W], const T (&h)[3][W]) {
    for (int k = 0; k < 3; ++k) {
      for (int lane = 0; lane < W; ++lane) {
        const int axis = (W * k + lane) % 3;
        min[axis] = std::min(min[axis], double(l[k][lane]));
        max[axis] = std::max(max[axis], double(h[k][lane]));
      }
    }
  }
  // Axes whose bound came out zero, from `before` with the n points in turn.
  template <class T>
  void redo_zero_bounds(const Box& before, const T* xyz, size_t n) {
    for (int i = 0; i < 3; ++i) {
      if (min[i] != 0 && max[i] != 0) continue;
      min[i] = before.min[i];
      max[i] = before.max[i];
      add_in_turn(xyz, n, {i});
    }
  }
  template <class T>
  void add_in_turn(const T* xyz, size_t n, std::initializer_list<int> axes) {
    for (int i : axes) {
      double lo = min[i], hi = max[i];
      for (size_t j = 0; j < n; ++j) {
        const double x = xyz[3 * j + i];
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
      min[i] = lo;
      max[i] = hi;
    }
  }
  void add(const Box& other) {
    for (int i = 0; i < 3; ++i) {
      min[i] = std::min(min[i], other.min[i]);
      max[i] = std::max(max[i], other.max[i]);
    }
    float_exact = float_exact && other.float_exact;
  }
};

// Doubles to floats, four a step (-O2 leaves the loop scalar); each float(x).
void narrow_to_floats(const double* in, size_t n, float* out) {
  const size_t whole = n / 4 * 4;
  for (size_t i = 0; i < whole; i += 4) {
    const __m128 lo = _mm_cvtpd_ps(_mm_loadu_pd(in + i)), hi = _mm_cvtpd_ps(_mm_loadu_pd(in + i + 2));
    _mm_storeu_ps(out + i, _mm_movelh_ps(lo, hi));
  }
  for (size_t i = whole; i < n; ++i) out[i] = float(in[i]);
}

Point barycenter(const std::array<Point, 3>& p) {
  return {(p[0][0] + p[1][0] + p[2][0]) / 3, (p[0][1] + p[1][1] + p[2][1]) / 3,
          (p[0][2] + p[1][2] + p[2][2]) / 3};
}

[[noreturn]] void index_out_of_range(const std::filesystem::path& input, uint64_t face,
                                     uint64_t vertex, uint64_t count) {
  throw_bad_input(input.string(), "triangle " + std::to_string(face),
                  "vertex index " + std::to_string(vertex) + " out of range (" +
                      std::to_string(count) + " vertices)");
}

// Out of core, a face whose vertex ids lo <= hi lie in one chunk or two neighbouring
// ones is *local*: resolved with chunk lo / chunk and the next. Its bucket, or
// UINT32_MAX for a face that spans farther (hi / chunk <= lo / chunk + 1, with one
// division instead of two).
uint32_t local_bucket(uint64_t lo, uint64_t hi, uint64_t chunk) {
  const uint64_t lo_chunk = lo / chunk;
  return hi < (lo_chunk + 2) * chunk ? uint32_t(lo_chunk) : UINT32_MAX;
}

// local_bucket without a division a face (a 64-bit div was most of the out-of-core
// face classification's time): the quotient from a reciprocal in double, within one
// of the true one below 2^52, then corrected. The same buckets.
struct LocalBuckets {
  uint64_t chunk;
  double reciprocal = 1.0 / double(chunk);
  uint32_t operator()(uint64_t lo, uint64_t hi) const {
    if (lo >= (uint64_t(1) << 52)) return local_bucket(lo, hi, chunk);
    uint64_t q = uint64_t(double(lo) * reciprocal);
    if (q * chunk > lo) --q;
    else if ((q + 1) * chunk <= lo) ++q;
    return hi < (q + 2) * chunk ? uint32_t(q) : UINT32_MAX;
  }
  // The same for u32 ids (the decoded local records'), with one multiply a face: the
  // quotient is the high half of lo times ceil(2^64 / chunk), exact for every u32 lo
  // and chunk from 2 (Lemire, Kaser and Kurz, "Faster remainder by direct computation",
  // 2019; for 1 it wraps to 0), where the double's conversions and corrections were a
  // quarter of the load's transform.
  uint64_t magic = chunk > 1 && chunk <= UINT32_MAX ? UINT64_MAX / chunk + 1 : 0;
  uint32_t operator()(uint32_t lo, uint32_t hi) const {
    if (magic == 0) return (*this)(uint64_t(lo), uint64_t(hi));
    const uint64_t q = uint64_t(__uint128_t(magic) * lo >> 64);
    return hi < (q + 2) * chunk ? uint32_t(q) : UINT32_MAX;
  }
};

// fn(cell, begin, end) for each run [begin, end) of equal cells: neighbouring faces
// mostly share a block or bucket, so records are filed a run at a time.
template <class Fn>
void for_each_cell_run(const uint32_t* cells, uint64_t count, Fn&& fn) {
  for (uint64_t i = 0; i < count;) {
    uint64_t end = i + 1;
    while (end < count && cells[end] == cells[i]) ++end;
    fn(cells[i], i, end);
    i = end;
  }
}

uint32_t block_count_for(uint64_t faces, uint64_t faces_per_block) {
  uint64_t blocks = (faces + faces_per_block - 1) / std::max<uint64_t>(faces_per_block, 1);
  return uint32_t(std::clamp<uint64_t>(blocks, 1, 4096));
}

// What a .zst input's decoder needs beyond the window every run already counts in the
// governor's baseline margin (io/byte_source.hpp; the shared meshes' tests at 40-60M
// run with such windows unleased); 0 for other inputs.
uint64_t input_window_bytes(const std::filesystem::path& input) {
  return io::mesh_file_kind(input).zstd ? io::zstd_decoder_bytes_to_reserve(input) : 0;
}

// One input batch on its way through the load pass.
struct InputItem {
  io::RawChunk raw;                                       // bulk input: the bytes as read
  io::MeshBatch batch;
  Box box;
  std::vector<std::pair<uint64_t, Bytes>> vertex_frames;  // (window, frame)
  Bytes block_records;                                    // faces made into block records
  std::vector<uint32_t> cells;                            // and their cells
  uint64_t dropped = 0;                                   // faces with a repeated welded vertex
  uint64_t max_index = 0;                                 // out of core: the largest vertex index
  bool classified = false;  // out of core: block_records hold u32 ids, cells the local bucket (or UINT32_MAX)
  // Resident re-encode: the faces were decoded straight into block_records as u32
  // triples (triangle32 records) or PLY face records, and batch.triangles stays empty;
  // out of core, as (face id, triple) records (id_triangle32) the same way.
  bool records_decoded = false;
  // Float vertices decoded without batches, this many from batch.first_vertex
  // (batch.vertices stays empty): a resident re-encode's straight into the vertex
  // array (InputStream::vertex_xyz), an out-of-core load's into `xyz`.
  uint64_t xyz_decoded = 0;
  // Out-of-core float load: those vertices are here instead (InputStream::vertex_floats).
  UninitializedVector<float> xyz;
  // With records_decoded: or ply_triangle_record_size, or out of core id_triangle32_record_size.
  uint32_t decoded_record_size = triangle32_record_size;
  // With records_decoded: the records are the input's own bytes, `raw`, checked where
  // they lie (PLY face records from a file that holds just those), not block_records.
  bool records_in_raw = false;
  const std::byte* records() const {
    return records_in_raw ? reinterpret_cast<const std::byte*>(raw.bytes.get()) : block_records.data();
  }
  uint64_t triangle_count() const {
    if (!records_decoded) return batch.triangles.size();
    return (records_in_raw ? raw.size : block_records.size()) / decoded_record_size;
  }
};

// The buffers items leave behind (block records and cells), for later items to decode
// into: a fresh buffer is fresh pages, faulted in one by one (a third of a resident
// re-encode's page faults were those). Kept under `lease`, taken for the pass from the
// loader's reservation; a buffer it cannot cover is freed.
struct SpareItemBuffers {
  std::mutex mutex;
  Lease lease;
  uint64_t kept_bytes = 0;
  std::vector<std::pair<Bytes, std::vector<uint32_t>>> kept;
  static uint64_t bytes_of(const Bytes& records, const std::vector<uint32_t>& cells) {
    return records.capacity() + cells.capacity() * sizeof(uint32_t);
  }
  void lend(InputItem& item) {
    std::lock_guard lock(mutex);
    if (kept.empty()) return;
    kept_bytes -= bytes_of(kept.back().first, kept.back().second);
    item.block_records = std::move(kept.back().first);
    item.cells = std::move(kept.back().second);
    kept.pop_back();
  }
  void keep(InputItem& item) {
    const uint64_t bytes = bytes_of(item.block_records, item.cells);
    std::lock_guard lock(mutex);
    if (kept_bytes + bytes > lease.bytes()) return;
    kept_bytes += bytes;
    kept.emplace_back(std::move(item.block_records), std::move(item.cells));
  }
  // Every kept buffer freed; the lease is left to its owner.
  void clear() {
    std::lock_guard lock(mutex);
    kept.clear();
    kept_bytes = 0;
  }
};

// The input, read from the I/O thread. A binary PLY goes through the bulk reader:
// the I/O thread only reads byte ranges and decode() (a compute thread, ranges in
// read order) parses them; any other input through the streaming reader, which
// parses on the I/O thread.
struct InputStream {
  std::unique_ptr<io::PlyBulkReader> bulk;
  std::unique_ptr<io::MeshReader> reader;
  std::filesystem::path path;
  uint64_t size = 0;
  void open() {
    close();  // one decoder (and its window) at a time
    carried.reset();
    vertices_done = false;
    bulk = io::open_ply_bulk_reader(path);
    if (!bulk) reader = io::open_mesh_reader(path);
  }
  void close() {
    bulk.reset();
    reader.reset();
  }
  const io::MeshInfo& info() const { return bulk ? bulk->info() : reader->info(); }
  bool float_coordinates() const { return bulk && bulk->float_coordinates(); }
  uint64_t bytes_read() const { return bulk ? bulk->bytes_read() : reader->bytes_read(); }
  bool read(InputItem& item, Lease& lease) {
    size_t elements = std::max<uint64_t>(lease.bytes() / bytes_per_input_element, 64);
    if (bulk) return bulk->read(item.raw, elements * io::ply_triangle_bytes);
    return reader->next(item.batch, elements) &&
           (!item.batch.vertices.empty() || !item.batch.triangles.empty());
  }
  // Faces ranges decoded as block records of this size (triangle32 or PLY face
  // records, out of core (face id, triple) id_triangle32 records;
  // InputItem::records_decoded), into the buffers of earlier items when
  // `spare` has some. 0: decoded to batches.
  uint32_t decoded_records = 0;
  SpareItemBuffers* spare = nullptr;
  // Compute side of the bulk reader: one item at a time, in read order.
  // Vertex ranges decoded straight into this array of `vertex_xyz_capacity` vertices
  // (InputItem::xyz_decoded) where the file's layout allows.
  float* vertex_xyz = nullptr;
  uint64_t vertex_xyz_capacity = 0;
  // Out of core: vertex ranges decoded into each item's own xyz (InputItem::xyz) where
  // the file's layout allows, instead of Points narrowed back to floats.
  bool vertex_floats = false;
  void decode(InputItem& item) {
    if (!bulk) return;
    item.xyz_decoded = 0;
    item.records_in_raw = false;
    if (vertex_xyz && item.raw.part == io::RawChunk::Part::vertices &&
        bulk->decode_float_vertices(item.raw, vertex_xyz, vertex_xyz_capacity, item.batch.first_vertex,
                                    item.xyz_decoded)) {
      item.batch.vertices.clear();
    } else if (vertex_floats && item.raw.part == io::RawChunk::Part::vertices &&
               bulk->decode_float_vertices(item.raw, item.xyz, item.batch.first_vertex, item.xyz_decoded)) {
      item.batch.vertices.clear();
    } else if (decoded_records && item.raw.part == io::RawChunk::Part::faces) {
      if (spare) spare->lend(item);
      if (decoded_records == ply_triangle_record_size) {
        uint64_t checked = 0;
        // No copy where the bytes read are the records already.
        item.records_in_raw = bulk->check_ply_triangles(item.raw, item.batch.first_triangle, checked);
        if (!item.records_in_raw) bulk->decode_ply_triangles(item.raw, item.block_records, item.batch.first_triangle);
      } else if (decoded_records == id_triangle32_record_size) {
        bulk->decode_id_triangles32(item.raw, item.block_records, item.batch.first_triangle);
      } else {
        bulk->decode_triangles32(item.raw, item.block_records, item.batch.first_triangle);
      }
      item.records_decoded = true;
      item.decoded_record_size = decoded_records;
    } else {
      bulk->decode(item.raw, item.batch);
    }
    if (!item.records_in_raw) item.raw.clear();
  }
  // Vertices first, then faces, as two passes: the vertex pass ends at the first
  // triangle, which is carried over to the face pass (the bulk reader's ranges are
  // all vertices or all faces, so it ends where the faces begin).
  std::optional<io::MeshBatch> carried;
  bool vertices_done = false;
  bool read_vertices(InputItem& item, Lease& lease) {
    if (bulk) return !bulk->past_vertices() && read(item, lease);
    if (vertices_done || !read(item, lease)) return false;
    if (!item.batch.triangles.empty()) {
      vertices_done = true;
      carried.emplace();
      carried->first_triangle = item.batch.first_triangle;
      carried->triangles = std::move(item.batch.triangles);
      item.batch.triangles.clear();
    }
    return !item.batch.vertices.empty();
  }
  bool read_faces(InputItem& item, Lease& lease) {
    if (bulk) return read(item, lease);
    if (carried) {
      item.batch = std::move(*carried);
      carried.reset();
      return true;
    }
    if (!read(item, lease)) return false;
    if (!item.batch.vertices.empty()) {
      throw_bad_input(path.string(), "vertex " + std::to_string(item.batch.first_vertex),
                      "vertices after the first face");
    }
    return true;
  }
};

// Writes finished vertex frames to one scratch file per window. Serial (a sink).
class VertexFrameWriter {
 public:
  VertexFrameWriter(Job& job, ScratchStore& scratch, VertexStore& store)
      : job_(job), scratch_(scratch), store_(store) {}
  void write(uint64_t window, Bytes frame, uint64_t count, uint64_t first, uint32_t record_size, Lease lease) {
    if (window >= store_.windows.size()) {
      store_.windows.resize(window + 1);
      files_.resize(window + 1, UINT32_MAX);
      offsets_.resize(window + 1, 0);
    }
    if (files_[window] == UINT32_MAX) {
      files_[window] = scratch_.create_file("vertices-" + std::to_string(window));
    }
    uint64_t size = frame.size();
    store_.windows[window].push_back({files_[window], offsets_[window], size, count, first, record_size});
    offsets_[window] += size;
    auto shared = std::make_shared<std::pair<Bytes, Lease>>(std::move(frame), std::move(lease));
    ScratchStore* scratch = &scratch_;
    uint32_t file = files_[window];
    StageStats* stage = &job_.stage("load");
    job_.io().submit(
        "scratch write",
        [shared, scratch, file, stage] {
          scratch->append(file, shared->first.data(), shared->first.size());
          stage->bytes_written += shared->first.size();
          shared->first = Bytes();
          shared->second.release();
        },
        job_.error_handler(), size);
  }
  void finish() {
    ScratchStore* scratch = &scratch_;
    std::vector<uint32_t> files;
    for (uint32_t f : files_) {
      if (f != UINT32_MAX) files.push_back(f);
    }
    job_.io().call("scratch finalize", [scratch, files] {
      for (uint32_t f : files) scratch->finalize(f);
    });
    job_.check();
  }

 private:
  Job& job_;
  ScratchStore& scratch_;
  VertexStore& store_;
  std::vector<uint32_t> files_;
  std::vector<uint64_t> offsets_;
};

// Triangle-only block records kept in memory: pages of records per cell, so nothing
// is ever reallocated and the memory held is within what bytes() asks for. A cell's
// pages double from its first page up to page_bytes: a cell's unused room is its
// last page's, at most min(page_bytes, its records' bytes + the first page), where
// fixed 256 KiB pages leased 256 KiB a cell however few faces it got (a small mesh
// with many cells leased several times its records).
class ResidentBlocks {
 public:
  static constexpr uint64_t page_bytes = 256 << 10;
  // Room for `faces` records over `cells` cells; hold() a lease of bytes() before add().
  // A cell's first page is about its share of the records, between 4 KiB and
  // page_bytes, so that big cells start with the 256 KiB pages they would grow to anyway.
  ResidentBlocks(uint64_t faces, uint32_t record_size, uint32_t cells)
      : record_size_(record_size), faces_left_(faces), pages_(cells) {
    const uint64_t records = faces * record_size;
    first_page_bytes_ = std::clamp<uint64_t>(std::bit_ceil(std::max<uint64_t>(records / std::max<uint32_t>(cells, 1), 1)),
                                             4 << 10, page_bytes);
    bytes_ = records + std::min(uint64_t(cells) * page_bytes, records + uint64_t(cells) * first_page_bytes_) +
             uint64_t(cells) * record_size;  // a page's capacity rounds up to whole records
  }
  uint64_t bytes() const { return bytes_; }
  void hold(Lease lease) { lease_ = std::move(lease); }
  bool fits(uint64_t faces) const { return faces <= faces_left_; }
  void add(uint32_t cell, const std::byte* record) { add_run(cell, record, 1); }
  void add_run(uint32_t cell, const std::byte* records, uint64_t count) {
    auto& pages = pages_[cell];
    while (count > 0) {
      if (pages.empty() || pages.back().size() == pages.back().capacity()) {
        const uint64_t bytes = pages.empty() ? first_page_bytes_ : std::min(page_bytes, 2 * pages.back().capacity());
        pages.emplace_back();
        // Whole records, rounded up: a full page of PLY face records is then at least
        // page_bytes, which the output's sink writes as it lies, without a copy.
        pages.back().reserve((bytes + record_size_ - 1) / record_size_ * record_size_);
        // A re-encode's pages (PLY face records) are most of its fresh memory, each
        // filled whole but a cell's last: one call faults a page in, not one trap per
        // 4 KiB. (Not for the simplify's records: there a cell's last page, faulted in
        // whole, held ~55 MiB more at 20M faces for nothing; 85ebbc6.)
        if (record_size_ == ply_triangle_record_size)
          populate_pages(pages.back().data(), pages.back().data() + pages.back().capacity());
      }
      Bytes& page = pages.back();
      const size_t at = page.size();
      const uint64_t n = std::min<uint64_t>(count, (page.capacity() - at) / record_size_);
      page.resize(at + n * record_size_);
      if (n == 1 && record_size_ == triangle32_record_size) {
        std::memcpy(page.data() + at, records, triangle32_record_size);  // no libc call
      } else if (n == 1 && record_size_ == ply_triangle_record_size) {
        std::memcpy(page.data() + at, records, ply_triangle_record_size);
      } else {
        std::memcpy(page.data() + at, records, n * record_size_);
      }
      records += n * record_size_;
      count -= n;
      faces_left_ -= n;
    }
  }
  std::vector<std::vector<Bytes>> finish(Lease& lease) {
    lease = std::move(lease_);
    return std::move(pages_);
  }

 private:
  uint32_t record_size_;
  uint64_t first_page_bytes_ = 0;
  uint64_t bytes_ = 0;
  uint64_t faces_left_;
  std::vector<std::vector<Bytes>> pages_;
  Lease lease_;
};

class Loader {
 public:
  Loader(Job& job, ScratchStore& scratch, const std::filesystem::path& input,
         const LoadOptions& options, const LoadHooks& hooks)
      : job_(job), scratch_(scratch), options_(options), hooks_(hooks) {
    input_.path = input;
    // A .zst input's decoder window beyond what every run counts (io/byte_source.hpp)
    // is held for as long as the input may be read: `zstd --long=27` (128 MiB) unleased
    // took a 3M-face re-encode at 50M to 70 MiB.
    const uint64_t window_bytes = input_window_bytes(input);
    job_.require_fits(job_.owner("loader"), loader_minimum_bytes() + window_bytes);
    if (window_bytes > 0) {
      window_ = job_.governor().acquire(job_.owner("input window"), window_bytes, window_bytes,
                                        [this] { return job_.stopped(); });
      job_.check();
    }
    job_.io().call("open input", [&] { input_.open(); });
    input_.size = input_.info().file_size;
    // One reservation for everything the loader holds for a whole pass (spills,
    // vertex chunks, face ranges), taken at once and handed out with split(): a job
    // never holds part of its working set while waiting for the rest, so jobs sharing
    // a governor cannot deadlock. Streamed items (batches, frames) come from what is
    // left, through leases that never wait while holding anything.
    // Sized from what is free at the grant: another job's loader starting at the same
    // moment must not count the same bytes (together they took everything, and both
    // input streams waited forever for a batch lease).
    reserve_ = job_.governor().acquire_share(
        job_.owner("loader reserve"), reserve_minimum_bytes(),
        [](uint64_t free) { return free - std::min(free, std::max(items_minimum_bytes, free / 4)); },
        [this] { return job_.stopped(); });
    job_.check();
    capacity_ = reserve_.bytes();
    held_outside_ = job_.governor().in_use() - std::min(job_.governor().in_use(), capacity_);
  }

  // The budget at which what the reservation holds now (`bytes` short) would be enough.
  // What the loader's spills have taken grows with the reservation (fractions of it, at
  // most half at any time), so the reservation grows by twice the shortfall; it is the
  // share of the free memory above (3/4, or all but items_minimum_bytes), on top of the process
  // baseline and what other owners hold (the job's trace, another job).
  uint64_t budget_for_shortfall(uint64_t short_bytes) const {
    const uint64_t reservation = capacity_ + 2 * short_bytes;
    const uint64_t free = std::max(reservation + items_minimum_bytes, (reservation * 4 + 2) / 3);
    return job_.governor().baseline() + held_outside_ + free;
  }

  LoadedMesh run() {
    const auto& info = input_.info();
    mesh_.input_bytes = input_.size;
    // Resident positions and, while they are welded, their sort order (weld_in_memory)
    // within 6/10 of the reservation, and the block writer's smallest lease beside them.
    // A re-encode's float positions (resident_float_positions) need nothing else beside
    // them but the block writer: 8/10. Holding them spares the out-of-core dereference's
    // scratch round trip (vertex windows, local faces: 2.5 GB of 3.8 at 100M faces), so a
    // budget that holds them gives the resident path's speed with blocks spilled.
    const uint64_t resident_bytes =
        info.vertex_count.value_or(0) * (resident_position_bytes() + (options_.weld ? sizeof(uint64_t) : 0));
    const uint64_t resident_share = resident_float_positions() ? capacity_ * 8 / 10 : capacity_ * 6 / 10;
    bool resident = info.vertex_count && !options_.force_out_of_core && resident_bytes <= resident_share &&
                    resident_bytes + BucketSpill::min_lease_bytes(sizeof(BlockFace)) <= reserve_.bytes();
    // Known before the load (a PLY's vertex count): refused up front, not after a pass
    // over the input (a sorted 6M faces at 48M read for 36-41 s first).
    if (options_.degrees && info.vertex_count) require_state("the per-vertex face counts", *info.vertex_count);
    if (resident) {
      load_resident(*info.vertex_count, info.polygon_count.value_or(0));
    } else {
      load_out_of_core();
    }
    input_.close();
    return std::move(mesh_);
  }

 private:
  // A part of the reservation for `owner`. The loader's fractions of it never add up
  // to more than it holds at once.
  // A budget that leaves the loader too little is a resource error naming roughly
  // what would do, not an internal one (the up-front check covers the usual layouts,
  // not every mesh's).
  Lease take(const char* owner, uint64_t bytes) {
    if (bytes > reserve_.bytes()) {
      const uint64_t budget = job_.governor().budget();
      throw Error(ErrorKind::resource, std::string("loader: the ") + owner + " need " + config::format_size(bytes) +
                                           " but --mem-budget " + config::format_size(budget) + " leaves them " +
                                           config::format_size(reserve_.bytes()) +
                                           "; this needs a budget of at least " +
                                           config::format_budget(budget_for_shortfall(bytes - reserve_.bytes())));
    }
    return reserve_.split(bytes, job_.owner(owner));
  }
  void give_back(Lease&& lease) { reserve_.merge(std::move(lease)); }
  static uint32_t weld_buckets_for(uint32_t chunks) { return std::clamp<uint32_t>(chunks * 2, 1, 4096); }

  Lease spill_lease(const char* owner, double fraction, uint32_t record_size, uint32_t buckets = 1) {
    uint64_t min = BucketSpill::min_lease_bytes(record_size, buckets);
    // Past a few hundred MiB, bigger spill buffers only make bigger frames.
    uint64_t bytes = std::clamp<uint64_t>(uint64_t(double(capacity_) * fraction), min, 192ull << 20);
    return take(owner, std::min(bytes, std::max(min, reserve_.bytes())));
  }

  // A spill sized for fewer pages than buckets may write frames of a record or two,
  // past the eighth raw_load_scratch_bound allows for their envelopes (review16: up to
  // 1.28x). Once such a spill is made, and before it writes, an automatic store that
  // went raw on that bound chooses again against the bound that counts an envelope a
  // record (`triangles`, `vertices`: the load's counts, or a bound on them;
  // UINT64_MAX when unknown). It can only go from raw to zstd; forced codecs stay.
  void note_spill_frames(std::initializer_list<const BucketSpill*> spills, uint64_t triangles, uint64_t vertices,
                         const char* stage) {
    bool small = false;
    for (const BucketSpill* spill : spills) small = small || (spill && spill->small_frames());
    if (!small || mesh_.small_spill_frames) return;
    mesh_.small_spill_frames = true;
    if (!scratch_.codec().raw) return;
    const bool known = triangles != UINT64_MAX && vertices != UINT64_MAX;
    scratch_.choose_codec(known ? raw_load_scratch_bound(triangles, vertices, true) : UINT64_MAX, stage);
  }

  // Reads with `read`: the whole input (default), its vertices or its faces.
  StreamPass<InputItem> input_pass(bool (InputStream::*read)(InputItem&, Lease&) = &InputStream::read) {
    StreamPass<InputItem> pass;
    pass.stage = "load";
    pass.read_name = "read input";
    pass.owner = "input batches";
    pass.min_item_bytes = min_input_lease;
    pass.max_item_bytes = std::clamp<uint64_t>(capacity_ / 24, min_input_lease, max_input_lease);
    pass.read = [this, read](InputItem& item, Lease& lease) {
      bool more = (input_.*read)(item, lease);
      report_read_progress();
      return more;
    };
    if (input_.bulk) pass.decode = [this](InputItem& item, Lease&) { input_.decode(item); };
    return pass;
  }

  void report_read_progress() {
    job_.stage("load").bytes_read = input_.bytes_read();
    if (input_.size) job_.progress(progress_base_ + progress_span_ * double(input_.bytes_read()) / double(input_.size), "load");
  }

  void build_grid(uint64_t faces) {
    mesh_.grid = BlockGrid::around(box_.min, box_.max, block_count_for(faces, options_.faces_per_block));
    mesh_.blocks.assign(mesh_.grid.count(), {});
    mesh_.block_faces.assign(mesh_.grid.count(), 0);
  }

  void add_face(BucketSpill& blocks, const BlockFace& face) {
    std::byte record[sizeof(BlockFace)];
    uint32_t cell = make_record(face, record);
    blocks.add(cell, record);
    ++mesh_.block_faces[cell];
  }

  // A face as its block record at `out` (block_record_size bytes); returns its cell.
  // Any thread.
  uint32_t make_record(const BlockFace& face, std::byte* out) const {
    if (mesh_.block_record_size == id_triangle32_record_size) {
      const uint32_t record[4] = {uint32_t(face.id), uint32_t(face.vertices[0]), uint32_t(face.vertices[1]),
                                  uint32_t(face.vertices[2])};
      std::memcpy(out, record, sizeof record);
    } else if (mesh_.block_record_size == id_triangle64_record_size) {
      const LocalFace record{face.id, face.vertices};
      std::memcpy(out, &record, sizeof record);
    } else if (mesh_.block_record_size == triangle32_record_size) {
      const uint32_t ids[3] = {uint32_t(face.vertices[0]), uint32_t(face.vertices[1]), uint32_t(face.vertices[2])};
      std::memcpy(out, ids, sizeof ids);
    } else if (mesh_.block_record_size == triangle64_record_size) {
      std::memcpy(out, face.vertices.data(), sizeof(Triangle));
    } else if (mesh_.block_record_size == sizeof(PackedBlockFace)) {
      PackedBlockFace packed;
      packed.id = face.id;
      packed.vertices = face.vertices;
      for (int k = 0; k < 9; ++k) packed.positions[k] = float(face.positions[k / 3][k % 3]);
      packed.degree = face.degree;
      std::memcpy(out, &packed, sizeof packed);
    } else {
      std::memcpy(out, &face, sizeof face);
    }
    return mesh_.grid.cell_of(barycenter(face.positions));
  }
  template <class Blocks>
  void add_records(Blocks& blocks, const InputItem& item) {
    add_record_runs(blocks, item.records(), item.cells.data(), item.cells.size());
  }
  // Records with their cells, filed a run of equal cells at a time; UINT32_MAX cells
  // are dropped faces. Returns how many.
  template <class Blocks>
  uint64_t add_record_runs(Blocks& blocks, const std::byte* records, const uint32_t* cells, uint64_t count) {
    const uint32_t size = mesh_.block_record_size;
    uint64_t dropped = 0;
    for_each_cell_run(cells, count, [&](uint32_t cell, uint64_t begin, uint64_t end) {
      if (cell == UINT32_MAX) {
        dropped += end - begin;
      } else {
        blocks.add_run(cell, records + begin * size, end - begin);
        mesh_.block_faces[cell] += end - begin;
      }
    });
    return dropped;
  }

  // The re-encode of an input with float coordinates keeps them as floats when resident:
  // half the memory the face lookups wander over, and the output's vertices as they are.
  bool resident_float_positions() const { return verbatim_triangles() && input_.float_coordinates(); }
  uint64_t resident_position_bytes() const { return resident_float_positions() ? 3 * sizeof(float) : sizeof(Point); }
  // Triangle-only records of the input's faces as they are (no weld, every face): the
  // lean path, without a BlockFace per face.
  bool verbatim_triangles() const {
    return options_.triangles_only && !options_.weld && !options_.drop_repeated_vertex_faces && !options_.degrees;
  }
  // A triangle record at `out` (block_record_size bytes); returns its cell (the same
  // as make_record's). Any thread.
  uint32_t triangle_record(const Triangle& t, const Point& a, const Point& b, const Point& c, std::byte* out) const {
    if (mesh_.block_record_size == ply_triangle_record_size) {
      io::put_ply_triangle(uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2]), out);
    } else if (mesh_.block_record_size == triangle32_record_size) {
      put_u32_pair(out, t[0], t[1]);
      const uint32_t third = uint32_t(t[2]);
      std::memcpy(out + 8, &third, sizeof third);
    } else {
      std::memcpy(out, t.data(), sizeof(Triangle));
    }
    return mesh_.grid.cell_of(barycenter({a, b, c}));
  }

  // Once every coordinate has been seen (and the vertex count is known): blocks store
  // triangles only when asked, else floats when that is exact.
  // Out of core, triangle-only records keep the face id: the writer sorts each block
  // by it (blocks.hpp).
  uint32_t choose_block_layout() {
    if (options_.triangles_only && mesh_.out_of_core) {
      mesh_.block_record_size = mesh_.vertex_count <= UINT32_MAX && mesh_.face_count <= UINT32_MAX
                                    ? id_triangle32_record_size
                                    : id_triangle64_record_size;
    } else if (options_.triangles_only) {
      mesh_.block_record_size = mesh_.vertex_count > UINT32_MAX        ? triangle64_record_size
                                : options_.ply_triangle_records ? ply_triangle_record_size
                                                                : triangle32_record_size;
    } else {
      mesh_.block_record_size = box_.float_exact ? sizeof(PackedBlockFace) : sizeof(BlockFace);
    }
    return mesh_.block_record_size;
  }

  // Out of core, a local face's spill record: the full LocalFace (u64 id and ids),
  // else for triangle-only blocks without the degree pass the face id and the three
  // ids as u32 when the header's counts allow: 16 bytes instead of 32, and the block
  // record already (id_triangle32_record_size).
  uint32_t local_record_size() const {
    const auto& vertices = input_.info().vertex_count;
    const auto& faces = input_.info().polygon_count;
    if (options_.triangles_only && !options_.degrees && vertices && *vertices <= UINT32_MAX && faces &&
        *faces <= UINT32_MAX) {
      return id_triangle32_record_size;
    }
    return sizeof(LocalFace);
  }

  void collect_blocks(BucketSpill& blocks) {
    give_back(blocks.finish());
    for (uint32_t c = 0; c < mesh_.grid.count(); ++c) {
      const auto& frames = blocks.frames(c);
      mesh_.blocks[c].insert(mesh_.blocks[c].end(), frames.begin(), frames.end());
    }
  }

  // A face's welded ids and degrees from its input ids (positions already set);
  // false when it is dropped. Any thread, once the weld and the counts are done.
  bool prepare(BlockFace& face, const Triangle& input_ids) const {
    for (int k = 0; k < 3; ++k) face.vertices[k] = options_.weld ? weld_(input_ids[k]) : input_ids[k];
    if (options_.drop_repeated_vertex_faces && repeated(face.vertices)) return false;
    for (int k = 0; k < 3; ++k) face.degree[k] = degree_.low.empty() ? 0 : degree_[face.vertices[k]];
    return true;
  }
  // The welded face, or nullopt when it is dropped (for counting).
  std::optional<Triangle> welded(const Triangle& input_ids) const {
    Triangle t;
    for (int k = 0; k < 3; ++k) t[k] = options_.weld ? weld_(input_ids[k]) : input_ids[k];
    if (options_.drop_repeated_vertex_faces && repeated(t)) return std::nullopt;
    return t;
  }

  // Per-vertex state (weld bits and duplicates, degree bytes) is held for the whole
  // load; refused up front when the budget cannot hold it.
  void take_state(const char* what, uint64_t bytes) {
    require_state(what, bytes);
    state_lease_.merge(reserve_.split(bytes, job_.owner("loader vertex state")));
  }
  void require_state(const char* what, uint64_t bytes) const {
    if (bytes > reserve_.bytes() / 2) {
      const uint64_t budget = job_.governor().budget();
      throw Error(ErrorKind::resource, std::string("loader: ") + what + " needs " + config::format_size(bytes) +
                                           ", more than --mem-budget " + config::format_size(budget) +
                                           " leaves for it (" + config::format_size(reserve_.bytes() / 2) +
                                           "); this needs a budget of at least " +
                                           config::format_budget(budget_for_shortfall(2 * bytes - reserve_.bytes())));
    }
  }

  void finish_weld(uint64_t vertex_count) {
    take_state("the weld's duplicate list", weld_.duplicates.size() * 16 + (vertex_count + 63) / 64 * 8);
    weld_.finish(vertex_count);
    mesh_.welded_vertices = weld_.duplicates.size();
  }

  // Resident weld: indices sorted by (position, index), runs of equal positions map
  // to their first (smallest) index.
  // `order_lease` holds n * 8 bytes, taken before the block writer sized its lease.
  void weld_in_memory(const std::vector<Point>& positions, Lease order_lease) {
    if (!options_.weld) return;
    StageTimer timer(job_, "weld");
    const uint64_t n = positions.size();
    UninitializedVector<uint64_t> order(n);
    for (uint64_t i = 0; i < n; ++i) order[i] = i;
    job_.arena().execute([&] {
      tbb::parallel_sort(order.begin(), order.end(), [&](uint64_t a, uint64_t b) {
        PositionKey ka = position_key(positions[a]), kb = position_key(positions[b]);
        return ka != kb ? ka < kb : a < b;
      });
    });
    weld_.add_runs(n, [&](uint64_t i) { return positions[order[i]]; }, [&](uint64_t i) { return order[i]; });
    release_memory(order);
    give_back(std::move(order_lease));
    finish_weld(n);
  }

  void start_degrees(uint64_t vertex_count) {
    take_state("the per-vertex face counts", vertex_count);
    degree_.low.assign(vertex_count, 0);
  }

  // Resident: the input's faces (after its vertex pass), counted around welded vertices.
  void count_degrees_from_input(uint64_t vertex_count) {
    StageTimer timer(job_, "degrees");
    start_degrees(vertex_count);
    auto pass = input_pass(&InputStream::read_faces);
        pass.transform = [&](InputItem& item, Lease&) {
      auto& triangles = item.batch.triangles;
      size_t kept = 0;
      for (size_t i = 0; i < triangles.size(); ++i) {
        for (uint64_t v : triangles[i]) {
          if (v >= vertex_count) index_out_of_range(input_.path, item.batch.first_triangle + i, v, vertex_count);
        }
        if (auto t = welded(triangles[i])) triangles[kept++] = *t;
      }
      triangles.resize(kept);
    };
    pass.sink = [&](InputItem& item, Lease&) {
      for (const Triangle& t : item.batch.triangles)
        for (uint64_t v : t) degree_.add(v);
    };
    run_stream_pass(job_, pass);
  }

  // Opens the input again and reads through its vertices (the face pass follows).
  void reopen_input_past_vertices() {
    job_.io().call("open input", [&] { input_.open(); });
    progress_base_ += progress_span_;
    auto pass = input_pass(&InputStream::read_vertices);
        run_stream_pass(job_, pass);
  }

  // Where the resident load's block records go: in memory when triangle-only records
  // of `triangles` faces fit what the loader holds (`block_lease` then goes back), else
  // a BucketSpill under `block_lease` (taken again if it went back). The grid is built
  // from `polygons`, the same on both reads and out of core.
  void place_blocks(uint64_t polygons, uint64_t triangles, uint32_t record_size, Lease& block_lease,
                    std::optional<ResidentBlocks>& in_memory, std::unique_ptr<BucketSpill>& blocks) {
    build_grid(polygons);
    if (options_.triangles_only && triangles > 0) {
      ResidentBlocks planned(triangles, record_size, mesh_.grid.count());
      if (planned.bytes() <= reserve_.bytes() + block_lease.bytes()) {
        give_back(std::move(block_lease));
        planned.hold(take("resident blocks", planned.bytes()));
        in_memory.emplace(std::move(planned));
        return;
      }
    }
    if (block_lease.bytes() == 0) block_lease = spill_lease("block writer", 0.3, sizeof(BlockFace));
    blocks = std::make_unique<BucketSpill>(job_, scratch_, "blocks", record_size, std::move(block_lease),
                                           mesh_.grid.count(), "load");
    // Only the blocks are written: with an envelope apiece they stay within the eighth
    // the load's bound gives the widest out-of-core records, so no new choice (but the
    // report's bound on the blocks left on disk counts them).
    if (blocks->small_frames()) mesh_.small_spill_frames = true;
  }

  // The resident load's face pass: faces resolved against the resident positions
  // (as xyz floats when `floats`) and filed into `in_memory` when given, else into
  // `blocks`. Returns whether `in_memory` overflowed (an input with polygons: its
  // triangles were then counted, not stored); on the `retry`, sized by that count, an
  // overflow is bad input.
  bool resident_face_pass(bool floats, ResidentBlocks* in_memory, BucketSpill* blocks, bool retry) {
    const uint64_t vertex_count = mesh_.vertex_count;
    const auto& positions = mesh_.vertices.resident;
    const auto& xyz = mesh_.vertices.resident_xyz;
    // Pass B: faces resolved and made into block records on every compute thread;
    // the sink only files them. A binary PLY's faces, re-encoded as triangle32 records,
    // are decoded straight into them (12 bytes a face instead of a 24-byte Triangle
    // the transform then read back): only their cells are left to find. As PLY face
    // records, a little-endian file's "list uchar int" triangles are those records
    // already: checked where they lie in the range read, and filed from there.
    const uint32_t record = mesh_.block_record_size;
    // A record's first id: PLY face records start with their count byte.
    const uint32_t ids_at = record == ply_triangle_record_size ? 1 : 0;
    input_.decoded_records = input_.bulk && verbatim_triangles() &&
                                     (record == triangle32_record_size || record == ply_triangle_record_size)
                                 ? record
                                 : 0;
    auto face_pass = input_pass(&InputStream::read_faces);
    SpareItemBuffers spare;
    if (input_.decoded_records) {
      // Records and cells of up to 8 items of the largest size (16 bytes an element).
      const uint64_t spare_bytes = 8 * (face_pass.max_item_bytes / bytes_per_input_element + 16) * 16;
      if (spare_bytes <= reserve_.bytes() / 4) {
        spare.lease = take("spare item buffers", spare_bytes);
        input_.spare = &spare;
      }
    }
    face_pass.transform = [&](InputItem& item, Lease&) {
      if (item.records_decoded) {  // indices checked by the decode
        const size_t faces = item.triangle_count();
        item.cells.resize(faces);
        const std::byte* records = item.records();
        if (floats) {
          // Division-free: the scalar kernel's six divisions a face were a quarter of a
          // resident re-encode's CPU, and the AVX2 kernel's gathers came out 5-10% slower.
          face_cells_xyz(FaceCellsKernel::steps, mesh_.grid, xyz.data(), 0, vertex_count, records + ids_at, record,
                         faces, item.cells.data());
          return;
        }
        auto id = [&](size_t i, int k) {
          uint32_t v;
          std::memcpy(&v, records + i * record + ids_at + k * sizeof v, sizeof v);
          return uint64_t(v);
        };
        for (size_t i = 0; i < faces; ++i) {
          if (i + prefetch_faces_ahead < faces) {  // as below
            for (int k = 0; k < 3; ++k) prefetch_position(floats, xyz.data(), positions.data(), id(i + prefetch_faces_ahead, k));
          }
          const uint64_t a = id(i, 0), b = id(i, 1), c = id(i, 2);
          item.cells[i] = mesh_.grid.cell_of(barycenter({positions[a], positions[b], positions[c]}));
        }
        return;
      }
      const auto& batch = item.batch;
      item.block_records.resize(batch.triangles.size() * mesh_.block_record_size);
      item.cells.resize(batch.triangles.size());
      if (verbatim_triangles()) {
        const size_t faces = batch.triangles.size();
        for (size_t i = 0; i < faces; ++i) {
          // The positions a face reads are scattered over the whole vertex array:
          // ask for a later face's while this one's are resolved, so the cache
          // misses overlap instead of stalling one after another.
          if (i + prefetch_faces_ahead < faces) {
            for (uint64_t v : batch.triangles[i + prefetch_faces_ahead]) {
              if (v < vertex_count) prefetch_position(floats, xyz.data(), positions.data(), v);
            }
          }
          const Triangle& t = batch.triangles[i];
          for (uint64_t v : t) {
            if (v >= vertex_count) index_out_of_range(input_.path, batch.first_triangle + i, v, vertex_count);
          }
          if (floats) {
            auto at = [&](uint64_t v) { return Point{xyz[3 * v], xyz[3 * v + 1], xyz[3 * v + 2]}; };
            item.cells[i] = triangle_record(t, at(t[0]), at(t[1]), at(t[2]),
                                            item.block_records.data() + i * mesh_.block_record_size);
          } else {
            item.cells[i] = triangle_record(t, positions[t[0]], positions[t[1]], positions[t[2]],
                                            item.block_records.data() + i * mesh_.block_record_size);
          }
        }
        return;
      }
      BlockFace face;
      size_t kept = 0;
      for (size_t i = 0; i < batch.triangles.size(); ++i) {
        face.id = batch.first_triangle + i;
        for (int k = 0; k < 3; ++k) {
          uint64_t v = batch.triangles[i][k];
          if (v >= vertex_count) index_out_of_range(input_.path, face.id, v, vertex_count);
          face.positions[k] = positions[v];
        }
        if (!prepare(face, batch.triangles[i])) {
          ++item.dropped;
          continue;
        }
        item.cells[kept] = make_record(face, item.block_records.data() + kept * mesh_.block_record_size);
        ++kept;
      }
      item.cells.resize(kept);
    };
    bool overflowed = false;
    face_pass.sink = [&](InputItem& item, Lease&) {
      if (in_memory) {
        if (overflowed || !in_memory->fits(item.cells.size())) {
          // The reader holds the file to its header's polygon count; past the first
          // read, the count is the triangles' own.
          if (retry) {
            throw_bad_input(input_.path.string(), "triangle " + std::to_string(item.batch.first_triangle),
                            "more faces than the first read of the file found (did it change?)");
          }
          overflowed = true;  // counted on, not stored
        } else {
          add_records(*in_memory, item);
        }
      } else {
        add_records(*blocks, item);
      }
      mesh_.dropped_faces += item.dropped;
      if (item.triangle_count() > 0) {
        mesh_.face_count = std::max<uint64_t>(mesh_.face_count, item.batch.first_triangle + item.triangle_count());
      }
      if (input_.spare) input_.spare->keep(item);
    };
    run_stream_pass(job_, face_pass);
    input_.decoded_records = 0;
    input_.spare = nullptr;
    spare.clear();
    give_back(std::move(spare.lease));
    return overflowed;
  }

  // All vertex positions in memory; faces resolved as they stream by.
  void load_resident(uint64_t vertex_count, uint64_t polygon_count) {
    progress_span_ = options_.degrees ? 0.4 : 0.8;
    const bool floats = resident_float_positions();
    Lease vertex_lease = take("vertex positions", vertex_count * resident_position_bytes());
    auto& positions = mesh_.vertices.resident;
    auto& xyz = mesh_.vertices.resident_xyz;
    if (floats) {
      xyz.resize(3 * vertex_count);
      advise_huge_pages(xyz.data(), xyz.data() + xyz.size());
    } else {
      positions.resize(vertex_count);
    }
    mesh_.vertices.count = vertex_count;
    mesh_.vertices.window = std::max<uint64_t>(vertex_count, 1);
    mesh_.vertex_count = vertex_count;
    std::unique_ptr<BucketSpill> blocks;
    Lease weld_order_lease = options_.weld ? take("weld order", vertex_count * sizeof(uint64_t)) : Lease{};
    // Taken before the pass: a sink must never wait for memory that items queued
    // behind it hold.
    Lease block_lease = spill_lease("block writer", 0.3, sizeof(BlockFace));
    uint64_t vertices_seen = 0;

    // The read passes are the "load" stage; the weld and the degrees between them time
    // themselves (stages do not nest).
    std::optional<StageTimer> timer(std::in_place, job_, "load");
    // Pass A: vertices, copied in place (batches hold disjoint index ranges).
    auto vertex_pass = input_pass(&InputStream::read_vertices);
    // The positions of a float PLY go to `xyz` as decoded; only their box is left.
    if (floats) {
      input_.vertex_xyz = xyz.data();
      input_.vertex_xyz_capacity = vertex_count;
    }
    vertex_pass.transform = [&](InputItem& item, Lease&) {
      if (item.xyz_decoded > 0) {
        item.box.add_floats(xyz.data() + 3 * item.batch.first_vertex, item.xyz_decoded);
        return;
      }
      const auto& batch = item.batch;
      if (batch.first_vertex + batch.vertices.size() > vertex_count) {
        throw_bad_input(input_.path.string(), "vertex " + std::to_string(batch.first_vertex),
                        "more vertices than the header declares");
      }
      if (floats) {
        float* at = xyz.data() + 3 * batch.first_vertex;
        for (const Point& p : batch.vertices)
          for (int k = 0; k < 3; ++k) *at++ = float(p[k]);
      } else {
        std::copy(batch.vertices.begin(), batch.vertices.end(), positions.begin() + int64_t(batch.first_vertex));
      }
      item.box.add(batch.vertices.data(), batch.vertices.size());
    };
    vertex_pass.sink = [&](InputItem& item, Lease&) {
      box_.add(item.box);
      vertices_seen += item.batch.vertices.size() + item.xyz_decoded;
    };
    run_stream_pass(job_, vertex_pass);
    input_.vertex_xyz = nullptr;
    if (vertices_seen != vertex_count) {
      throw_bad_input(input_.path.string(), "end of vertices",
                      "truncated: " + std::to_string(vertices_seen) + " of " + std::to_string(vertex_count) + " vertices");
    }
    timer.reset();
    weld_in_memory(positions, std::move(weld_order_lease));
    if (options_.degrees) count_degrees_from_input(vertex_count);
    timer.emplace(job_, "load");
    if (options_.degrees) reopen_input_past_vertices();
    const uint32_t record_size = choose_block_layout();
    // A PLY's face count counts polygons: an input with quads or larger polygons has
    // more triangles than that, and resident blocks sized by it overflow. Its faces are
    // then read once more, into blocks sized by the triangles the first read counted.
    std::optional<ResidentBlocks> in_memory;
    place_blocks(polygon_count, polygon_count, record_size, block_lease, in_memory, blocks);
    if (resident_face_pass(floats, in_memory ? &*in_memory : nullptr, blocks.get(), false)) {
      Lease resident_lease;
      in_memory->finish(resident_lease);
      in_memory.reset();
      give_back(std::move(resident_lease));
      const uint64_t triangles = mesh_.face_count;
      mesh_.face_count = 0;
      mesh_.dropped_faces = 0;
      // The second read reports the first's fractions again; the job never reports less
      // than before (engine/job.hpp), so the bar holds where the first read ended.
      progress_base_ = 0;
      progress_span_ = 0.4;
      reopen_input_past_vertices();
      place_blocks(polygon_count, triangles, record_size, block_lease, in_memory, blocks);
      resident_face_pass(floats, in_memory ? &*in_memory : nullptr, blocks.get(), true);
    }
    if (in_memory) {
      mesh_.resident_blocks = in_memory->finish(mesh_.resident_blocks_lease);
      mesh_.float_exact = box_.float_exact;
      mesh_.resident_lease = std::move(vertex_lease);
      return;
    }
    if (!blocks) {  // no faces at all
      build_grid(0);
      blocks = std::make_unique<BucketSpill>(job_, scratch_, "blocks", choose_block_layout(),
                                             std::move(block_lease), 1, "load");
    }
    collect_blocks(*blocks);
    mesh_.float_exact = box_.float_exact;
    // The positions stay resident for whoever writes them next; their lease goes with
    // the mesh.
    mesh_.resident_lease = std::move(vertex_lease);
  }

  // Out of core. Vertices go to scratch in chunks of `chunk` consecutive indices. A
  // face whose vertex indices all fall in two consecutive chunks (most faces of a
  // real mesh: indices are local) is a *local* face: it is bucketed by the chunk of
  // its smallest index and resolved with that chunk and the next loaded. The others go
  // corner by corner: bucketed by chunk, resolved chunk by chunk, regrouped by
  // face-id range and rebuilt.
  void load_out_of_core() {
    mesh_.out_of_core = true;
    progress_span_ = 0.4;
    const auto& info = input_.info();
    uint64_t chunk = options_.window_vertices
                         ? options_.window_vertices
                         : std::max<uint64_t>(1024, uint64_t(double(capacity_) * 0.15) / sizeof(Point));
    // An input without a vertex count (OBJ) is taken to have one vertex per 40 bytes
    // of text (10 of zstd): more than a real file's ~80, so its chunk buckets are not
    // undercounted (a shuffled 3M-face OBJ at 48M, taken as 16 chunks for 81, went to
    // 222 MiB as the PLY had, review13).
    const uint64_t vertices = info.vertex_count.value_or(
        std::max<uint64_t>(input_.size / (io::mesh_file_kind(input_.path).zstd ? 10 : 40), 1));
    auto chunks_of = [&](uint64_t chunk) {
      return uint32_t(std::min<uint64_t>(std::max<uint64_t>((vertices + chunk - 1) / chunk, 1), UINT32_MAX));
    };
    // Pass 1's spills hold two pages per chunk bucket where the reserve allows
    // (BucketSpill::min_lease_bytes): under a small reserve, fewer and larger chunks,
    // while pass 2's pair of them leaves room for its two spills' smallest leases.
    const uint32_t local_size = local_record_size();
    const uint64_t pass1_room = uint64_t(double(capacity_) * 0.4);
    auto pass1_min = [&](uint32_t chunks) {
      return BucketSpill::min_lease_bytes(local_size, chunks) +
             BucketSpill::min_lease_bytes(sizeof(CornerRef), chunks) +
             (options_.weld ? BucketSpill::min_lease_bytes(sizeof(WeldRecord), weld_buckets_for(chunks)) : 0);
    };
    // Pass 2 also holds the per-vertex face counts (1 B a vertex) when they are kept.
    const uint64_t pass2_rest = 3 * BucketSpill::min_lease_bytes(sizeof(BlockFace)) + (options_.degrees ? vertices : 0);
    while (!options_.window_vertices && pass1_min(chunks_of(chunk)) > pass1_room &&
           2 * (chunk + chunk / 4) * sizeof(Point) + pass2_rest <= capacity_) {
      chunk += chunk / 4;
    }
    mesh_.vertices.window = chunk;
    const uint32_t expected_chunks = chunks_of(chunk);
    // Where even that does not fit (a large input at a budget near the loader's
    // minimum), the spills take their fractions as before: an input with locality
    // still loads, and one in random order makes small frames (README, re-encode).
    const bool paged = pass1_min(expected_chunks) <= pass1_room;
    auto paged_buckets = [&](uint32_t buckets) { return paged ? buckets : 1u; };

    // Pass 1: vertices to chunks in scratch; local faces bucketed by their first
    // chunk, the corners of the others by their vertex's chunk.
    BucketSpill local(job_, scratch_, "local-faces", local_size,
                      spill_lease("face bucketer", 0.2, local_size, paged_buckets(expected_chunks)),
                      expected_chunks, "load");
    BucketSpill corners(job_, scratch_, "corners", sizeof(CornerRef),
                        spill_lease("corner bucketer", 0.1, sizeof(CornerRef), paged_buckets(expected_chunks)),
                        expected_chunks, "load");
    // Out of core, the weld sorts (position, index) records by position-hash bucket,
    // one bucket at a time; and the degree count reads every face once before the
    // dereference, so spanning faces are also kept whole.
    const uint32_t weld_buckets = weld_buckets_for(expected_chunks);
    std::optional<BucketSpill> weld_spill, spanning;
    if (options_.weld) {
      weld_spill.emplace(job_, scratch_, "weld", sizeof(WeldRecord),
                         spill_lease("weld bucketer", 0.1, sizeof(WeldRecord), paged_buckets(weld_buckets)),
                         weld_buckets, "load");
    }
    if (options_.degrees) {
      spanning.emplace(job_, scratch_, "spanning-faces", sizeof(LocalFace),
                       spill_lease("spanning faces", 0.05, sizeof(LocalFace)), 1, "load");
    }
    {
      const std::optional<InputCountsBound> counts = input_counts_bound(input_.path);
      note_spill_frames({&local, &corners, weld_spill ? &*weld_spill : nullptr}, counts ? counts->triangles : UINT64_MAX,
                        counts ? counts->vertices : UINT64_MAX, "load");
    }
    VertexFrameWriter vertex_writer(job_, scratch_, mesh_.vertices);
    uint64_t vertex_count = 0, face_count = 0, max_index = 0;
    std::optional<StageTimer> timer(std::in_place, job_, "load");
    auto pass = input_pass();
    // A binary PLY's float vertices come as floats and its faces as local records
    // (u32 id and triple) straight from the decode, with no 24-byte Point or Triangle
    // between: those batches, made and read back, were a fifth of a 256M re-encode's
    // CPU (its load's transform, the double box, the 64-bit decode, and zeroing them).
    input_.vertex_floats = input_.bulk && !weld_spill;
    input_.decoded_records = input_.bulk && local_size == id_triangle32_record_size ? id_triangle32_record_size : 0;
    pass.transform = [&](InputItem& item, Lease&) {
      const auto& batch = item.batch;
      const uint64_t vertices_in = item.xyz_decoded ? item.xyz_decoded : batch.vertices.size();
      if (item.xyz_decoded) {
        item.box.add_floats(item.xyz.data(), item.xyz_decoded);
      } else {
        item.box.add(batch.vertices.data(), batch.vertices.size());
      }
      uint64_t done = 0;
      while (done < vertices_in) {  // one frame per chunk the batch touches
        uint64_t first = batch.first_vertex + done;
        uint64_t c = first / chunk;
        uint64_t n = std::min<uint64_t>(vertices_in - done, (c + 1) * chunk - first);
        if (item.xyz_decoded) {
          item.vertex_frames.emplace_back(
              c, encode_frame(first, float_vertex_record_size, item.xyz.data() + 3 * done, n, scratch_.codec()));
        } else if (item.box.float_exact) {
          // Every coordinate of the batch is a float: the frame holds floats, half the
          // scratch bytes (load_vertex_window widens them back, exactly).
          UninitializedVector<float> xyz(3 * n);
          narrow_to_floats(batch.vertices[done].data(), 3 * n, xyz.data());
          item.vertex_frames.emplace_back(c, encode_frame(first, float_vertex_record_size, xyz.data(), n, scratch_.codec()));
        } else {
          item.vertex_frames.emplace_back(
              c, encode_frame(first, sizeof(Point), batch.vertices.data() + done, n, scratch_.codec()));
        }
        done += n;
      }
      // Faces sorted into local buckets here, on every compute thread, when local
      // records are u32 id and ids (the sink then files them a run at a time).
      if (local_size != id_triangle32_record_size || item.triangle_count() == 0) return;
      const size_t faces = item.triangle_count();
      // The header counts polygons, not the triangles fan-triangulated from them: the
      // bound that matters is the records' u32 face ids. A valid file past it is our
      // limit, not bad input (review12 L2): a resource error (exit 4).
      if (batch.first_triangle + faces > (uint64_t(1) << 32)) {
        throw Error(ErrorKind::resource, input_.path.string() + ": triangle " + std::to_string(batch.first_triangle) +
                                             ": its polygons make more than 2^32 triangles, more than the "
                                             "out-of-core re-encode's 32-bit face records can number");
      }
      item.cells.resize(faces);
      uint64_t largest = 0;
      const LocalBuckets buckets{chunk};
      if (item.records_decoded) {  // indices checked by the decode
        const std::byte* records = item.block_records.data();
        for (size_t i = 0; i < faces; ++i) {
          const auto abc = id_record_vertices(records + i * id_triangle32_record_size);
          const uint32_t lo = std::min({abc[0], abc[1], abc[2]}), hi = std::max({abc[0], abc[1], abc[2]});
          largest = std::max<uint64_t>(largest, hi);
          item.cells[i] = buckets(lo, hi);
        }
        item.max_index = largest;
        item.classified = true;
        return;
      }
      item.block_records.resize(faces * id_triangle32_record_size);
      for (size_t i = 0; i < faces; ++i) {
        const Triangle& t = batch.triangles[i];
        const uint64_t lo = std::min({t[0], t[1], t[2]}), hi = std::max({t[0], t[1], t[2]});
        largest = std::max(largest, hi);
        if (info.vertex_count && hi >= *info.vertex_count) {
          index_out_of_range(input_.path, batch.first_triangle + i, hi, *info.vertex_count);
        }
        std::byte* record = item.block_records.data() + i * id_triangle32_record_size;
        put_u32_pair(record, batch.first_triangle + i, t[0]);
        put_u32_pair(record + 8, t[1], t[2]);
        item.cells[i] = buckets(lo, hi);
      }
      item.max_index = largest;
      item.classified = true;
    };
    pass.sink = [&](InputItem& item, Lease& lease) {
      const auto& batch = item.batch;
      box_.add(item.box);
      for (auto& [c, frame] : item.vertex_frames) {
        uint64_t first = 0, count = 0;
        uint16_t record_size = 0;
        std::memcpy(&record_size, frame.data() + 6, 2);  // the frame header's record size, tag and count
        std::memcpy(&first, frame.data() + 12, 8);
        std::memcpy(&count, frame.data() + 20, 8);
        Lease frame_lease = lease.split(frame.capacity());
        vertex_writer.write(c, std::move(frame), count, first, record_size, std::move(frame_lease));
      }
      vertex_count = std::max<uint64_t>(vertex_count, batch.first_vertex + batch.vertices.size() + item.xyz_decoded);
      if (weld_spill) {
        for (size_t i = 0; i < batch.vertices.size(); ++i) {
          WeldRecord record{batch.vertices[i], batch.first_vertex + i};
          weld_spill->add(weld_bucket(record.position, weld_buckets), &record);
        }
      }
      auto spanning_face = [&](uint64_t face, const Triangle& t) {
        for (int k = 0; k < 3; ++k) {
          CornerRef ref{face * 3 + uint64_t(k), t[k]};
          corners.add(uint32_t(t[k] / chunk), &ref);
        }
        if (spanning) {
          LocalFace record{face, t};
          spanning->add(0, &record);
        }
        ++mesh_.corner_faces;
      };
      if (item.classified) {
        max_index = std::max(max_index, item.max_index);
        const size_t faces = item.cells.size();
        for_each_cell_run(item.cells.data(), faces, [&](uint32_t bucket, uint64_t begin, uint64_t end) {
          if (bucket == UINT32_MAX) {
            for (uint64_t f = begin; f < end; ++f) {
              const auto abc = id_record_vertices(item.block_records.data() + f * id_triangle32_record_size);
              spanning_face(batch.first_triangle + f, Triangle{abc[0], abc[1], abc[2]});
            }
          } else {
            local.add_run(bucket, item.block_records.data() + begin * id_triangle32_record_size, end - begin);
            mesh_.local_faces += end - begin;
          }
        });
        face_count = std::max<uint64_t>(face_count, batch.first_triangle + faces);
        return;
      }
      if (local_size == id_triangle32_record_size && !batch.triangles.empty())
        throw Error(ErrorKind::internal, "loader: u32 local faces reached the sink unclassified");
      for (size_t i = 0; i < batch.triangles.size(); ++i) {
        uint64_t face = batch.first_triangle + i;
        const Triangle& t = batch.triangles[i];
        uint64_t lo = std::min({t[0], t[1], t[2]}), hi = std::max({t[0], t[1], t[2]});
        max_index = std::max(max_index, hi);
        if (info.vertex_count && hi >= *info.vertex_count) index_out_of_range(input_.path, face, hi, *info.vertex_count);
        // Not classified by the transform: local records are LocalFaces.
        if (const uint32_t bucket = local_bucket(lo, hi, chunk); bucket != UINT32_MAX) {
          LocalFace record{face, t};
          local.add(bucket, &record);
          ++mesh_.local_faces;
          continue;
        }
        spanning_face(face, t);
      }
      if (!batch.triangles.empty()) face_count = std::max<uint64_t>(face_count, batch.first_triangle + batch.triangles.size());
    };
    run_stream_pass(job_, pass);
    input_.vertex_floats = false;
    input_.decoded_records = 0;
    vertex_writer.finish();
    give_back(local.finish());
    give_back(corners.finish());
    if (weld_spill) give_back(weld_spill->finish());
    if (spanning) give_back(spanning->finish());
    if (face_count && max_index >= vertex_count) index_out_of_range(input_.path, 0, max_index, vertex_count);
    mesh_.vertex_count = mesh_.vertices.count = vertex_count;
    mesh_.face_count = face_count;
    mesh_.float_exact = box_.float_exact;
    const uint32_t chunks = uint32_t(std::max<uint64_t>((vertex_count + chunk - 1) / chunk, 1));
    mesh_.vertices.windows.resize(chunks);
    // Sized by the header's face count where it has one, as the resident load is: a
    // PLY with polygon faces has more triangles, and another grid files them in
    // another order.
    const uint64_t grid_faces = info.polygon_count.value_or(face_count);
    input_.close();
    if (vertex_count == 0) box_.min = box_.max = Point{0, 0, 0};
    build_grid(grid_faces);
    timer.reset();

    if (weld_spill) weld_by_buckets(*weld_spill, vertex_count);
    if (options_.degrees) count_degrees_from_spills(local, *spanning, vertex_count);
    if (hooks_.counted) hooks_.counted(mesh_);
    resolve_faces(local, corners, local_size, chunk, chunks);
  }

  // Out-of-core weld: each position-hash bucket loaded, sorted by (position, index),
  // runs of equal positions mapped to their first index. Equal positions share a bucket.
  void weld_by_buckets(BucketSpill& spill, uint64_t vertex_count) {
    StageTimer timer(job_, "weld");
    for (uint32_t b = 0; b < spill.bucket_count(); ++b) {
      const uint64_t n = spill.records(b);
      if (n == 0) continue;
      const uint64_t bytes = n * sizeof(WeldRecord);
      if (bytes > reserve_.bytes()) {
        throw Error(ErrorKind::resource, "loader: a weld bucket of " + std::to_string(n) +
                                             " vertices (" + config::format_size(bytes) +
                                             ") does not fit the memory budget; this needs a budget of at least " +
                                             config::format_budget(budget_for_shortfall(bytes - reserve_.bytes())));
      }
      Lease bucket_lease = take("weld bucket", bytes);
      UninitializedVector<WeldRecord> records(n);
      uint64_t at = 0;
      for_each_frame(job_, scratch_, "weld", "weld frames", spill.frames(b), sizeof(WeldRecord), {},
                     [&](const FrameHeader& header, Bytes& frame, Lease&) {
                       std::memcpy(static_cast<void*>(records.data() + at), frame.data(), header.count * sizeof(WeldRecord));
                       at += header.count;
                     },
                     0);
      if (at != n) throw Error(ErrorKind::internal, "weld bucket lost records");
      job_.arena().execute([&] {
        tbb::parallel_sort(records.begin(), records.end(), [](const WeldRecord& a, const WeldRecord& b) {
          PositionKey ka = position_key(a.position), kb = position_key(b.position);
          return ka != kb ? ka < kb : a.index < b.index;
        });
      });
      weld_.add_runs(n, [&](uint64_t i) { return records[i].position; }, [&](uint64_t i) { return records[i].index; });
      release_memory(records);
      give_back(std::move(bucket_lease));
      job_.check();
    }
    remove_files(spill);
    finish_weld(vertex_count);
  }

  // Out of core: every face (local ones from their buckets, spanning ones whole)
  // counted around its welded vertices before any record is made.
  void count_degrees_from_spills(const BucketSpill& local, BucketSpill& spanning, uint64_t vertex_count) {
    StageTimer timer(job_, "degrees");
    start_degrees(vertex_count);
    std::vector<FrameRef> frames;
    for (uint32_t b = 0; b < local.bucket_count(); ++b) frames.insert(frames.end(), local.frames(b).begin(), local.frames(b).end());
    for (uint32_t b = 0; b < spanning.bucket_count(); ++b) frames.insert(frames.end(), spanning.frames(b).begin(), spanning.frames(b).end());
    for_each_frame(
        job_, scratch_, "degrees", "face frames", frames, sizeof(LocalFace),
        [&](const FrameHeader& header, Bytes& records, Lease&) {
          auto* faces = reinterpret_cast<LocalFace*>(records.data());
          for (uint64_t i = 0; i < header.count; ++i) {
            auto t = welded(faces[i].vertices);
            faces[i].vertices = t ? *t : Triangle{UINT64_MAX, UINT64_MAX, UINT64_MAX};
          }
        },
        [&](const FrameHeader& header, Bytes& records, Lease&) {
          const auto* faces = reinterpret_cast<const LocalFace*>(records.data());
          for (uint64_t i = 0; i < header.count; ++i) {
            if (faces[i].vertices[0] == UINT64_MAX) continue;
            for (uint64_t v : faces[i].vertices) degree_.add(v);
          }
        },
        0);
    remove_files(spanning);
  }

  // Pass 2: one walk over the vertex chunks in index order, each read from scratch
  // once. With chunk c (and c+1) loaded: the local faces of bucket c become whole faces
  // and go to their blocks, the corners that fall in chunk c are resolved, and the
  // chunk is handed to hooks_.vertices (the re-encode writes it to the output). Then,
  // for faces that span chunks (passes 3 and 4), the resolved corners are regrouped
  // by face-id range and the faces rebuilt range by range.
  void resolve_faces(BucketSpill& local, BucketSpill& corners, uint32_t local_size, uint64_t chunk, uint32_t chunks) {
    std::optional<StageTimer> timer(std::in_place, job_, "resolve");
    const uint64_t face_count = mesh_.face_count;
    const uint64_t range = options_.range_faces
                               ? options_.range_faces
                               : std::max<uint64_t>(1024, uint64_t(double(capacity_) * 0.3) / (3 * 32));
    const uint64_t range_count = std::max<uint64_t>((face_count + range - 1) / range, 1);
    const bool spanning = corners.records() > 0;
    Lease pair_lease = take("vertex window", 2 * chunk * sizeof(Point));
    std::optional<BucketSpill> resolved;
    if (spanning) {
      resolved.emplace(job_, scratch_, "resolved", sizeof(ResolvedCorner),
                       spill_lease("corner resolver", 0.1, sizeof(ResolvedCorner)), uint32_t(range_count), "resolve");
    }
    BucketSpill blocks(job_, scratch_, "blocks-local", choose_block_layout(),
                       spill_lease("block writer", 0.3, sizeof(BlockFace)), mesh_.grid.count(), "resolve");
    note_spill_frames({resolved ? &*resolved : nullptr, &blocks}, face_count, mesh_.vertex_count, "resolve");
    // Float-exact triangle-only loads (the re-encode) keep the pair as the frames'
    // floats: half the memory the face lookups wander over, no widening, and the
    // chunk goes to hooks_.float_vertices as it is. Others widen to Points.
    const bool floats = verbatim_triangles() && box_.float_exact && bool(hooks_.float_vertices);
    UninitializedVector<Point> pair(floats ? 0 : 2 * chunk);  // chunks c and c+1
    UninitializedVector<float> pair_xyz(floats ? 6 * chunk : 0);
    advise_huge_pages(pair_xyz.data(), pair_xyz.data() + pair_xyz.size());
    auto position = [&](uint64_t at) -> Point {
      if (floats) return {pair_xyz[3 * at], pair_xyz[3 * at + 1], pair_xyz[3 * at + 2]};
      return pair[at];
    };
    uint32_t upper_loaded = UINT32_MAX;  // which chunk sits in the upper half
    // The frame buffers of the loop's passes (a few frames each), reused across them.
    // Every pass in the loop takes from it (so a parked pump holds one at most) but
    // load_vertex_window's: cleared before that one.
    FramePool buffers;
    bool handed_out = false;  // the lower half may still be read by an I/O task
    auto wait_for_hand_out = [&] {
      if (!handed_out) return;
      job_.io().drain();
      job_.check();
      handed_out = false;
    };
    for (uint32_t c = 0; c < chunks; ++c) {
      const bool has_local = c < local.bucket_count() && !local.frames(c).empty();
      const bool has_corners = c < corners.bucket_count() && !corners.frames(c).empty();
      if (!has_local && !has_corners && !hooks_.vertices && !floats) continue;
      wait_for_hand_out();
      const uint64_t first = uint64_t(c) * chunk;
      const uint64_t n = std::min<uint64_t>(chunk, mesh_.vertex_count - std::min(first, mesh_.vertex_count));
      if (upper_loaded == c) {
        if (floats) {
          std::copy(pair_xyz.begin() + int64_t(3 * chunk), pair_xyz.end(), pair_xyz.begin());
        } else {
          std::copy(pair.begin() + int64_t(chunk), pair.end(), pair.begin());
        }
      } else if (floats) {
        load_float_vertex_window(c, pair_xyz.data(), &buffers);
      } else {
        buffers.clear();
        load_vertex_window(job_, scratch_, mesh_.vertices, c, pair.data());
      }
      upper_loaded = UINT32_MAX;
      if (has_local && c + 1 < chunks) {
        if (floats) {
          load_float_vertex_window(c + 1, pair_xyz.data() + 3 * chunk, &buffers);
        } else {
          buffers.clear();
          load_vertex_window(job_, scratch_, mesh_.vertices, c + 1, pair.data() + chunk);
        }
        upper_loaded = c + 1;
      }
      if (n > 0 && (floats || hooks_.vertices)) {
        if (floats) {
          hooks_.float_vertices(first, pair_xyz.data(), n);
        } else {
          hooks_.vertices(first, pair.data(), n);
        }
        handed_out = true;
      }
      if (has_local) {
        // u32 local records that are the block records already (id and ids): only
        // their cells are made, in place (4 bytes a record); else block records and
        // cells, anew.
        const bool cells_in_place = local_size == id_triangle32_record_size &&
                                    mesh_.block_record_size == id_triangle32_record_size && verbatim_triangles();
        for_each_frame(
            job_, scratch_, "resolve", "local face frames", local.frames(c), local_size,
            [&](const FrameHeader& header, Bytes& records, Lease&) {
              // Records become block records followed by their cells, in one buffer.
              const uint32_t size = mesh_.block_record_size;
              if (cells_in_place) {
                // The local records are the block records already (u32 id and ids):
                // the cells go after them, in the room the frame's read left (no new
                // buffer).
                const uint64_t n = header.count;
                records.resize(n * (size + sizeof(uint32_t)));
                const std::byte* ids_at = records.data() + sizeof(uint32_t);
                auto* cells = reinterpret_cast<uint32_t*>(records.data() + n * size);
                const uint64_t pair_vertices = floats ? pair_xyz.size() / 3 : pair.size();
                if (floats) {
                  // Over a window pair the arithmetic, not memory, sets the pace: the division-free kernel.
                  face_cells_xyz(mesh_.grid, pair_xyz.data(), first, pair_vertices, ids_at, size, n, cells);
                  return;
                }
                for (uint64_t i = 0; i < n; ++i, ids_at += size) {
                  if (i + prefetch_faces_ahead < n) {  // as in load_resident
                    uint32_t ahead[3];
                    std::memcpy(ahead, ids_at + prefetch_faces_ahead * size, sizeof ahead);
                    for (uint32_t v : ahead) {
                      const uint64_t at = uint64_t(v) - first;  // wraps past the end when below
                      if (at < pair_vertices) prefetch_position(floats, pair_xyz.data(), pair.data(), at);
                    }
                  }
                  uint32_t ids[3];
                  std::memcpy(ids, ids_at, sizeof ids);
                  cells[i] = mesh_.grid.cell_of(
                      barycenter({position(ids[0] - first), position(ids[1] - first), position(ids[2] - first)}));
                }
                return;
              }
              Bytes out(header.count * (size + sizeof(uint32_t)));
              auto* cells = reinterpret_cast<uint32_t*>(out.data() + header.count * size);
              BlockFace face;
              for (uint64_t i = 0; i < header.count; ++i) {
                LocalFace local_face;
                if (local_size == id_triangle32_record_size) {
                  uint32_t record[4];
                  std::memcpy(record, records.data() + i * local_size, sizeof record);
                  local_face = {record[0], {record[1], record[2], record[3]}};
                } else {
                  std::memcpy(&local_face, records.data() + i * local_size, sizeof local_face);
                }
                face.id = local_face.id;
                for (int k = 0; k < 3; ++k) face.positions[k] = position(local_face.vertices[k] - first);
                cells[i] = prepare(face, local_face.vertices) ? make_record(face, out.data() + i * size) : UINT32_MAX;
              }
              records.swap(out);
            },
            [&](const FrameHeader& header, Bytes& records, Lease&) {
              const auto* cells = reinterpret_cast<const uint32_t*>(records.data() + header.count * mesh_.block_record_size);
              mesh_.dropped_faces += add_record_runs(blocks, records.data(), cells, header.count);
            },
            cells_in_place ? id_triangle32_record_size + sizeof(uint32_t) : sizeof(BlockFace) + sizeof(uint32_t), false,
            cells_in_place, &buffers);
        discard_frames(local.frames(c));  // their last read (the files go after the loop)
      }
      if (has_corners) {
        for_each_frame(
            job_, scratch_, "resolve", "corner frames", corners.frames(c), sizeof(CornerRef),
            [&](const FrameHeader& header, Bytes& records, Lease&) {
              // In place, in the room the frame's read left: backwards, so that each
              // ref is read before anything is written over it (ref i goes from 16i
              // to 40i, at or after where it was).
              static_assert(sizeof(ResolvedCorner) >= sizeof(CornerRef));
              records.resize(header.count * sizeof(ResolvedCorner));
              for (uint64_t i = header.count; i-- > 0;) {
                CornerRef ref;
                std::memcpy(&ref, records.data() + i * sizeof(CornerRef), sizeof ref);
                const ResolvedCorner res{ref.corner, ref.vertex, position(ref.vertex - first)};
                std::memcpy(records.data() + i * sizeof(ResolvedCorner), &res, sizeof res);
              }
            },
            [&](const FrameHeader& header, Bytes& records, Lease&) {
              const auto* res = reinterpret_cast<const ResolvedCorner*>(records.data());
              for (uint64_t i = 0; i < header.count; ++i) resolved->add(uint32_t(res[i].corner / 3 / range), &res[i]);
            },
            sizeof(ResolvedCorner), false, true, &buffers);
        discard_frames(corners.frames(c));  // their last read (the files go after the loop)
      }
      job_.progress(0.4 + 0.4 * double(c + 1) / chunks, "resolve");
    }
    buffers.clear();
    wait_for_hand_out();
    mesh_.vertices_delivered = bool(hooks_.vertices) || floats;
    release_memory(pair);
    release_memory(pair_xyz);
    give_back(std::move(pair_lease));
    collect_blocks(blocks);
    remove_files(local);
    if (!spanning) return;
    BucketSpill& resolved_corners = *resolved;
    give_back(resolved_corners.finish());
    remove_files(corners);
    trim_allocator();
    timer.emplace(job_, "assemble");

    BucketSpill spanning_blocks(job_, scratch_, "blocks-spanning", choose_block_layout(),
                       spill_lease("block writer", 0.3, sizeof(BlockFace)), mesh_.grid.count(), "assemble");
    note_spill_frames({&spanning_blocks}, mesh_.face_count, mesh_.vertex_count, "assemble");
    // Slots for every face of a range (only spanning faces fill theirs), made once for
    // the largest range and filled range after range: fresh slots per range were
    // fresh pages, most of a shuffled input's page faults. So are the frame buffers
    // (kept across the ranges' passes; nothing else waits for memory in this loop).
    const uint64_t slots = std::min<uint64_t>(range, face_count);
    Lease range_lease = take("face range", slots * 3 * 32 + slots);
    UninitializedVector<uint64_t> vertex_of(3 * slots);
    UninitializedVector<Point> position_of(3 * slots);
    std::vector<uint8_t> filled(slots);
    FramePool frame_buffers;
    for (uint32_t r = 0; r < range_count && r < resolved_corners.bucket_count(); ++r) {
      if (resolved_corners.records(r) == 0) continue;
      uint64_t first_face = uint64_t(r) * range;
      uint64_t n = std::min<uint64_t>(range, face_count - first_face);
      std::fill_n(filled.begin(), n, uint8_t{0});
      for_each_frame(job_, scratch_, "assemble", "resolved frames", resolved_corners.frames(r), sizeof(ResolvedCorner),
                     [&](const FrameHeader& header, Bytes& records, Lease&) {
                       const auto* res = reinterpret_cast<const ResolvedCorner*>(records.data());
                       for (uint64_t i = 0; i < header.count; ++i) {
                         uint64_t slot = res[i].corner - first_face * 3;
                         vertex_of[slot] = res[i].vertex;
                         position_of[slot] = res[i].position;
                       }
                     },
                     [&](const FrameHeader& header, Bytes& records, Lease&) {
                       const auto* res = reinterpret_cast<const ResolvedCorner*>(records.data());
                       for (uint64_t i = 0; i < header.count; ++i) ++filled[res[i].corner / 3 - first_face];
                     },
                     0, false, false, &frame_buffers);
      discard_frames(resolved_corners.frames(r));  // their last read (the files go after the loop)
      Span span(&job_.trace(), &job_.activity(), "assemble faces");
      BlockFace face;
      for (uint64_t i = 0; i < n; ++i) {
        if (filled[i] == 0) continue;
        if (filled[i] != 3) throw Error(ErrorKind::internal, "face " + std::to_string(first_face + i) + ": corners lost");
        face.id = first_face + i;
        for (int k = 0; k < 3; ++k) face.positions[k] = position_of[3 * i + k];
        if (!prepare(face, {vertex_of[3 * i], vertex_of[3 * i + 1], vertex_of[3 * i + 2]})) {
          ++mesh_.dropped_faces;
          continue;
        }
        add_face(spanning_blocks, face);
      }
      job_.check();
      job_.progress(0.8 + 0.1 * double(r + 1) / range_count, "assemble");
    }
    frame_buffers.clear();
    release_memory(vertex_of);
    release_memory(position_of);
    release_memory(filled);
    give_back(std::move(range_lease));
    collect_blocks(spanning_blocks);
    remove_files(resolved_corners);
  }

  // Window w of a float-exact mesh's vertices (every frame of floats) as xyz floats.
  void load_float_vertex_window(uint64_t w, float* out, FramePool* buffers = nullptr) {
    const VertexStore& store = mesh_.vertices;
    const uint64_t first = w * store.window;
    for (const FrameRef& ref : store.windows.at(w)) {
      if (ref.record_size != float_vertex_record_size) throw Error(ErrorKind::internal, "a vertex frame of doubles in a float-exact mesh");
    }
    for_each_frame(job_, scratch_, "vertices", "vertex frames", store.windows.at(w), float_vertex_record_size,
                   [&](const FrameHeader& header, Bytes& records, Lease&) {
                     if (header.tag < first || header.tag + header.count > first + store.window) {
                       throw Error(ErrorKind::internal, "vertex frame outside its window");
                     }
                     std::memcpy(out + 3 * (header.tag - first), records.data(), records.size());
                   },
                   {}, 0, false, false, buffers);
  }

  // Frames read for the last time: their pages serve the writes that follow
  // (ScratchStore::discard), queued behind the reads.
  void discard_frames(const std::vector<FrameRef>& frames) {
    job_.io().submit(
        "discard frames",
        [this, frames] {
          for (const FrameRef& ref : frames) scratch_.discard(ref.file, ref.offset, ref.bytes);
        },
        job_.error_handler());
  }

  void remove_files(const BucketSpill& spill) {
    std::vector<uint32_t> files;
    for (uint32_t b = 0; b < spill.bucket_count(); ++b) {
      if (!spill.frames(b).empty()) files.push_back(spill.frames(b)[0].file);
    }
    job_.io().call("scratch remove", [&] {
      for (uint32_t f : files) scratch_.remove(f);
    });
  }

  Job& job_;
  ScratchStore& scratch_;
  LoadOptions options_;
  LoadHooks hooks_;
  InputStream input_;
  Lease window_;   // a .zst input's decoder window, when larger than zstd_window_allowance
  Lease reserve_;  // the loader's working set; parts are split off and merged back
  uint64_t capacity_ = 0;
  uint64_t held_outside_ = 0;  // what other owners held when the reservation was granted
  double progress_span_ = 0.4;
  double progress_base_ = 0;
  Lease state_lease_;  // covers weld_ and degree_ (declared first: released last)
  WeldMap weld_;
  DegreeCounter degree_;
  Box box_;
  LoadedMesh mesh_;
};

}  // namespace

bool is_triangle_record(uint32_t record_size) {
  return record_size == triangle32_record_size || record_size == triangle64_record_size ||
         record_size == ply_triangle_record_size;
}

bool is_id_triangle_record(uint32_t record_size) {
  return record_size == id_triangle32_record_size || record_size == id_triangle64_record_size;
}

void unpack_block_triangles(const std::byte* records, uint64_t count, uint32_t record_size, Triangle* out) {
  if (record_size == triangle64_record_size) {
    std::memmove(static_cast<void*>(out), records, count * sizeof(Triangle));
    return;
  }
  if (record_size == ply_triangle_record_size) {
    // Backwards as below (a record is 13 bytes, a Triangle 24).
    for (uint64_t i = count; i-- > 0;) {
      uint32_t ids[3];
      std::memcpy(ids, records + i * ply_triangle_record_size + 1, sizeof ids);
      out[i] = {ids[0], ids[1], ids[2]};
    }
    return;
  }
  if (record_size != triangle32_record_size) throw Error(ErrorKind::internal, "not a triangle block record");
  // Backwards, so that `out` may start where `records` does (in-place widening).
  for (uint64_t i = count; i-- > 0;) {
    uint32_t ids[3];
    std::memcpy(ids, records + i * triangle32_record_size, sizeof ids);
    out[i] = {ids[0], ids[1], ids[2]};
  }
}

void unpack_block_faces(const std::byte* records, uint64_t count, uint32_t record_size, BlockFace* out) {
  if (record_size == sizeof(BlockFace)) {
    std::memcpy(static_cast<void*>(out), records, count * sizeof(BlockFace));
    return;
  }
  if (record_size != sizeof(PackedBlockFace)) throw Error(ErrorKind::internal, "unknown block record layout");
  for (uint64_t i = 0; i < count; ++i) {
    PackedBlockFace packed;
    std::memcpy(&packed, records + i * sizeof packed, sizeof packed);
    out[i].id = packed.id;
    out[i].vertices = packed.vertices;
    for (int k = 0; k < 9; ++k) out[i].positions[k / 3][k % 3] = packed.positions[k];
    out[i].degree = packed.degree;
    out[i].unused = 0;
  }
}

BlockGrid BlockGrid::around(const Point& min, const Point& max, uint32_t blocks) {
  BlockGrid grid;
  grid.min = min;
  grid.max = max;
  double e[3], largest = 0;
  for (int i = 0; i < 3; ++i) {
    e[i] = std::max(max[i] - min[i], 0.0);
    largest = std::max(largest, e[i]);
  }
  if (largest <= 0 || blocks <= 1) return grid;
  for (double& x : e) x = std::max(x, largest * 1e-3);
  double cell = std::cbrt(e[0] * e[1] * e[2] / blocks);
  for (int i = 0; i < 3; ++i) {
    grid.dims[i] = uint32_t(std::clamp<double>(std::round(e[i] / cell), 1, 256));
  }
  return grid;
}

void for_each_frame(Job& job, ScratchStore& scratch, const char* stage, const char* owner,
                    const std::vector<FrameRef>& frames, uint32_t record_size, const FrameUse& transform,
                    const FrameUse& sink, uint32_t out_record_size, bool ordered, bool in_place,
                    FramePool* pool, bool read_once) {
  // The header and the payload are read apart, so that a raw payload is the records
  // themselves: no copy between the disk's bytes and the transform.
  struct FrameItem {
    FrameRef ref;
    std::array<std::byte, frame_header_bytes> header_bytes;
    Bytes records;
    FrameHeader header;
  };
  size_t next = 0;
  // The frames after the one being read, up to kReadAheadBytes, are asked of the kernel
  // (ScratchStore::will_need): a gather's frames lie scattered over a state the page
  // cache may not hold, and one pread at a time left the disk idle between them.
  constexpr uint64_t kReadAheadBytes = uint64_t(32) << 20;
  size_t advised = 0;      // frames[.. advised) asked for
  uint64_t advised_ahead = 0;  // their bytes after frames[next - 1]
  FramePool own_pool;
  FramePool& kept = pool ? *pool : own_pool;
  using Kept = FramePool::Kept;
  std::optional<Kept> taken;  // the pump's (I/O thread): for frames[next]
  auto room_for = [&](const FrameRef& ref) {
    return in_place ? std::max(ref.bytes - frame_header_bytes, ref.count * out_record_size) : ref.bytes - frame_header_bytes;
  };
  auto item_bytes = [&](const FrameRef& ref) { return ref.bytes + ref.count * (record_size + out_record_size); };
  StreamPass<FrameItem> pass;
  pass.stage = stage;
  pass.read_name = "read scratch";
  pass.transform_name = "decode";
  pass.owner = owner;
  pass.ordered = ordered;
  pass.next_item_bytes = [&] {
    if (next == frames.size()) return uint64_t(1);
    const FrameRef& ref = frames[next];
    const uint64_t need = item_bytes(ref);
    // A buffer that holds the records and is no larger than the item's lease.
    kept.choose(taken, [&](const Kept& kept) {
      return kept.buffer.capacity() >= room_for(ref) && kept.lease.bytes() <= need;
    });
    return taken ? std::max<uint64_t>(need - taken->lease.bytes(), 1) : need;
  };
  pass.read = [&](FrameItem& item, Lease& lease) {
    if (next == frames.size()) return false;
    item.ref = frames[next++];
    if (advised < next) {
      advised = next;
      advised_ahead = 0;
    } else {
      advised_ahead -= item.ref.bytes;
    }
    for (; advised < frames.size() && advised_ahead < kReadAheadBytes; ++advised) {
      scratch.will_need(frames[advised].file, frames[advised].offset, frames[advised].bytes);
      advised_ahead += frames[advised].bytes;
    }
    const std::string where = "frame " + std::to_string(item.ref.file) + "@" + std::to_string(item.ref.offset);
    if (item.ref.bytes < frame_header_bytes) throw Error(ErrorKind::internal, where + ": shorter than its header");
    if (taken) {
      item.records = std::move(taken->buffer);
      lease.merge(std::move(taken->lease));
      taken.reset();
    }
    scratch.read(item.ref.file, item.ref.offset, item.header_bytes.data(), frame_header_bytes);
    // Room for what transform makes of the records (the lease covers it), so that it
    // can write them in place rather than into a new buffer.
    // A fresh buffer gets some slack within its lease, so that the next frames (of
    // about the same count) fit it too.
    if (item.records.capacity() < room_for(item.ref)) {
      item.records.reserve(std::min(lease.bytes(), room_for(item.ref) + room_for(item.ref) / 4));
    }
    item.records.resize(item.ref.bytes - frame_header_bytes);
    scratch.read(item.ref.file, item.ref.offset + frame_header_bytes, item.records.data(), item.records.size());
    if (read_once) scratch.discard(item.ref.file, item.ref.offset, item.ref.bytes);
    job.stage(stage).bytes_read += item.ref.bytes;
    return true;
  };
  pass.transform = [&](FrameItem& item, Lease& lease) {
    item.header = decode_frame_payload(item.header_bytes.data(), item.records, record_size,
                                       "frame " + std::to_string(item.ref.file) + "@" + std::to_string(item.ref.offset));
    if (transform) transform(item.header, item.records, lease);
  };
  pass.sink = [&](FrameItem& item, Lease& lease) {
    if (sink) sink(item.header, item.records, lease);
    if (kept.keep(item.records, lease)) job.governor().wake_all();
  };
  // Parked: nothing kept but the buffer taken for this read (counted in what it waits
  // for), so that the pool never holds bytes the governor is waiting for.
  pass.parked_for_memory = [&kept] { kept.clear(); };
  struct GiveBackTaken {  // a buffer taken for a frame never read stays kept
    FramePool& pool;
    std::optional<Kept>& taken;
    ~GiveBackTaken() {
      if (taken && !pool.keep(taken->buffer, taken->lease)) taken.reset();
    }
  } give_back_taken{kept, taken};
  run_stream_pass(job, pass);
}

void FramePool::choose(std::optional<Kept>& taken, const std::function<bool(const Kept&)>& fits) {
  std::vector<Kept> freed = take_all();
  if (taken && !fits(*taken)) taken.reset();
  for (Kept& one : freed) {
    if (!taken && fits(one)) {
      taken = std::move(one);
    } else if (one.lease && !keep(one.buffer, one.lease)) {
      break;  // the pool filled meanwhile: the rest are freed
    }
  }
  freed.clear();  // buffers freed, then their leases (releases wake waiters)
}

bool FramePool::keep(Bytes& buffer, Lease& lease, size_t max_kept) {
  const uint64_t capacity = buffer.capacity();
  if (capacity == 0 || capacity > lease.bytes()) return false;  // moved away, or not covered
  std::lock_guard lock(mutex_);
  if (kept_.size() >= max_kept) return false;
  kept_.push_back({lease.split(capacity), std::move(buffer)});
  return true;
}

void load_vertex_window(Job& job, ScratchStore& scratch, const VertexStore& store, uint64_t window,
                        Point* out) {
  uint64_t first = window * store.window;
  if (store.is_resident()) {
    uint64_t n = std::min<uint64_t>(store.window, store.count - first);
    if (!store.resident_xyz.empty()) {
      for (uint64_t i = 0; i < n; ++i) {
        const float* p = store.resident_xyz.data() + 3 * (first + i);
        out[i] = {p[0], p[1], p[2]};
      }
      return;
    }
    std::copy(store.resident.begin() + first, store.resident.begin() + first + n, out);
    return;
  }
  // Frames of floats (float_vertex_record_size) or of Points; one pass per run of
  // frames of one size (a window mixes them only when the input mixes float-exact and
  // other coordinates).
  const auto& frames = store.windows.at(window);
  for (size_t begin = 0; begin < frames.size();) {
    const uint32_t record_size = frames[begin].record_size ? frames[begin].record_size : uint32_t(sizeof(Point));
    size_t end = begin + 1;
    while (end < frames.size() && (frames[end].record_size ? frames[end].record_size : sizeof(Point)) == record_size) ++end;
    const std::vector<FrameRef> run(frames.begin() + int64_t(begin), frames.begin() + int64_t(end));
    for_each_frame(job, scratch, "vertices", "vertex frames", run, record_size,
                   [&](const FrameHeader& header, Bytes& records, Lease&) {
                     if (header.tag < first || header.tag + header.count > first + store.window) {
                       throw Error(ErrorKind::internal, "vertex frame outside its window");
                     }
                     Point* at = out + (header.tag - first);
                     if (record_size == sizeof(Point)) {
                       std::memcpy(static_cast<void*>(at), records.data(), records.size());
                       return;
                     }
                     const std::byte* xyz = records.data();
                     for (uint64_t i = 0; i < header.count; ++i, xyz += float_vertex_record_size) {
                       float p[3];
                       std::memcpy(p, xyz, sizeof p);
                       at[i] = {p[0], p[1], p[2]};
                     }
                   },
                   {}, 0);
    begin = end;
  }
}

LoadedMesh load_into_blocks(Job& job, ScratchStore& scratch, const std::filesystem::path& input,
                            const LoadOptions& options, const LoadHooks& hooks) {
  return Loader(job, scratch, input, options, hooks).run();
}

std::optional<InputCountsBound> input_counts_bound(const std::filesystem::path& input) {
  const io::MeshFileKind kind = io::mesh_file_kind(input);
  if (kind.obj || kind.zstd) return std::nullopt;
  io::ByteSource source(input, false, 1 << 16);
  const io::PlyHeader header = io::read_ply_header(source);
  if (header.format == io::MeshFormat::ply_ascii || !header.face_element) return std::nullopt;
  // The face element's bytes are the body's less the other elements' (fixed records);
  // each triangle past a polygon's first takes one more index, of at least
  // index-size bytes, so the body's size bounds the fan (a file of triangles: exact).
  uint64_t other_bytes = 0;
  for (size_t e = 0; e < header.elements.size(); ++e) {
    if (e == *header.face_element) continue;
    const size_t record = header.elements[e].fixed_record_size();
    if (record == 0) return std::nullopt;
    other_bytes += header.elements[e].count * record;
  }
  const io::PlyElement& faces = header.elements[*header.face_element];
  uint64_t least_face = 0, index_size = 0;
  for (size_t k = 0; k < faces.properties.size(); ++k) {
    const io::PlyProperty& p = faces.properties[k];
    if (k == header.index_property) {
      index_size = io::size_of(p.type);
      least_face += io::size_of(p.count_type) + 3 * index_size;
    } else if (p.is_list) {
      return std::nullopt;
    } else {
      least_face += io::size_of(p.type);
    }
  }
  const uint64_t file = std::filesystem::file_size(input);
  const uint64_t polygons = faces.count;
  if (index_size == 0 || file < header.byte_count + other_bytes) return std::nullopt;
  const uint64_t face_bytes = file - header.byte_count - other_bytes;
  const uint64_t extra = face_bytes > polygons * least_face ? (face_bytes - polygons * least_face) / index_size : 0;
  return InputCountsBound{polygons + extra, header.elements[header.vertex_element].count};
}

// Every record the load files, counted as if none were removed (spills go as the
// load moves on, so this bounds what is on disk at once), at its widest layout: a
// face is either local (one LocalFace, 32 bytes) or spanning (3 CornerRefs, 48; its
// LocalFace among the spanning faces, 32; 3 ResolvedCorners, 120), then one block
// record (a BlockFace, 120); a vertex is a window record (a Point, 24) and a weld
// record (32). The resident load writes only the blocks.
//
// Frame envelopes (a raw frame's header and checksum, 56 bytes) come on top. Where
// every spill of the load holds two pages per bucket (!small_frames), a flush's frames
// average half a page or more (BucketSpill::small_frames: the envelopes are under 6%
// of the records) and the finish adds at most one frame per page held, 56 bytes per
// 2 KiB of the spills' leases, which an out-of-core load's records outweigh many times
// over: an eighth more covers both. Where a spill has fewer pages than that (the
// loader's "not paged" case, face ranges or grid blocks outnumbering their spill's
// pages; review16: frames of 1-3 records, a peak 1.19-1.28x the eighth's bound), a
// frame may hold a single record: every record is then counted with an envelope of
// its own, which no frame can exceed.
static uint64_t with_frame_envelopes(uint64_t record_bytes, uint64_t records, bool small_frames) {
  return small_frames ? record_bytes + records * frame_envelope_bytes + (1 << 20)
                      : record_bytes + record_bytes / 8 + (1 << 20);
}

uint64_t raw_load_scratch_bound(uint64_t triangles, uint64_t vertices, bool small_frames) {
  const uint64_t spanning = 3 * sizeof(CornerRef) + sizeof(LocalFace) + 3 * sizeof(ResolvedCorner);
  const uint64_t bytes = triangles * (std::max<uint64_t>(sizeof(LocalFace), spanning) + sizeof(BlockFace)) +
                         vertices * (sizeof(Point) + sizeof(WeldRecord));
  // Records: a spanning face's 3 + 1 + 3 and its block record; a vertex's two.
  return with_frame_envelopes(bytes, triangles * 8 + vertices * 2, small_frames);
}

uint64_t raw_loaded_blocks_bound(uint64_t triangles, uint64_t vertices, bool small_frames) {
  return with_frame_envelopes(triangles * sizeof(BlockFace) + vertices * sizeof(Point), triangles + vertices,
                              small_frames);
}

uint64_t loader_minimum_bytes() { return reserve_minimum_bytes() + items_minimum_bytes; }

void require_budget_for_load(uint64_t budget, uint64_t baseline) {
  if (budget >= baseline + loader_minimum_bytes()) return;
  throw Error(ErrorKind::resource, "--mem-budget " + config::format_size(budget) + " leaves " +
                                       config::format_size(budget - std::min(budget, baseline)) +
                                       " after the process's own " + config::format_size(baseline) +
                                       " but the loader needs " + config::format_size(loader_minimum_bytes()) +
                                       "; the minimum budget is " +
                                       config::format_budget(baseline + loader_minimum_bytes()));
}

}  // namespace qemflow::engine
