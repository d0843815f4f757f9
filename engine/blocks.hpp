#pragma once
// Blocks (paper §4.2): the input's faces, each with its global id, its global vertex
// ids and its three vertex positions, sorted by barycenter into a uniform grid and
// kept as zstd frames in scratch. Every later stage reads blocks, never the input.
//
// load_into_blocks() streams the input once through the I/O thread and keeps only
// bounded state. The vertex→position dereference of each face is done in one of two
// ways, chosen from the lease the loader gets:
// - resident: all vertex positions fit the lease: they are held in memory while the
//   faces stream by (one pass);
// - out of core: vertices go to scratch in chunks of consecutive indices. A face whose
//   indices fall in two consecutive chunks (most faces: indices are local in real
//   meshes) is bucketed by its first chunk and resolved with those two chunks loaded;
//   the other faces' corners are bucketed by chunk, each chunk is loaded in turn to
//   resolve its corners, and resolved corners are regrouped by face-id range to
//   rebuild those faces.
// Either way faces keep their input id.
//
// What the simplifier sees (the same as the in-core run, nodes/decimate/simplify.cpp):
// - weld (LoadOptions::weld): a face's vertex ids are welded ids: the smallest input
//   index among the vertices at exactly its position (== per coordinate, so -0.0
//   equals 0.0; NaN never welds). Resident: sorted in memory; out of core: (position,
//   index) records spilled by position-hash bucket and sorted per bucket. Either way
//   only the duplicates (index → representative) are kept, sorted, with one bit per
//   vertex to find them.
// - drop (LoadOptions::drop_repeated_vertex_faces): faces with a repeated welded
//   vertex (zero area) are not written to the blocks; LoadedMesh::dropped_faces
//   counts them (the in-core PatchDecimator drops the same faces).
// - degree (LoadOptions::degrees): each record carries, per corner, the number of
//   kept faces around that welded vertex in the whole mesh (a byte per vertex,
//   saturating, with the rare larger counts kept exactly on the side). Resident: the
//   faces are read twice from the input (count, then make records); out of core:
//   counted from the face spills before the dereference makes the records.
// Positions are always those of the input index, equal to the representative's.
// Memory: every buffer is sized from a lease of the governor; the loader refuses up
// front (Error(resource)) a budget below its minimum.
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

#include "engine/job.hpp"
#include "engine/scratch.hpp"
#include "util/geometry.hpp"

namespace qemflow::engine {

struct BlockFace {
  uint64_t id = 0;                 // global face id (input triangle order)
  Triangle vertices{};             // global vertex indices
  std::array<Point, 3> positions{};
  std::array<uint32_t, 3> degree{};  // kept faces around each corner's vertex (0: not counted)
  uint32_t unused = 0;
};
static_assert(sizeof(BlockFace) == 120);

// The same face as stored when every input coordinate is a float (the usual case):
// positions as float, exactly. A third less to compress, store and decompress.
struct PackedBlockFace {
  uint64_t id = 0;
  Triangle vertices{};
  std::array<float, 9> positions{};
  std::array<uint32_t, 3> degree{};
};
static_assert(sizeof(PackedBlockFace) == 80);

// Re-encode (LoadOptions::triangles_only): a block record is only the face's three
// input vertex ids, as u32 when the vertex count fits (12 bytes), else as u64 (24):
// the output writer needs nothing else, and positions only served to find the cell.
// 6x to 10x fewer bytes than a BlockFace to store, write and read back.
// The resident load files every block's faces in input (face-id) order. The
// out-of-core one files a block's local faces chunk by chunk, then its spanning ones,
// an order that depends on the vertex chunk, hence on the memory the loader got; so
// its records also carry the face id (u32 id then u32 ids, 16 bytes, when both counts
// fit, else u64 id then u64 ids, 32), and the writer puts each block in face-id order:
// either way a block's faces come out in face-id order (DESIGN.md §3, guarantee 1).
constexpr uint32_t triangle32_record_size = 3 * sizeof(uint32_t);
// Or, resident, when the output is a binary PLY (LoadOptions::ply_triangle_records):
// the output's own face records, "3 a b c" (uchar, then three u32 little-endian), which
// the writer hands to the file as they lie: no decode to ids and encode back a face.
constexpr uint32_t ply_triangle_record_size = 13;
constexpr uint32_t id_triangle32_record_size = 4 * sizeof(uint32_t);
constexpr uint32_t id_triangle64_record_size = 4 * sizeof(uint64_t);
bool is_id_triangle_record(uint32_t record_size);
// Vertex frames in scratch: xyz as floats when every coordinate of the frame is one
// exactly, else as Points (FrameRef::record_size says which).
constexpr uint32_t float_vertex_record_size = 3 * sizeof(float);
constexpr uint32_t triangle64_record_size = 3 * sizeof(uint64_t);
// Triangle-only records without ids (either width, or PLY face records).
bool is_triangle_record(uint32_t record_size);
// Triangle-only records without ids (either width) to Triangles.
void unpack_block_triangles(const std::byte* records, uint64_t count, uint32_t record_size, Triangle* out);

// Block records of either BlockFace layout (record_size says which) to BlockFaces
// (triangle-only records are refused: they hold no positions).
void unpack_block_faces(const std::byte* records, uint64_t count, uint32_t record_size, BlockFace* out);

struct BlockGrid {
  Point min{0, 0, 0}, max{0, 0, 0};
  std::array<uint32_t, 3> dims{1, 1, 1};
  uint32_t count() const { return dims[0] * dims[1] * dims[2]; }
  // Inline, always: the loaders call it once a face (GCC left it a call in the
  // resident re-encode's cell loop, a fifth of that run's samples).
  [[gnu::always_inline]] uint32_t cell_of(const Point& p) const {
    uint32_t idx[3];
    for (int i = 0; i < 3; ++i) {
      const double extent = max[i] - min[i];
      const double x = (extent > 0 ? (p[i] - min[i]) / extent : 0.0) * dims[i];
      // floor, then clamp to [0, dims), without std::floor (a libm call: the baseline
      // x86-64 has no SSE4.1 round). Same cells as int64_t(floor(x)) clamped: below 0
      // and NaN give 0, and so does 2^63 and up (that conversion's x86 result).
      idx[i] = !(x >= 0) ? 0 : x < double(dims[i]) ? uint32_t(x) : x < 0x1p63 ? dims[i] - 1 : 0;
    }
    return (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0];
  }
  // About `blocks` cells over the box, cubes as near as the box allows.
  static BlockGrid around(const Point& min, const Point& max, uint32_t blocks);
};

// Vertex positions by index, in windows of `window` consecutive vertices.
struct VertexStore {
  uint64_t count = 0;
  uint64_t window = 0;
  std::vector<Point> resident;                   // all of them, when resident
  // Or, when resident for the re-encode (triangle-only load of an input that declares
  // float coordinates), all of them as xyz floats, and `resident` stays empty.
  UninitializedVector<float> resident_xyz;
  std::vector<std::vector<FrameRef>> windows;    // else frames per window (tag = first index; float or Point records)
  bool is_resident() const { return windows.empty(); }
};

struct LoadOptions {
  uint64_t faces_per_block = 1 << 20;  // sets the grid's cell count
  // Tests: force the out-of-core dereference with chunks of this many vertices and
  // face ranges of this many faces (0 = from the lease).
  uint64_t window_vertices = 0;
  uint64_t range_faces = 0;
  bool force_out_of_core = false;
  bool weld = true;                        // --no-weld: false
  bool drop_repeated_vertex_faces = true;  // as the decimator does
  bool degrees = true;                     // count BlockFace::degree
  // Blocks hold triangle-only records (no ids, positions or degrees), and are kept in
  // memory instead of scratch when they fit the lease (LoadedMesh::resident_blocks).
  bool triangles_only = false;
  // Resident triangle-only blocks of a mesh with u32 vertex ids hold PLY face records
  // (ply_triangle_record_size): the re-encode's, when it writes a binary PLY.
  bool ply_triangle_records = false;
  // Re-encode: the input as it is (no weld, every face, no degree pass), blocks of
  // triangles only.
  static LoadOptions verbatim(LoadOptions options) {
    options.weld = options.drop_repeated_vertex_faces = options.degrees = false;
    options.triangles_only = true;
    return options;
  }
};

struct LoadedMesh {
  uint64_t vertex_count = 0;
  uint64_t face_count = 0;      // input faces (ids are 0..face_count-1)
  uint64_t dropped_faces = 0;   // faces with a repeated welded vertex, not in the blocks
  uint64_t welded_vertices = 0; // vertices that are not their own representative
  uint64_t kept_faces() const { return face_count - dropped_faces; }
  bool float_exact = true;  // every coordinate is a float (the input was float)
  BlockGrid grid;
  std::vector<std::vector<FrameRef>> blocks;  // frames of block records per cell
  // triangles_only, when they fit: the block records per cell in memory (pages of
  // records, in order), and `blocks` is empty of frames. Covered by resident_blocks_lease.
  std::vector<std::vector<Bytes>> resident_blocks;
  Lease resident_blocks_lease;
  bool blocks_resident() const { return !resident_blocks.empty(); }
  // sizeof(BlockFace), sizeof(PackedBlockFace), a triangle record size (resident
  // triangles_only) or an id-triangle record size (out-of-core triangles_only)
  uint32_t block_record_size = sizeof(BlockFace);
  std::vector<uint64_t> block_faces;          // (kept) faces per cell
  VertexStore vertices;
  uint64_t input_bytes = 0;
  bool out_of_core = false;
  // Some spill of the load had fewer than two pages per bucket, so its frames may hold
  // a record each (BucketSpill::small_frames; raw_load_scratch_bound).
  bool small_spill_frames = false;
  uint64_t local_faces = 0;   // out of core: faces resolved with two chunks loaded
  uint64_t corner_faces = 0;  // out of core: faces resolved corner by corner
  Lease resident_lease;  // covers vertices.resident while it is held
  // Out of core with LoadHooks::vertices: every vertex went to the hook, in order.
  bool vertices_delivered = false;
};

// Optional calls from an out-of-core load (the resident one makes none), on the
// calling thread:
// - counted(mesh): after the first pass, when the counts, float_exact and the grid are
//   known, before the dereference (the re-encode opens its output here);
// - vertices(first, points, count): every vertex chunk, in index order, as the
//   dereference loads it; `points` stay untouched until every I/O task submitted
//   before the next call (or the end of the dereference) has run, so the hook may hand
//   them to the I/O thread without a copy. Then LoadedMesh::vertices_delivered is set.
struct LoadHooks {
  std::function<void(const LoadedMesh&)> counted;
  std::function<void(uint64_t first, const Point* points, uint64_t count)> vertices;
  // Optional, out of core: for a float-exact mesh loaded as triangles only, the
  // vertices as xyz floats instead of `vertices` (the buffer, like the points, stays
  // valid until the I/O thread has drained).
  std::function<void(uint64_t first, const float* xyz, uint64_t count)> float_vertices;
};

// The least the loader holds (its reservation's minimum and the streamed items'), and a
// check, before a Governor exists, that `budget` over `baseline` leaves it: a budget
// below the process's footprint is refused naming this minimum, not a guess.
uint64_t loader_minimum_bytes();
void require_budget_for_load(uint64_t budget, uint64_t baseline);

LoadedMesh load_into_blocks(Job& job, ScratchStore& scratch, const std::filesystem::path& input,
                            const LoadOptions& options, const LoadHooks& hooks = {});

// What a raw-scratch decision needs of an input before it is read: its vertices and a
// bound on its triangles (a PLY header counts polygons). Known from the header and the
// file's size for an uncompressed binary PLY whose elements other than the faces have
// fixed-size records; nullopt otherwise (a .zst, ascii or OBJ input: the triangles
// of its polygons are not known before they are read).
struct InputCountsBound {
  uint64_t triangles = 0, vertices = 0;
};
std::optional<InputCountsBound> input_counts_bound(const std::filesystem::path& input);

// A bound on the raw scratch bytes on disk at once during load_into_blocks of a mesh
// of `triangles` faces and `vertices` vertices (not triangles_only), in or out of core.
// `small_frames`: some spill of the load may write frames of a record or two
// (LoadedMesh::small_spill_frames; the load decides it, and --scratch-codec auto's
// choice for the load with it, once its spills are sized).
uint64_t raw_load_scratch_bound(uint64_t triangles, uint64_t vertices, bool small_frames);
// The part of it still on disk when the load returns: the blocks and vertex windows.
uint64_t raw_loaded_blocks_bound(uint64_t triangles, uint64_t vertices, bool small_frames);

// Streams the given frames of `record_size` records through the I/O thread (a stream
// pass): `transform(header, records, lease)` runs on compute threads concurrently,
// then `sink` (optional) one at a time, in any order (in frame order, both one at a
// time, when `ordered`). `records` holds header.count decoded records;
// each item's lease covers the encoded frame, the records, and `out_record_size`
// bytes per record for what transform makes of them. With `in_place`, the records
// buffer is read with room for header.count × out_record_size bytes, so that the
// transform can grow it to that (resize) and write there rather than into a new
// buffer; leave it off when transform makes a new one (the room would go unused).
//
// Buffers an item leaves behind (its records, unless its sink moved them away) are read
// into again by a later item instead of being freed: a fresh buffer is fresh pages,
// faulted in one by one (most of a re-encode's page faults were those). They are kept
// in a FramePool: the pass's own, or the caller's (`pool`), which keeps them across
// calls (many calls of a few frames each). A kept buffer stays covered: its capacity is
// split off the item's lease into the pool's, and the item that takes it asks the
// governor for the rest of its size only. The bytes a kept buffer holds are not
// released, so they would not wake a pump parked for memory: the sink wakes the
// governor's waiters after keeping one, and the pump's next step keeps only the one
// buffer it takes and frees the others, so a parked pump holds at most that one.
// A caller's pool must be cleared (or destroyed) before the caller waits for memory
// other than through a pass.
class FramePool {
 public:
  struct Kept {
    Lease lease;  // covers buffer.capacity(); declared first, so released last
    Bytes buffer;
  };
  ~FramePool() { clear(); }
  // Frees every kept buffer, each before its lease.
  void clear() {
    std::lock_guard lock(mutex_);
    kept_.clear();
  }
  // Every kept buffer out of the pool (the caller frees what it does not use).
  std::vector<Kept> take_all() {
    std::lock_guard lock(mutex_);
    return std::exchange(kept_, {});
  }
  // Keeps `buffer` under `lease`, unless `max_kept` are kept already (false: nothing
  // moved).
  bool keep(Bytes& buffer, Lease& lease, size_t max_kept = 4);
  // For a pump choosing the buffer for its next read: `taken` keeps the buffer it
  // holds if that one `fits`, else gets the first kept one that does; every other kept
  // buffer goes back to the pool, or is freed once the pool is full.
  void choose(std::optional<Kept>& taken, const std::function<bool(const Kept&)>& fits);
  // A kept buffer of at least `capacity` bytes out of the pool, if there is one.
  std::optional<Kept> take(size_t capacity) {
    std::lock_guard lock(mutex_);
    for (size_t i = 0; i < kept_.size(); ++i) {
      if (kept_[i].buffer.capacity() < capacity) continue;
      std::optional<Kept> taken(std::move(kept_[i]));
      kept_.erase(kept_.begin() + int64_t(i));
      return taken;
    }
    return std::nullopt;
  }

 private:
  std::mutex mutex_;
  std::vector<Kept> kept_;
};

using FrameUse = std::function<void(const FrameHeader&, Bytes& records, Lease& lease)>;
// Reads `frames` in order on the I/O thread; the next 32 MiB of them are asked of the
// kernel ahead of the reads (ScratchStore::will_need), so frames scattered over a file
// the page cache does not hold arrive many at a time.
// `read_once`: each frame's pages go back to the OS once it is read (ScratchStore::
// discard), so the writes that follow reuse them rather than fault in fresh ones, and
// no dirty page of a frame done with waits to be written back.
void for_each_frame(Job& job, ScratchStore& scratch, const char* stage, const char* owner,
                    const std::vector<FrameRef>& frames, uint32_t record_size,
                    const FrameUse& transform, const FrameUse& sink, uint32_t out_record_size,
                    bool ordered = false, bool in_place = false, FramePool* pool = nullptr, bool read_once = false);

// Loads vertices [window * store.window, +store.window) into `out` (resident or not).
void load_vertex_window(Job& job, ScratchStore& scratch, const VertexStore& store, uint64_t window,
                        Point* out);

}  // namespace qemflow::engine
