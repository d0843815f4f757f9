#include "nodes/pipeline/epochs.hpp"

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <ctime>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <unordered_map>

#include <oneapi/tbb/enumerable_thread_specific.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_sort.h>

#include "config/size.hpp"
#include "engine/process_memory.hpp"
#include "engine/retained_buffers.hpp"
#include "util/error.hpp"
#include "util/morton.hpp"
#include "util/parallel_fill.hpp"
#include "util/parallel_select.hpp"
#include "util/radix_sort.hpp"

namespace qemflow::nodes::pipeline {
namespace {

using engine::Bytes;
using engine::FrameHeader;
using engine::FrameRef;
using engine::Job;
using engine::Lease;
using engine::ScratchStore;

struct FaceRecord {
  uint64_t fid = 0;
  std::array<uint64_t, 3> v{};
  uint32_t owner = 0;
  uint32_t unused = 0;
};
static_assert(sizeof(FaceRecord) == 40);

struct VertexRecord {
  uint64_t gid = 0;
  Vec3 position{};
  Quadric quadric{};
  uint32_t degree = 0;
  uint8_t locked = 0;
  uint8_t has_quadric = 0;
  uint8_t unused[2] = {0, 0};
  // The vertex's best edge at the exporting pass's summary (PatchOutput::best_gids):
  // the next pass's patches restore it instead of refreshing it in their first round.
  uint64_t best_gid = kBestUnknown;
  double best_cost = 0.0;
};
static_assert(sizeof(VertexRecord) == 136);

// Copies of one vertex's record (written by every patch that exported one of its
// faces) must agree on all but the carried best, which a copy may lack (kBestUnknown);
// two known bests must agree too. Checked under QEMFLOW_VERIFY_CARRIED (decimator.hpp):
// throws naming the gid.
void check_copies_agree(const VertexRecord& kept, const VertexRecord& copy) {
  constexpr size_t kState = offsetof(VertexRecord, best_gid);  // gid .. has_quadric, unused
  const bool state_equal = std::memcmp(&kept, &copy, kState) == 0;
  const bool bests_equal = kept.best_gid == kBestUnknown || copy.best_gid == kBestUnknown ||
                           (kept.best_gid == copy.best_gid &&
                            std::bit_cast<uint64_t>(kept.best_cost) == std::bit_cast<uint64_t>(copy.best_cost));
  if (state_equal && bests_equal) return;
  std::string what = state_equal ? "carried best" : "";
  if (!state_equal) {
    if (std::memcmp(&kept.position, &copy.position, sizeof kept.position)) what += " position";
    if (std::memcmp(&kept.quadric, &copy.quadric, sizeof kept.quadric)) what += " quadric";
    if (kept.degree != copy.degree)
      what += " degree (" + std::to_string(kept.degree) + " vs " + std::to_string(copy.degree) + ")";
    if (kept.locked != copy.locked) what += " lock";
    if (kept.has_quadric != copy.has_quadric) what += " has_quadric";
    if (!bests_equal) what += " carried best";
  }
  throw Error(ErrorKind::internal, "QEMFLOW_VERIFY_CARRIED: two copies of the state record of vertex " +
                                       std::to_string(kept.gid) + " differ in:" + (state_equal ? " " : "") + what);
}

// QEMFLOW_FUZZ_ORDER=SEED (epochs.hpp): the seed, 0 when unset. Read once.
uint64_t order_fuzz_seed() {
  static const uint64_t seed = [] {
    const char* value = std::getenv("QEMFLOW_FUZZ_ORDER");
    return value ? std::strtoull(value, nullptr, 10) : 0ull;
  }();
  return seed;
}
// A fresh pseudo-random value per call (per gather, per patch build) from the seed.
uint64_t next_fuzz_salt() {
  static std::atomic<uint64_t> calls{0};
  return mix64(order_fuzz_seed() * 0x9E3779B97F4A7C15ull + ++calls) | 1;
}
// Puts `items` in a pseudo-random order (Fisher-Yates on next_fuzz_salt()).
template <class Items>
void shuffle(Items& items) {
  uint64_t x = next_fuzz_salt();
  for (size_t i = items.size(); i > 1; --i) {
    x = mix64(x + i);
    std::swap(items[i - 1], items[size_t(x % i)]);
  }
}

struct Box {
  Point min{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
            std::numeric_limits<double>::infinity()};
  Point max{-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
            -std::numeric_limits<double>::infinity()};
  void add(const Point& p) {
    for (int k = 0; k < 3; ++k) {
      min[k] = std::min(min[k], p[k]);
      max[k] = std::max(max[k], p[k]);
    }
  }
  void add(const Box& b) {
    add(b.min);
    add(b.max);
  }
  // Empty on any axis: an intersection can be (a chunk's box beside a part's region
  // along y or z).
  bool empty() const { return !(min[0] <= max[0] && min[1] <= max[1] && min[2] <= max[2]); }
  bool contains(const Point& p) const {
    for (int k = 0; k < 3; ++k)
      if (p[k] < min[k] || p[k] > max[k]) return false;
    return true;
  }
  // Half-open: a point on a shared face of two adjacent regions is in exactly one.
  bool contains_half_open(const Point& p) const {
    for (int k = 0; k < 3; ++k)
      if (!(p[k] >= min[k] && p[k] < max[k])) return false;
    return true;
  }
  Box intersected(const Box& b) const {
    Box r;
    for (int k = 0; k < 3; ++k) {
      r.min[k] = std::max(min[k], b.min[k]);
      r.max[k] = std::min(max[k], b.max[k]);
    }
    return r;
  }
  bool meets(const Box& b) const {
    for (int k = 0; k < 3; ++k)
      if (b.max[k] < min[k] || b.min[k] > max[k]) return false;
    return true;
  }
  static Box unbounded() {
    Box b;
    std::swap(b.min, b.max);
    return b;
  }
};

// A chunk blob: u64 faces, u64 vertices, FaceRecord[faces], VertexRecord[vertices]
// (each gid once; in gid order from the conversion, in first-use order from an export:
// readers look gids up in a GidTable). Stored as one frame of 1-byte records.
struct ChunkMeta {
  uint32_t owner = 0;
  uint64_t faces = 0;
  Box box;
  // The boxes of the chunk's faces (their corners) in kParts runs of the chunk's order
  // (part_of): an export's chunk is in Morton order, so each run is a compact piece of
  // surface where the whole chunk's box may span a fold or a Morton jump. A part's
  // gather reads the runs whose boxes hold the vertices its BFS needs the fans of.
  static constexpr size_t kParts = 8;
  std::array<Box, kParts> parts;
  static size_t part_of(size_t face, size_t faces) { return face * kParts / faces; }
  // Summed over the chunk's face corners, 1 / the vertex's degree: the state's chunks
  // sum to its distinct vertices (each face is in one chunk), where their vertex
  // records count a vertex once per chunk it is in.
  double vertex_share = 0;
  // The same per run (parts): a gather counts the vertices of the runs it reads with
  // them before it reads them (patch_bytes), in fixed point (share_units) so the sum does
  // not depend on the order of the runs.
  std::array<double, kParts> run_share{};
  static constexpr int kShareBits = 20;
  static int64_t share_units(double share) { return std::llround(std::ldexp(share, kShareBits)); }
  static uint64_t vertices_of(int64_t units) {
    return uint64_t((units + (int64_t(1) << (kShareBits - 1))) >> kShareBits);
  }
  // The id of the chunk's first face: tells its frame apart when read (read_runs).
  uint64_t first_fid = 0;
};

struct Chunk {
  ChunkMeta meta;
  FrameRef frame;
};

size_t blob_bytes(size_t faces, size_t vertices) {
  return 16 + faces * sizeof(FaceRecord) + vertices * sizeof(VertexRecord);
}

struct BlobView {
  uint64_t faces = 0, vertices = 0;
  const FaceRecord* face = nullptr;
  const VertexRecord* vertex = nullptr;
};
BlobView view_blob(const std::byte* data, size_t size) {
  BlobView v;
  if (size < 16) throw Error(ErrorKind::internal, "state chunk too short");
  std::memcpy(&v.faces, data, 8);
  std::memcpy(&v.vertices, data + 8, 8);
  if (blob_bytes(v.faces, v.vertices) != size) throw Error(ErrorKind::internal, "state chunk size mismatch");
  v.face = reinterpret_cast<const FaceRecord*>(data + 16);
  v.vertex = reinterpret_cast<const VertexRecord*>(data + 16 + v.faces * sizeof(FaceRecord));
  return v;
}

// gid → index of its first record, by open addressing: one short probe sequence per
// lookup instead of a binary search over the records (the gather's hot loop).
class GidTable {
 public:
  static constexpr uint32_t kMissing = std::numeric_limits<uint32_t>::max();

  template <class GidOf>
  GidTable(size_t n, GidOf gid_of) : GidTable(n, gid_of, [](size_t, uint32_t) { return false; }) {}
  // `prefer(i, kept)`: record i of a repeated gid replaces the one kept so far.
  template <class GidOf, class Prefer>
  GidTable(size_t n, GidOf gid_of, Prefer prefer) {
    size_t slots = 16;
    while (slots < 2 * n) slots *= 2;
    shift_ = 64 - std::countr_zero(slots);
    mask_ = slots - 1;
    slots_.assign(slots, {0, kMissing});
    for (size_t i = 0; i < n; ++i) {
      const uint64_t gid = gid_of(i);
      size_t at = slot_of(gid);
      while (slots_[at].second != kMissing && slots_[at].first != gid) at = (at + 1) & mask_;
      if (slots_[at].second == kMissing || prefer(i, slots_[at].second)) slots_[at] = {gid, uint32_t(i)};
    }
  }
  uint32_t find(uint64_t gid) const {
    size_t at = slot_of(gid);
    while (slots_[at].second != kMissing && slots_[at].first != gid) at = (at + 1) & mask_;
    return slots_[at].second;
  }

 private:
  size_t slot_of(uint64_t gid) const { return size_t((gid * 0x9E3779B97F4A7C15ull) >> shift_); }
  int shift_ = 0;
  size_t mask_ = 0;
  std::vector<std::pair<uint64_t, uint32_t>> slots_;
};

// The gathered vertex records, one per gid, appended to `records` (empty at the start;
// reserved at its upper bound, so it does not reallocate): a gid's records in several
// chunks are equal copies but for the carried best, and the one kept is the first with
// a known best, else the first (so the patch does not depend on the read order).
// Without this, a state whose chunks share few vertices (the first state of an input
// in random face order: ~2.8 records per face, against ~0.6) held ~4x the vertex
// records the patch lease (kPatchBytesPerFace) counts. The table holds 4-byte record
// indices (the gid read from the record); the part's BFS finds its vertices through it.
class UniqueVertexRecords {
 public:
  static constexpr uint32_t kMissing = std::numeric_limits<uint32_t>::max();
  explicit UniqueVertexRecords(std::vector<VertexRecord>& records) : records_(records) {
    if (!records_.empty()) throw Error(ErrorKind::internal, "UniqueVertexRecords needs an empty array");
    rehash(1024);
  }
  void add(const VertexRecord& r) {
    if (2 * (records_.size() + 1) > slots_.size()) rehash(2 * slots_.size());
    size_t at = slot_of(r.gid);
    for (; slots_[at] != kMissing; at = (at + 1) & mask_) {
      VertexRecord& kept = records_[slots_[at]];
      if (kept.gid != r.gid) continue;
      if (verify_) check_copies_agree(kept, r);
      if (kept.best_gid == kBestUnknown && r.best_gid != kBestUnknown) kept = r;
      return;
    }
    slots_[at] = uint32_t(records_.size());
    records_.push_back(r);
  }
  // The index of the gid's record (kMissing when none was added). Read-only: callers
  // may look up from several threads between adds.
  uint32_t find(uint64_t gid) const {
    for (size_t at = slot_of(gid); slots_[at] != kMissing; at = (at + 1) & mask_)
      if (records_[slots_[at]].gid == gid) return slots_[at];
    return kMissing;
  }
  // Lookups are cache misses (a random slot, then a random 136-byte record): a caller
  // looking up many gids prefetches each gid's slot some lookups ahead (prefetch_slot),
  // then, once that slot has arrived, its record (prefetch_record), so the misses of
  // consecutive lookups overlap instead of following one another.
  void prefetch_slot(uint64_t gid) const { __builtin_prefetch(&slots_[slot_of(gid)]); }
  void prefetch_record(uint64_t gid) const {
    const uint32_t i = slots_[slot_of(gid)];
    if (i != kMissing) __builtin_prefetch(&records_[i].gid);
  }
  void release() { release_memory(slots_); }

 private:
  size_t slot_of(uint64_t gid) const { return size_t((gid * 0x9E3779B97F4A7C15ull) >> shift_); }
  void rehash(size_t slots) {
    release_memory(slots_);  // the old table is not kept beside the new one
    slots_.assign(slots, kMissing);
    shift_ = 64 - std::countr_zero(slots);
    mask_ = slots - 1;
    for (uint32_t i = 0; i < records_.size(); ++i) {
      size_t at = slot_of(records_[i].gid);
      while (slots_[at] != kMissing) at = (at + 1) & mask_;
      slots_[at] = i;
    }
  }
  std::vector<VertexRecord>& records_;
  const bool verify_ = verify_carried_enabled();
  std::vector<uint32_t> slots_;  // record indices, the gid read from the record
  int shift_ = 0;
  size_t mask_ = 0;
};

// A blob for `nf` face and `nv` vertex records with its header written; the records
// go from data() + 16 on, faces first (view_blob's layout).
Bytes blob_with_header(uint64_t nf, uint64_t nv) {
  Bytes blob(blob_bytes(nf, nv));
  std::memcpy(blob.data(), &nf, 8);
  std::memcpy(blob.data() + 8, &nv, 8);
  return blob;
}

// The global mesh between epochs: chunks in one scratch file.
struct MeshState {
  uint32_t file = 0;
  std::deque<Chunk> chunks;
  std::mutex mutex;
  uint64_t faces = 0;
  // The chunks' vertex_share summed in fixed point (units of 2^-20), so the sum does not
  // depend on the order chunks are written in.
  int64_t vertex_share_units = 0;
  // The distinct vertices of the faces (what the finish's memory rule counts,
  // in_core_finish_bytes); unreferenced input vertices are not in the state.
  uint64_t vertices() const { return ChunkMeta::vertices_of(vertex_share_units); }
  // Faces whose three corners are used by no other face (a soup's triangles): nothing
  // collapses them, so the finish holds them all (set by the conversion).
  uint64_t isolated_faces = 0;
  uint64_t blob_bytes_total = 0;
};

// Encodes and queues a chunk for writing (the I/O thread fills in the offset).
void write_encoded_chunk(Job& job, ScratchStore& scratch, MeshState& state, const ChunkMeta& meta,
                         uint64_t blob_size, std::shared_ptr<Bytes> encoded, Lease carried,
                         const char* stage = "epochs") {
  size_t index;
  {
    std::lock_guard lock(state.mutex);
    index = state.chunks.size();
    Chunk c;
    c.meta = meta;
    c.frame.file = state.file;
    c.frame.bytes = encoded->size();
    c.frame.count = blob_size;
    c.frame.tag = meta.owner;
    state.chunks.push_back(c);
    state.faces += meta.faces;
    state.vertex_share_units += ChunkMeta::share_units(meta.vertex_share);
    state.blob_bytes_total += blob_size;
  }
  job.stage(stage).bytes_written += encoded->size();
  auto held = std::make_shared<Lease>(std::move(carried));
  const uint32_t file = state.file;
  job.io().submit(
      "write state chunk",
      [&scratch, &state, encoded, held, index, file] {
        const uint64_t offset = scratch.append(file, encoded->data(), encoded->size());
        {
          std::lock_guard lock(state.mutex);
          state.chunks[index].frame.offset = offset;
        }
        *encoded = Bytes();
        held->release();
      },
      job.error_handler(), encoded->size());
}

// A raw frame's bytes: its blob and the envelope (header, checksum).
uint64_t raw_frame_bytes(uint64_t blob_size) { return blob_size + engine::frame_envelope_bytes; }

void write_chunk(Job& job, ScratchStore& scratch, MeshState& state, const ChunkMeta& meta, const Bytes& blob,
                 Lease carried, const char* stage) {
  const engine::FrameCodec codec = scratch.frame_codec(raw_frame_bytes(blob.size()));
  write_encoded_chunk(job, scratch, state, meta, blob.size(),
                      std::make_shared<Bytes>(engine::encode_frame(meta.owner, 1, blob.data(), blob.size(), codec)),
                      std::move(carried), stage);
}

void finish_state(Job& job, ScratchStore& scratch, MeshState& state) {
  job.io().drain();
  job.check();
  job.io().call("finalize state", [&] { scratch.finalize(state.file); });
}

// Writes a patch's owned output as chunks of at most `chunk_faces` faces, taken in
// `order` (indices into out.faces). Chunks are made from the output's local indices
// directly (no gid lookups), and made and encoded in parallel, a batch at a time
// (bounded memory), queued for writing in order.
void write_output_as_chunks(Job& job, ScratchStore& scratch, MeshState& state, uint32_t owner, const PatchOutput& out,
                            const std::vector<uint32_t>& order, uint64_t chunk_faces) {
  struct Made {
    ChunkMeta meta;
    uint64_t blob_size = 0;
    std::shared_ptr<Bytes> encoded;
  };
  const size_t chunks = (order.size() + chunk_faces - 1) / chunk_faces;
  // A batch per compute thread: what is in flight here (blob + encoded frame, ~2.6 MB
  // per 8192-face chunk) is outside the patch lease, so it stays this small.
  const size_t kBatch = size_t(std::max(1, job.threads()));
  // A chunk's vertices in first-use order, deduplicated by stamping each output vertex
  // with the chunk's number (per thread: 4 bytes per output vertex).
  tbb::enumerable_thread_specific<std::vector<uint32_t>> stamps(
      [&] { return std::vector<uint32_t>(out.positions.size(), std::numeric_limits<uint32_t>::max()); });
  std::vector<Made> made;
  for (size_t batch = 0; batch < chunks; batch += kBatch) {
    const size_t n_batch = std::min(kBatch, chunks - batch);
    made.assign(n_batch, {});
    job.arena().execute([&] {
      tbb::parallel_for(size_t(0), n_batch, [&](size_t i) {
        const size_t first = (batch + i) * chunk_faces;
        const size_t n = std::min<size_t>(chunk_faces, order.size() - first);
        std::vector<uint32_t>& stamp = stamps.local();
        const uint32_t mark = uint32_t(batch + i);
        std::vector<uint32_t> locals;
        locals.reserve(3 * n);
        for (size_t j = first; j < first + n; ++j)
          for (uint32_t v : out.faces[order[j]])
            if (stamp[v] != mark) {
              stamp[v] = mark;
              locals.push_back(v);
            }
        const uint64_t nf = n, nv = locals.size();
        const size_t size = blob_bytes(nf, nv);
        // Raw frames are made in place: the blob is built inside the frame (no copy).
        const bool raw = scratch.frame_codec(raw_frame_bytes(size)).raw;
        Bytes frame(raw ? raw_frame_bytes(size) : size);
        std::byte* blob = frame.data() + (raw ? engine::frame_header_bytes : 0);
        std::memcpy(blob, &nf, 8);
        std::memcpy(blob + 8, &nv, 8);
        auto* faces = reinterpret_cast<FaceRecord*>(blob + 16);
        auto* vertices = reinterpret_cast<VertexRecord*>(blob + 16 + nf * sizeof(FaceRecord));
        ChunkMeta& meta = made[i].meta;
        meta.owner = owner;
        meta.faces = nf;
        meta.first_fid = out.face_gids[order[first]];
        for (size_t j = 0; j < n; ++j) {
          const uint32_t f = order[first + j];
          const auto& t = out.faces[f];
          faces[j] = {out.face_gids[f], {out.vertex_gids[t[0]], out.vertex_gids[t[1]], out.vertex_gids[t[2]]}, owner, 0};
          const Point& p0 = out.positions[t[0]];
          const Point& p1 = out.positions[t[1]];
          const Point& p2 = out.positions[t[2]];
          const size_t run = ChunkMeta::part_of(j, n);
          for (uint32_t v : t) {
            const double share = 1.0 / double(std::max<uint32_t>(1, out.degrees[v]));
            meta.vertex_share += share;
            meta.run_share[run] += share;
          }
          Box& part = meta.parts[run];
          for (const Point* c : {&p0, &p1, &p2}) part.add(*c);
        }
        for (size_t k = 0; k < nv; ++k) {
          const uint32_t v = locals[k];
          VertexRecord r;
          r.gid = out.vertex_gids[v];
          r.position = out.positions[v];
          r.quadric = out.quadrics[v];
          r.degree = out.degrees[v];
          r.locked = out.locked[v];
          r.has_quadric = 1;
          if (!out.best_gids.empty()) {
            r.best_gid = out.best_gids[v];
            r.best_cost = out.best_costs[v];
          }
          vertices[k] = r;
          meta.box.add(r.position);
        }
        made[i].blob_size = size;
        if (raw) {
          const auto envelope = engine::raw_frame_envelope(owner, 1, {{blob, size}}, size);
          std::memcpy(frame.data(), envelope.header.data(), envelope.header.size());
          std::memcpy(blob + size, envelope.trailer.data(), envelope.trailer.size());
          made[i].encoded = std::make_shared<Bytes>(std::move(frame));
        } else {
          made[i].encoded = std::make_shared<Bytes>(engine::encode_frame(owner, 1, blob, size, engine::FrameCodec::zstd()));
        }
      });
    });
    for (auto& m : made) write_encoded_chunk(job, scratch, state, m.meta, m.blob_size, std::move(m.encoded), Lease());
  }
}

void remove_load_files(Job& job, ScratchStore& scratch, const engine::LoadedMesh& mesh) {
  std::vector<uint32_t> files;
  for (const auto& frames : mesh.blocks)
    for (const FrameRef& f : frames) files.push_back(f.file);
  for (const auto& frames : mesh.vertices.windows)
    for (const FrameRef& f : frames) files.push_back(f.file);
  std::sort(files.begin(), files.end());
  files.erase(std::unique(files.begin(), files.end()), files.end());
  job.io().call("remove blocks", [&] {
    for (uint32_t file : files) scratch.remove(file);
  });
}

// Morton code of a point in a box (10 bits per axis): chunks of spatially close faces.
uint32_t morton(const Point& p, const Box& box) {
  uint64_t q[3];
  for (int k = 0; k < 3; ++k) {
    const double extent = box.max[k] - box.min[k];
    const double t = extent > 0 ? (p[k] - box.min[k]) / extent : 0.0;
    q[k] = uint32_t(std::clamp(t * 1023.0, 0.0, 1023.0));
  }
  // Bit b of axis k at bit 3 b + 2 - k: axis 0's bits lead each triple.
  return uint32_t(spread_bits21(q[0]) << 2 | spread_bits21(q[1]) << 1 | spread_bits21(q[2]));
}

// ---------------------------------------------------------------- conversion

// What a conversion transform holds per face of its frame beside the frame's records,
// leased with the frame (for_each_frame's out_record_size): the unpacked faces and
// their sort keys, the results' blobs (a face and, in the worst case of an input in
// random order, its three corners' vertex records), and the chunk being built (counted
// as much again; its corners' gid keys take 60 bytes a face). It was 250: a shuffled 300k at 80M (--clusters 2) then held some 20 MiB
// no lease covered and peaked at 89.7-93 MiB in the conversion in 2 of 4 runs at once
// (each with a thread sampling its RSS every 2 ms); 69.5-76.8 MiB, in the epochs, after.
constexpr uint32_t kConvertBytesPerFace =
    sizeof(engine::BlockFace) + 24 + 2 * (sizeof(FaceRecord) + 3 * sizeof(VertexRecord));

// A block frame's face in the conversion's order: by owner, then Morton code of its
// centroid, then id; `index` is its place in the frame.
struct ConvertKey {
  uint32_t owner, code;
  uint64_t fid;
  uint32_t index;
  bool operator<(const ConvertKey& o) const { return std::tie(owner, code, fid) < std::tie(o.owner, o.code, o.fid); }
};
static_assert(sizeof(ConvertKey) == 24);  // as kConvertBytesPerFace counts it

struct ConvertedChunk {
  ChunkMeta meta;
  Bytes blob;
};

// The chunk of faces[keys[0..n).index] (one owner): its face records in key order and
// one vertex record per gid in gid order, written straight into the blob, and its meta:
// the box of the vertex records, each run's box of its faces' corners (their vertex
// records' positions), the vertex shares. `isolated` counts the faces whose three
// corners have degree 1.
ConvertedChunk convert_chunk(const std::vector<engine::BlockFace>& faces, const ConvertKey* keys, size_t n,
                             uint64_t& isolated) {
  // The corners sorted by gid alone, with std::sort as the 136-byte vertex records
  // themselves were before (the same comparisons give the same permutation, for an
  // eighth of the bytes moved): the first corner of each gid gives its record, and copies
  // can differ (a corner's position is its unwelded input vertex's: -0.0 welds to 0.0),
  // so which one comes first shows in the output.
  struct GidCorner {
    uint64_t gid;
    uint64_t corner;  // 3 * (face in the chunk) + k
  };
  std::vector<GidCorner> corners(3 * n);
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) corners[3 * i + k] = {faces[keys[i].index].vertices[k], 3 * i + k};
  std::sort(corners.begin(), corners.end(), [](const GidCorner& a, const GidCorner& b) { return a.gid < b.gid; });
  // Each corner's vertex record (its place among the kept ones), for the runs' boxes.
  std::vector<uint32_t> vertex_of(3 * n);
  uint64_t nv = 0;
  for (size_t j = 0; j < corners.size(); ++j) {
    if (j > 0 && corners[j].gid != corners[j - 1].gid) ++nv;
    vertex_of[corners[j].corner] = uint32_t(nv);
  }
  if (!corners.empty()) ++nv;
  ConvertedChunk out;
  out.blob = blob_with_header(n, nv);
  std::byte* face_at = out.blob.data() + 16;
  std::byte* vertex_at = face_at + n * sizeof(FaceRecord);
  ChunkMeta& m = out.meta;
  m.owner = n ? keys[0].owner : 0;
  m.faces = n;
  for (size_t j = 0; j < corners.size(); ++j) {
    if (j > 0 && corners[j].gid == corners[j - 1].gid) continue;
    const engine::BlockFace& f = faces[keys[corners[j].corner / 3].index];
    const int k = int(corners[j].corner % 3);
    VertexRecord r;
    r.gid = f.vertices[k];
    r.position = f.positions[k];
    r.degree = f.degree[k];
    std::memcpy(static_cast<void*>(vertex_at), &r, sizeof r);
    vertex_at += sizeof r;
    m.box.add(r.position);
  }
  const auto* vertices = reinterpret_cast<const VertexRecord*>(out.blob.data() + 16 + n * sizeof(FaceRecord));
  for (size_t i = 0; i < n; ++i) {
    const engine::BlockFace& f = faces[keys[i].index];
    const FaceRecord record{f.id, f.vertices, keys[i].owner, 0};
    std::memcpy(static_cast<void*>(face_at + i * sizeof(FaceRecord)), &record, sizeof record);
    isolated += f.degree[0] == 1 && f.degree[1] == 1 && f.degree[2] == 1;
    Box& part = m.parts[ChunkMeta::part_of(i, n)];
    for (int k = 0; k < 3; ++k) {
      const double share = 1.0 / double(std::max<uint32_t>(1, f.degree[k]));
      m.vertex_share += share;
      m.run_share[ChunkMeta::part_of(i, n)] += share;
      part.add(vertices[vertex_of[3 * i + k]].position);
    }
  }
  if (n) m.first_fid = faces[keys[0].index].id;
  return out;
}

// Blocks → state chunks of one owner each, with degrees; per-owner face counts.
void convert_blocks(Job& job, ScratchStore& scratch, const engine::LoadedMesh& mesh, const Partition& partition,
                    uint64_t chunk_faces, MeshState& state) {
  engine::StageTimer timer(job, "convert");
  std::vector<FrameRef> frames;
  for (const auto& b : mesh.blocks) frames.insert(frames.end(), b.begin(), b.end());
  using Out = ConvertedChunk;
  std::mutex outs_mutex;
  std::vector<std::vector<Out>> outs;  // by transform result slot
  uint64_t isolated_faces = 0;         // under outs_mutex
  size_t done = 0;
  engine::for_each_frame(
      job, scratch, "convert", "block frames", frames, mesh.block_record_size,
      [&](const FrameHeader& header, Bytes& records, Lease&) {
        std::vector<engine::BlockFace> faces(header.count);
        engine::unpack_block_faces(records.data(), header.count, mesh.block_record_size, faces.data());
        // Each owner's faces in Morton order of their centroids (in the frame's box), as
        // the export orders them: a chunk's runs (ChunkMeta::parts) are then spatially
        // tight even when the input's faces come in random order (a frame then holds a
        // random sample of its block), and a gather reads only the runs near a halo.
        Box frame_box;
        for (const auto& f : faces)
          for (const Point& c : f.positions) frame_box.add(c);
        std::vector<ConvertKey> by_owner(faces.size());
        for (size_t i = 0; i < faces.size(); ++i) {
          Point c{};
          for (const Point& corner : faces[i].positions)
            for (int k = 0; k < 3; ++k) c[k] += corner[k] / 3;
          by_owner[i] = {partition.owner_of(faces[i]), morton(c, frame_box), faces[i].id, uint32_t(i)};
        }
        std::sort(by_owner.begin(), by_owner.end());
        std::vector<Out> result;
        uint64_t isolated = 0;
        for (size_t first = 0; first < by_owner.size();) {
          size_t last = first;
          while (last < by_owner.size() && by_owner[last].owner == by_owner[first].owner &&
                 last - first < chunk_faces)
            ++last;
          result.push_back(convert_chunk(faces, by_owner.data() + first, last - first, isolated));
          first = last;
        }
        // Hand the results to the sink through the records buffer's slot index.
        size_t slot;
        {
          std::lock_guard lock(outs_mutex);
          isolated_faces += isolated;
          slot = outs.size();
          outs.push_back(std::move(result));
        }
        records.resize(sizeof slot);
        std::memcpy(records.data(), &slot, sizeof slot);
      },
      [&](const FrameHeader&, Bytes& records, Lease&) {
        size_t slot;
        std::memcpy(&slot, records.data(), sizeof slot);
        std::vector<Out> result;
        {
          std::lock_guard lock(outs_mutex);
          result = std::move(outs[slot]);
        }
        for (auto& o : result) write_chunk(job, scratch, state, o.meta, o.blob, Lease(), "convert");
        job.progress(double(++done) / double(frames.size()), "convert");
      },
      kConvertBytesPerFace);
  state.isolated_faces = isolated_faces;
  finish_state(job, scratch, state);
}

// ---------------------------------------------------------------- patches

// OocStats::phase_wall / phase_cpu: charge(phase) adds the time since the previous
// charge (or the clock's start) to `phase`, and traces that time as a span named for it
// (the patch's owner as its arg) on the calling thread's track, the patch loop's. A
// compute Span (untraced: the event takes the clock's own reads, so the trace's phases
// add up to the report's) counts the thread busy meanwhile, less its waits on the I/O
// thread and on stream passes, whose own spans count; the phase's parallel_for work
// counts in Activity's compute CPU.
enum Phase : size_t { kGather, kBuild, kSetup, kFirstRound, kRounds, kSummary, kExtract, kExport };
class PhaseClock {
 public:
  PhaseClock(Job& job, OocStats& stats, uint32_t owner) : job_(job), stats_(stats), owner_(owner) {}
  void charge(Phase phase) {
    const auto wall = engine::Clock::now();
    const double cpu = engine::process_cpu_seconds();
    stats_.phase_wall[phase] += std::chrono::duration<double>(wall - wall_).count();
    stats_.phase_cpu[phase] += cpu - cpu_;
    engine::Trace& trace = job_.trace();
    if (trace.enabled()) trace.span(OocStats::kPhaseNames[phase], trace.us_at(wall_), trace.us_at(wall), 0, owner_);
    wall_ = wall;
    cpu_ = cpu;
  }

 private:
  Job& job_;
  OocStats& stats_;
  const uint32_t owner_;
  engine::Span busy_{nullptr, &job_.activity(), "phase"};
  engine::Clock::time_point wall_ = engine::Clock::now();
  double cpu_ = engine::process_cpu_seconds();
};

struct PatchPlan {
  enum class Kind { summary_only, bin_cut, exact_cut } kind = Kind::summary_only;
  std::vector<RoundCut> cuts;  // one per round
};

// What one patch owns: the faces of `owner` whose centroid lies in `region`
// (half-open). Normally the whole owner (region unbounded); a smaller region when the
// owner's patch (owned + halo) would not fit the largest lease a patch may hold: then
// the owner runs as several parts, which is just a finer partition (same output).
struct PatchPart {
  uint32_t owner = 0;
  bool whole = true;
  Box region;  // when not whole
  // Owned faces of the part it was halved from, and how many halvings in a row left
  // all of them in one half (faces at one point: halving never frees them).
  uint64_t parent_owned = 0;
  uint32_t stalled = 0;
};

// Face records the part does not own carry this owner, so "owner == p" means "owned by
// this part" in PatchBfs.
inline constexpr uint32_t kNotInPart = std::numeric_limits<uint32_t>::max();

struct Gathered {
  // Sorted by fid / by gid for the finish (no part); as read for a part. One record
  // per gid either way (UniqueVertexRecords).
  std::vector<FaceRecord> faces;
  std::vector<VertexRecord> vertices;
  // Faces of the runs the gather read, and of the batch it did not read because it
  // would have gone over the limit (= faces.size() unless over_limit), and the runs'
  // vertex shares (ChunkMeta::run_share): both from the chunk metas, so the same on
  // every run.
  uint64_t found_faces = 0;
  int64_t share_units = 0;
  uint64_t owned_faces = 0;  // of the faces read, owned by the part
  bool over_limit = false;   // more than the limit: nothing is held
  uint64_t found_vertices() const { return ChunkMeta::vertices_of(share_units); }
};

// Which runs of a chunk (ChunkMeta::parts) a part's gather reads: bit k for run k.
using RunMask = uint8_t;
inline constexpr RunMask kAllRuns = 0xff;
static_assert(ChunkMeta::kParts == 8);
struct RunRead {
  size_t chunk = 0;  // index into MeshState::chunks
  RunMask runs = 0;
};

// Points bucketed in a grid over their bounds: "does this box hold one of them?"
// without testing every point against every box.
class PointGrid {
 public:
  explicit PointGrid(const std::vector<Point>& points) : points_(points) {
    for (const Point& p : points_) bounds_.add(p);
    cells_ = std::clamp(int(std::cbrt(double(points_.size()))), 1, 32);
    for (int k = 0; k < 3; ++k) {
      const double extent = bounds_.max[k] - bounds_.min[k];
      scale_[k] = extent > 0 ? cells_ / extent : 0.0;
    }
    first_.assign(size_t(cells_) * cells_ * cells_ + 1, 0);
    for (const Point& p : points_) ++first_[index(cell_of(p)) + 1];
    for (size_t c = 1; c < first_.size(); ++c) first_[c] += first_[c - 1];
    order_.resize(points_.size());
    std::vector<uint32_t> at(first_.begin(), first_.end() - 1);
    for (size_t i = 0; i < points_.size(); ++i) order_[at[index(cell_of(points_[i]))]++] = uint32_t(i);
  }
  const Box& bounds() const { return bounds_; }
  bool any_inside(const Box& box) const {
    if (box.empty() || !bounds_.meets(box)) return false;
    const Box cut = box.intersected(bounds_);
    const auto lo = cell_of(cut.min), hi = cell_of(cut.max);
    for (int x = lo[0]; x <= hi[0]; ++x)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int z = lo[2]; z <= hi[2]; ++z) {
          const size_t c = index({x, y, z});
          for (uint32_t i = first_[c]; i < first_[c + 1]; ++i)
            if (box.contains(points_[order_[i]])) return true;
        }
    return false;
  }

 private:
  std::array<int, 3> cell_of(const Point& p) const {
    std::array<int, 3> c;
    for (int k = 0; k < 3; ++k) c[k] = int(std::clamp((p[k] - bounds_.min[k]) * scale_[k], 0.0, double(cells_ - 1)));
    return c;
  }
  size_t index(const std::array<int, 3>& c) const { return (size_t(c[0]) * cells_ + size_t(c[1])) * cells_ + size_t(c[2]); }

  const std::vector<Point>& points_;
  Box bounds_;
  int cells_ = 1;
  std::array<double, 3> scale_{};
  std::vector<uint32_t> first_, order_;
};

// A part's first read: its owner's runs that may hold owned faces (all of them for a
// whole owner; a run holds the centroids of its faces, so one that misses the region
// owns nothing).
std::vector<RunRead> owned_runs(const MeshState& state, const PatchPart& part) {
  std::vector<RunRead> reads;
  for (size_t i = 0; i < state.chunks.size(); ++i) {
    const ChunkMeta& m = state.chunks[i].meta;
    if (m.owner != part.owner) continue;
    RunMask runs = 0;
    for (size_t k = 0; k < ChunkMeta::kParts; ++k)
      if (!m.parts[k].empty() && (part.whole || m.parts[k].meets(part.region))) runs |= RunMask(1u << k);
    if (runs) reads.push_back({i, runs});
  }
  return reads;
}

// The runs not read yet (`read`: per chunk) whose boxes hold one of `points`: every
// face of a vertex is in a run whose box holds the vertex (a run's box holds its
// faces' corners), so these are all the runs that can complete the points' fans.
std::vector<RunRead> runs_holding(const MeshState& state, const std::vector<Point>& points,
                                  const std::vector<RunMask>& read) {
  std::vector<RunRead> reads;
  const PointGrid grid(points);
  for (size_t i = 0; i < state.chunks.size(); ++i) {
    const ChunkMeta& m = state.chunks[i].meta;
    if (read[i] == kAllRuns || !grid.bounds().meets(m.box)) continue;
    RunMask runs = 0;
    for (size_t k = 0; k < ChunkMeta::kParts; ++k)
      if (!(read[i] >> k & 1u) && grid.any_inside(m.parts[k])) runs |= RunMask(1u << k);
    if (runs) reads.push_back({i, runs});
  }
  return reads;
}

// The faces of run k of a chunk of `faces` faces (ChunkMeta::part_of).
uint64_t run_faces(uint64_t faces, size_t k) {
  auto first = [&](size_t run) { return (run * faces + ChunkMeta::kParts - 1) / ChunkMeta::kParts; };
  return first(k + 1) - first(k);
}

// The runs a gather decoded with a chunk's frame but had not asked for yet (not read,
// not asked for in that batch), each a blob filtered as a read's: a later batch that
// asks for them takes them from here, so no frame is read and decoded twice in a
// gather. Opportunistic: it holds runs only within the patch lease's room (the faces
// the lease covers that the gather has neither found nor asked for), so it changes
// neither what the gather finds nor what it may hold.
struct RunCache {
  std::mutex mutex;
  std::unordered_map<size_t, std::array<Bytes, ChunkMeta::kParts>> runs;  // by chunk
  std::unordered_map<size_t, RunMask> held;                                // by chunk
  // A cached run is a blob with its own vertex records, up to 3 per face when its faces
  // share none (an input in random order): it is charged as many lease faces' bytes.
  static constexpr int64_t kCachedRunBytesPerFace =
      (sizeof(FaceRecord) + 3 * sizeof(VertexRecord) + kPatchBytesPerFace - 1) / kPatchBytesPerFace *
      kPatchBytesPerFace;
  int64_t room = 0;              // lease bytes it may still take in this batch (under `mutex`)
  uint64_t faces = 0;            // faces it holds
};

// Appends a filtered blob's faces and vertex records to `g` (over the limit: only
// counts its owned faces).
void gather_blob(const BlobView& v, const PatchPart& part, Gathered& g, UniqueVertexRecords& unique_vertices) {
  for (uint64_t i = 0; i < v.faces; ++i) g.owned_faces += v.face[i].owner == part.owner;
  if (g.over_limit) return;
  g.faces.insert(g.faces.end(), v.face, v.face + v.faces);
  constexpr uint64_t kSlotsAhead = 16, kRecordsAhead = 8;
  for (uint64_t i = 0; i < v.vertices; ++i) {
    if (i + kSlotsAhead < v.vertices) unique_vertices.prefetch_slot(v.vertex[i + kSlotsAhead].gid);
    if (i + kRecordsAhead < v.vertices) unique_vertices.prefetch_record(v.vertex[i + kRecordsAhead].gid);
    unique_vertices.add(v.vertex[i]);
  }
}

// The faces and vertex shares of a batch of runs, from the chunk metas.
std::pair<uint64_t, int64_t> runs_size(const MeshState& state, const std::vector<RunRead>& reads) {
  uint64_t faces = 0;
  int64_t units = 0;
  for (const RunRead& r : reads) {
    const ChunkMeta& m = state.chunks[r.chunk].meta;
    for (size_t k = 0; k < ChunkMeta::kParts; ++k)
      if (r.runs >> k & 1u) {
        faces += run_faces(m.faces, k);
        units += ChunkMeta::share_units(m.run_share[k]);
      }
  }
  return {faces, units};
}

// Reads the given runs of the given chunks (one batch of frames through the job's I/O
// thread) and appends their faces, and the vertex records those use, to `g`; the owner's
// faces outside the part's region get kNotInPart. Runs the cache holds are taken from
// it instead; of a frame read, the runs not read before (`read`: per chunk, including
// this batch's) go to the cache while it has room: what `limit_bytes` leaves beside
// `planned_bytes` (the gather with this batch, patch_bytes) and what the cache holds.
// Over the limit (g.over_limit, set by the caller) `g` holds nothing and only counts.
void read_runs(Job& job, ScratchStore& scratch, const MeshState& state, const std::vector<RunRead>& reads,
               const std::vector<RunMask>& read, const PatchPart& part, Gathered& g, uint64_t limit_bytes,
               uint64_t planned_bytes, UniqueVertexRecords& unique_vertices, RunCache& cache) {
  std::vector<FrameRef> frames;
  // A chunk's frame is told apart by its first face id (faces are in one chunk each).
  std::unordered_map<uint64_t, RunRead> runs_of;
  for (const RunRead& r : reads) {
    const auto held = cache.held.find(r.chunk);
    const RunMask cached = held == cache.held.end() ? 0 : RunMask(held->second & r.runs);
    const ChunkMeta& m = state.chunks[r.chunk].meta;
    for (size_t k = 0; k < ChunkMeta::kParts; ++k) {
      if (!(cached >> k & 1u)) continue;
      Bytes& blob = cache.runs[r.chunk][k];
      const BlobView v = view_blob(blob.data(), blob.size());
      cache.faces -= v.faces;
      gather_blob(v, part, g, unique_vertices);
      release_memory(blob);
    }
    if (cached) held->second &= RunMask(~cached);
    const RunMask rest = RunMask(r.runs & ~cached);
    if (!rest) continue;
    frames.push_back(state.chunks[r.chunk].frame);
    runs_of.emplace(m.first_fid, RunRead{r.chunk, rest});
  }
  if (order_fuzz_seed()) shuffle(frames);
  cache.room = int64_t(limit_bytes) - int64_t(planned_bytes) - RunCache::kCachedRunBytesPerFace * int64_t(cache.faces);
  engine::for_each_frame(
      job, scratch, "epochs", "state frames", frames, 1,
      [&](const FrameHeader& header, Bytes& records, Lease&) {
        const BlobView v = view_blob(records.data(), records.size());
        if (v.faces == 0) return;
        const auto found = runs_of.find(v.face[0].fid);
        if (found == runs_of.end()) throw Error(ErrorKind::internal, "state chunk not asked for");
        const RunMask runs = found->second.runs;
        const size_t chunk = found->second.chunk;
        // The runs not read yet go to the cache, as many as its room takes.
        RunMask to_cache = 0;
        {
          const std::lock_guard lock(cache.mutex);
          const auto held = cache.held.find(chunk);
          const RunMask unread = RunMask(~read[chunk] & ~(held == cache.held.end() ? 0 : held->second));
          for (size_t k = 0; k < ChunkMeta::kParts; ++k) {
            const int64_t faces = int64_t(run_faces(v.faces, k));
            if ((unread >> k & 1u) && faces > 0 && cache.room >= RunCache::kCachedRunBytesPerFace * faces) {
              cache.room -= RunCache::kCachedRunBytesPerFace * faces;
              to_cache |= RunMask(1u << k);
            }
          }
        }
        const bool owners = header.tag == part.owner;
        if (runs == kAllRuns && (!owners || part.whole)) return;  // kept as it is
        const GidTable table(v.vertices, [&](size_t i) { return v.vertex[i].gid; });
        auto index_of = [&](uint64_t gid) {
          const uint32_t i = table.find(gid);
          if (i == GidTable::kMissing) throw Error(ErrorKind::internal, "state chunk lacks a vertex record");
          return size_t(i);
        };
        // Per vertex: bit k, used by a face of run k.
        std::vector<uint8_t> used(v.vertices, 0);
        std::array<std::vector<FaceRecord>, ChunkMeta::kParts> kept;
        const RunMask wanted = RunMask(runs | to_cache);
        for (size_t k = 0; k < ChunkMeta::kParts; ++k)
          if (wanted >> k & 1u) kept[k].reserve(run_faces(v.faces, k));
        for (uint64_t j = 0; j < v.faces; ++j) {
          const size_t k = ChunkMeta::part_of(j, v.faces);
          if (!(wanted >> k & 1u)) continue;
          const FaceRecord& f = v.face[j];
          const size_t a = index_of(f.v[0]), b = index_of(f.v[1]), c = index_of(f.v[2]);
          kept[k].push_back(f);
          if (owners && !part.whole) {
            Point centroid{};
            for (size_t corner : {a, b, c})
              for (int d = 0; d < 3; ++d) centroid[d] += v.vertex[corner].position[d];
            for (int d = 0; d < 3; ++d) centroid[d] /= 3;
            if (!part.region.contains_half_open(centroid)) kept[k].back().owner = kNotInPart;
          }
          used[a] |= RunMask(1u << k);
          used[b] |= RunMask(1u << k);
          used[c] |= RunMask(1u << k);
        }
        // The asked runs as one blob (replacing the records), each cached run as its own.
        // Written in place: staging the records in vectors first copied each twice
        // more, with the vectors' growth.
        auto blob_of = [&](RunMask mask) {
          uint64_t nf = 0, nv = 0;
          for (size_t k = 0; k < ChunkMeta::kParts; ++k)
            if (mask >> k & 1u) nf += kept[k].size();
          for (uint64_t i = 0; i < v.vertices; ++i) nv += (used[i] & mask) != 0;
          Bytes blob = blob_with_header(nf, nv);
          std::byte* at = blob.data() + 16;
          for (size_t k = 0; k < ChunkMeta::kParts; ++k)
            if ((mask >> k & 1u) && !kept[k].empty()) {
              std::memcpy(at, kept[k].data(), kept[k].size() * sizeof(FaceRecord));
              at += kept[k].size() * sizeof(FaceRecord);
            }
          for (uint64_t i = 0; i < v.vertices; ++i)
            if (used[i] & mask) {
              std::memcpy(at, &v.vertex[i], sizeof(VertexRecord));
              at += sizeof(VertexRecord);
            }
          return blob;
        };
        std::array<Bytes, ChunkMeta::kParts> cached;
        for (size_t k = 0; k < ChunkMeta::kParts; ++k)
          if (to_cache >> k & 1u) cached[k] = blob_of(RunMask(1u << k));
        Bytes blob = blob_of(runs);
        records.swap(blob);
        if (!to_cache) return;
        const std::lock_guard lock(cache.mutex);
        auto& slots = cache.runs[chunk];
        for (size_t k = 0; k < ChunkMeta::kParts; ++k)
          if (to_cache >> k & 1u) {
            slots[k].swap(cached[k]);
            cache.faces += kept[k].size();
          }
        cache.held[chunk] |= to_cache;
      },
      [&](const FrameHeader&, Bytes& records, Lease&) {
        gather_blob(view_blob(records.data(), records.size()), part, g, unique_vertices);
      },
      0);
  if (g.over_limit) {
    release_memory(g.faces);
    release_memory(g.vertices);
  }
}

// Loads the whole state, sorted by fid / by gid and unique (the in-core finish).
Gathered load_state(Job& job, ScratchStore& scratch, const MeshState& state) {
  // Reserved up front at upper bounds: growth by doubling would hold the old and the new
  // arrays at once (a spike outside the lease); untouched reserved pages cost no RSS.
  Gathered g;
  std::vector<FrameRef> frames;
  for (const auto& c : state.chunks) frames.push_back(c.frame);
  g.faces.reserve(state.faces);
  g.vertices.reserve(state.blob_bytes_total / sizeof(VertexRecord) + 1);
  UniqueVertexRecords unique_vertices(g.vertices);
  if (order_fuzz_seed()) shuffle(frames);
  engine::for_each_frame(
      job, scratch, "epochs", "state frames", frames, 1, nullptr,
      [&](const FrameHeader&, Bytes& records, Lease&) {
        const BlobView v = view_blob(records.data(), records.size());
        g.found_faces += v.faces;
        g.faces.insert(g.faces.end(), v.face, v.face + v.faces);
        for (uint64_t i = 0; i < v.vertices; ++i) unique_vertices.add(v.vertex[i]);
      },
      0);
  // Keys are unique (face ids; one record per gid), so a parallel sort
  // gives the same arrays. In the job's arena: --threads holds here too.
  job.arena().execute([&] {
    tbb::parallel_sort(g.faces.begin(), g.faces.end(),
                       [](const FaceRecord& a, const FaceRecord& b) { return a.fid < b.fid; });
    tbb::parallel_sort(g.vertices.begin(), g.vertices.end(),
                       [](const VertexRecord& a, const VertexRecord& b) { return a.gid < b.gid; });
  });
  return g;
}

// Calls `f` on each of a PatchInput's per-vertex arrays that set_vertex fills from the
// records: quadrics and locks when the state has them, carried bests when they are valid.
template <class F>
void for_vertex_arrays(PatchInput& in, bool quadrics, bool bests, F&& f) {
  f(in.vertex_gids);
  f(in.positions);
  if (quadrics) {
    f(in.quadrics);
    f(in.locked);
  }
  if (bests) {
    f(in.best_gids);
    f(in.best_costs);
  }
}

// Sizes those arrays to `n` vertices, for set_vertex. Fresh arrays are faulted in on
// every thread (parallel_resize).
void resize_vertices(PatchInput& in, size_t n, bool quadrics, bool bests) {
  for_vertex_arrays(in, quadrics, bests, [n](auto& values) { parallel_resize(values, n); });
}

// Writes a vertex record's fields as vertex `i` of a PatchInput sized by resize_vertices
// (the same flags). By index rather than appended: the patch build writes its vertices
// from several threads. `fuzz` (nonzero under QEMFLOW_FUZZ_ORDER, a salt per build): a
// third of the bests are given as a copy without one would give them.
void set_vertex(PatchInput& in, size_t i, const VertexRecord& r, bool quadrics, bool bests, uint64_t fuzz) {
  in.vertex_gids[i] = r.gid;
  in.positions[i] = r.position;
  if (quadrics) {
    in.quadrics[i] = r.quadric;
    in.locked[i] = r.locked;
  }
  if (bests) {
    const bool dropped = fuzz && mix64(r.gid ^ fuzz) % 3 == 0;
    in.best_gids[i] = dropped ? kBestUnknown : r.best_gid;
    in.best_costs[i] = dropped ? 0.0 : r.best_cost;
  }
}

uint64_t fuzz_salt() { return order_fuzz_seed() ? next_fuzz_salt() : 0; }

// The patch build's per-vertex passes over a face list (fan lists, corner counts) split
// the vertices into ranges, one per thread: each range's task goes through the whole list
// but writes only its own vertices' entries, so every entry is written by one thread in
// the serial loop's order (the same arrays whatever the timing, no atomics). Each task
// reads the whole list, so below kSlicedItems the serial loop (one range) is cheaper.
constexpr size_t kSlicedItems = size_t(1) << 17;
constexpr size_t kMostSlices = 4;  // the list's reads grow with the ranges

size_t vertex_slices(size_t items) { return items < kSlicedItems ? 1 : std::min(parallel_threads(), kMostSlices); }

// body(slice, lo, hi) for the vertex ranges [lo, hi) that split [0, nv) into `slices`,
// one task each.
template <class Body>
void for_each_vertex_slice(size_t nv, size_t slices, Body&& body) {
  for_each_block(slices, 1, [&](size_t s, size_t, size_t) {
    body(s, uint32_t(nv * s / slices), uint32_t(nv * (s + 1) / slices));
  });
}

// A part's halo BFS over what its gather read so far, kept across the gather's read
// batches: each batch's faces and vertex records are indexed once (add), and the BFS
// goes on from where it stopped (run) instead of starting over: the vertices it had
// to expand but whose fans were not whole (loaded faces < degree; blocked) start it
// again, at their rings. A vertex's ring can drop once such a vertex is expanded; it
// is expanded again then, so the rings end as a fresh BFS's over the same faces, and
// a pass blocks at the vertices a fresh BFS would (the reads, and the patch, are the
// same). Owned faces are all in the first batch (owned_runs).
//
// A vertex is its record's index in the gathered array, which holds one record per gid
// (UniqueVertexRecords: the first copy with a known carried best, else the first read,
// so the patch does not depend on the read order; a record it replaces keeps its index).
class PatchBfs {
 public:
  PatchBfs(uint32_t owner, int rings, uint64_t limit_faces) : owner_(owner), rings_(rings), pending_(rings + 1) {
    if (rings >= kUnreached) throw Error(ErrorKind::internal, "halo rings beyond the BFS's ring type");
    // Reserved at upper bounds (a face brings at most 3 vertex records): no growth spikes.
    local_.reserve(limit_faces);
    face_ring_.reserve(limit_faces);
    next_.reserve(3 * limit_faces);
    head_.reserve(3 * limit_faces);
    loaded_.reserve(3 * limit_faces);
    ring_.reserve(3 * limit_faces);
  }

  // Indexes the faces and vertex records `g` gained since the last call (read order); a
  // vertex's id is its record's index (`ids`: the gather's, one record per gid).
  void add(const Gathered& g, const UniqueVertexRecords& ids) {
    head_.resize(g.vertices.size(), kNone);
    loaded_.resize(g.vertices.size(), 0);
    ring_.resize(g.vertices.size(), kUnreached);
    const size_t first = local_.size(), nf = g.faces.size();
    local_.resize(nf);
    face_ring_.resize(nf, kUnreached);
    std::atomic<bool> missing = false;
    tbb::parallel_for(tbb::blocked_range<size_t>(first, nf, 4096), [&](const tbb::blocked_range<size_t>& range) {
      constexpr size_t kSlotsAhead = 16, kRecordsAhead = 8;
      for (size_t f = range.begin(); f < range.end(); ++f) {
        if (f + kSlotsAhead < range.end())
          for (uint64_t gid : g.faces[f + kSlotsAhead].v) ids.prefetch_slot(gid);
        if (f + kRecordsAhead < range.end())
          for (uint64_t gid : g.faces[f + kRecordsAhead].v) ids.prefetch_record(gid);
        for (int k = 0; k < 3; ++k) {
          const uint32_t v = ids.find(g.faces[f].v[k]);
          if (v == UniqueVertexRecords::kMissing) {
            missing = true;
            continue;
          }
          local_[f][k] = v;
        }
        if (g.faces[f].owner == owner_) face_ring_[f] = 0;  // the owned faces seed the BFS
      }
    });
    if (missing) throw Error(ErrorKind::internal, "state chunk lacks a vertex record");
    // The fan lists, and the owned faces' corners as the BFS's seeds (ring 0). The order
    // of a ring's seeds (by range here) does not change the rings the BFS ends with.
    next_.resize(3 * nf);
    const size_t slices = vertex_slices(nf - first);
    std::vector<std::vector<uint32_t>> seeds(slices);
    for_each_vertex_slice(g.vertices.size(), slices, [&](size_t s, uint32_t lo, uint32_t hi) {
      link_corners(first, nf, lo, hi, seeds[s]);
    });
    for (const auto& some : seeds) pending_[0].insert(pending_[0].end(), some.begin(), some.end());
    // The vertices that blocked the last run: their fans may be whole now.
    for (uint32_t v : blocked_) pending_[ring_[v]].push_back(v);
    blocked_.clear();
  }

  // Goes on with the BFS over what was added; the positions of the vertices where it
  // is blocked (none: the halo is complete, build() may follow).
  std::vector<Point> run(const Gathered& g) {
    const VertexRecord* vb = g.vertices.data();
    for (int r = 0; r < rings_; ++r) {
      std::vector<uint32_t> level;
      level.swap(pending_[r]);
      // The next ring's vertices and the blocked ones, as found by a run of the level.
      auto visit = [&](size_t begin, size_t end, std::vector<uint32_t>& next, std::vector<uint32_t>& blocked) {
        for (size_t i = begin; i < end; ++i) {
          const uint32_t v = level[i];
          if (ring_[v] != r) continue;  // reached at a smaller ring since
          if (loaded_[v] < vb[v].degree) {
            blocked.push_back(v);
            continue;
          }
          expand(v, r, next);
        }
      };
      if (level.size() < kParallelLevel || parallel_threads() == 1) {
        visit(0, level.size(), pending_[r + 1], blocked_);
        continue;
      }
      // A level's vertices in parallel: they are expanded to the same rings in any order
      // (and the blocked are sorted below), so the patch does not depend on the timing.
      tbb::enumerable_thread_specific<std::pair<std::vector<uint32_t>, std::vector<uint32_t>>> found;
      tbb::parallel_for(tbb::blocked_range<size_t>(0, level.size(), 1024), [&](const tbb::blocked_range<size_t>& range) {
        auto& [next, blocked] = found.local();
        visit(range.begin(), range.end(), next, blocked);
      });
      for (const auto& [next, blocked] : found) {
        pending_[r + 1].insert(pending_[r + 1].end(), next.begin(), next.end());
        blocked_.insert(blocked_.end(), blocked.begin(), blocked.end());
      }
    }
    // A vertex reached at a smaller ring while blocked is listed twice.
    std::sort(blocked_.begin(), blocked_.end());
    blocked_.erase(std::unique(blocked_.begin(), blocked_.end()), blocked_.end());
    std::vector<Point> positions;
    positions.reserve(blocked_.size());
    for (uint32_t v : blocked_) positions.push_back(vb[v].position);
    return positions;
  }

  // The patch: the faces the BFS reached (owned + `rings` rings) and their corners, in
  // fid / gid order; flags as decimator.hpp asks. Consumes the index.
  PatchInput build(const Gathered& g, bool carry_bests) {
    const VertexRecord* vb = g.vertices.data();
    release_memory(next_);
    release_memory(head_);
    // The selection in fid order, each face with what the build reads of it (its
    // corners, whether it is owned): after the sort the loops below go through it in
    // order, where looking its record and corners up by index was a cache miss per face
    // in each of them.
    struct Selected {
      uint64_t fid;
      std::array<uint32_t, 3> corners;
      uint32_t owned;
    };
    static_assert(sizeof(Selected) == 24);
    std::vector<Selected> forder;
    const size_t nf = local_.size(), nv = loaded_.size();
    parallel_select(
        nf, [&](size_t f) { return face_ring_[f] != kUnreached; }, [&](size_t total) { forder.resize(total); },
        [&](size_t f, size_t rank) { forder[rank] = {g.faces[f].fid, local_[f], g.faces[f].owner == owner_}; });
    release_memory(face_ring_);
    release_memory(local_);
    // Keys are unique: the radix sort gives std::sort's order in a fraction of its CPU.
    radix_sort_by_key(forder, [](const Selected& x) { return x.fid; });
    // Per vertex: its faces in the patch, and whether the one of smallest fid is owned.
    std::vector<uint32_t> inside(nv, 0);
    std::vector<uint8_t> first_owned(nv, 0);
    for_each_vertex_slice(nv, vertex_slices(forder.size()), [&](size_t, uint32_t lo, uint32_t hi) {
      for (const Selected& s : forder)
        for (uint32_t v : s.corners)
          if (v - lo < hi - lo && inside[v]++ == 0) first_owned[v] = uint8_t(s.owned);
    });
    std::vector<std::pair<uint64_t, uint32_t>> vorder;
    parallel_select(
        nv, [&](size_t v) { return inside[v] != 0; }, [&](size_t total) { vorder.resize(total); },
        [&](size_t v, size_t rank) { vorder[rank] = {vb[v].gid, uint32_t(v)}; });
    radix_sort_by_key(vorder, [](const std::pair<uint64_t, uint32_t>& x) { return x.first; });
    const size_t kept_v = vorder.size();
    PatchInput in;
    std::vector<uint32_t> new_index(nv, std::numeric_limits<uint32_t>::max());
    const bool given_quadrics = nv > 0 && vb[0].has_quadric;
    const bool carried = given_quadrics && carry_bests;
    const uint64_t fuzz = fuzz_salt();
    // Exact sizes (no growth spikes); written by index from several threads.
    resize_vertices(in, kept_v, given_quadrics, carried);
    parallel_resize(in.incomplete, kept_v);
    parallel_resize(in.owned_vertex, kept_v);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, kept_v, 4096), [&](const tbb::blocked_range<size_t>& range) {
      // vorder visits the records at random: each is prefetched some visits ahead.
      constexpr size_t kAhead = 8;
      for (size_t i = range.begin(); i < range.end(); ++i) {
        if (i + kAhead < range.end()) {
          const std::byte* ahead = reinterpret_cast<const std::byte*>(vb + vorder[i + kAhead].second);
          for (size_t at = 0; at < sizeof(VertexRecord); at += 64) __builtin_prefetch(ahead + at);
          __builtin_prefetch(ahead + sizeof(VertexRecord) - 1);
        }
        const uint32_t v = vorder[i].second;
        const VertexRecord& r = vb[v];
        new_index[v] = uint32_t(i);
        set_vertex(in, i, r, given_quadrics, carried, fuzz);
        const bool incomplete = inside[v] < r.degree;
        in.incomplete[i] = incomplete;
        in.owned_vertex[i] = !incomplete && first_owned[v];
      }
    });
    release_memory(vorder);
    release_memory(inside);
    release_memory(first_owned);
    const size_t kept_f = forder.size();
    parallel_resize(in.faces, kept_f);
    parallel_resize(in.face_gids, kept_f);
    parallel_resize(in.owned_face, kept_f);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, kept_f, 4096), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t i = range.begin(); i < range.end(); ++i) {
        const Selected& s = forder[i];
        in.faces[i] = {new_index[s.corners[0]], new_index[s.corners[1]], new_index[s.corners[2]]};
        in.face_gids[i] = s.fid;
        in.owned_face[i] = s.owned != 0;
      }
    });
    release_memory(loaded_);
    release_memory(ring_);
    return in;
  }

 private:
  static constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
  static constexpr uint8_t kUnreached = std::numeric_limits<uint8_t>::max();
  // A level of the BFS at least this long is expanded in parallel.
  static constexpr size_t kParallelLevel = size_t(1) << 12;

  // Expands vertex v, reached at ring r < rings_ with its fan whole: faces reached from
  // ring r have their corners within r + 1 (those to expand: `next`). A face reached
  // from a smaller ring already gave its corners that. Relaxed atomic accesses: a
  // level's vertices are expanded in parallel, and all they write is r + 1, so the
  // rings end the same in any order; a vertex two of them reach at once is listed twice
  // and its second expansion finds nothing left to do.
  void expand(uint32_t v, int r, std::vector<uint32_t>& next) {
    const auto reached = uint8_t(r + 1);
    for (uint32_t e = head_[v]; e != kNone; e = next_[e]) {
      const uint32_t f = e / 3;
      std::atomic_ref<uint8_t> face_ring(face_ring_[f]);
      if (face_ring.load(std::memory_order_relaxed) <= reached) continue;
      face_ring.store(reached, std::memory_order_relaxed);
      for (uint32_t u : local_[f]) {
        std::atomic_ref<uint8_t> ring(ring_[u]);
        if (ring.load(std::memory_order_relaxed) <= reached) continue;
        ring.store(reached, std::memory_order_relaxed);
        if (reached < rings_) next.push_back(u);
      }
    }
  }

  // Links the corners of faces [first, nf) at vertices in [lo, hi) into their fans, in
  // face order; an owned face's corners are reached at ring 0 (those to expand: `seeds`).
  void link_corners(size_t first, size_t nf, uint32_t lo, uint32_t hi, std::vector<uint32_t>& seeds) {
    for (size_t f = first; f < nf; ++f) {
      const bool owned = face_ring_[f] == 0;
      for (int k = 0; k < 3; ++k) {
        const uint32_t v = local_[f][k];
        if (v - lo >= hi - lo) continue;  // another range's
        next_[3 * f + k] = head_[v];
        head_[v] = uint32_t(3 * f + k);
        ++loaded_[v];
        if (owned && ring_[v] != 0) {
          ring_[v] = 0;
          if (rings_ > 0) seeds.push_back(v);
        }
      }
    }
  }

  uint32_t owner_;
  int rings_;
  std::vector<std::array<uint32_t, 3>> local_; // face → its corners' vertices
  // Fans as lists through the faces' corners: head_[v] → 3 f + k → next_[3 f + k] ...
  std::vector<uint32_t> head_, next_, loaded_;
  std::vector<uint8_t> ring_;                  // per vertex: its ring (kUnreached: none)
  // Per face: the ring of its corners it was reached for (0: owned; kUnreached: none).
  std::vector<uint8_t> face_ring_;
  std::vector<std::vector<uint32_t>> pending_; // per ring: vertices to expand
  std::vector<uint32_t> blocked_;              // expanded vertices whose fans were not whole
};

// The finish's patch: the whole gathered state as one PatchInput (everything owned,
// nothing incomplete). Unlike a part's (PatchBfs) it needs no fans or BFS. The records are
// copied block by block, vertices first (the faces need their gids: local index = rank
// among the sorted, unique gids), and each copied block's pages go back to the OS at
// once (engine::release_pages), so the records and the input's arrays are never both
// whole: the build holds about what the gather held (40 B per face record, 136 B per
// vertex record) plus a block, and the finish peaks in the decimator
// (kInCoreBytesPerFace). The arrays grow within their reservations (no reallocation),
// each block's part written as it is made. `g` is consumed.
PatchInput build_whole_patch(Gathered&& g, bool carry_bests) {
  constexpr size_t kVertexBlock = size_t(1) << 16;  // 8.5 MiB of vertex records
  constexpr size_t kFaceBlock = size_t(1) << 18;    // 10 MiB of face records
  PatchInput in;
  const size_t nv = g.vertices.size(), nf = g.faces.size();
  const bool given_quadrics = nv > 0 && g.vertices[0].has_quadric;
  const bool bests = given_quadrics && carry_bests;
  const uint64_t fuzz = fuzz_salt();
  for_vertex_arrays(in, given_quadrics, bests, [nv](auto& values) { values.reserve(nv); });
  const void* released = g.vertices.data();
  for (size_t begin = 0; begin < nv; begin += kVertexBlock) {
    const size_t end = std::min(nv, begin + kVertexBlock);
    resize_vertices(in, end, given_quadrics, bests);
    for (size_t v = begin; v < end; ++v) set_vertex(in, v, g.vertices[v], given_quadrics, bests, fuzz);
    released = engine::release_pages(released, g.vertices.data() + end);
  }
  release_memory(g.vertices);
  in.faces.reserve(nf);
  in.face_gids.reserve(nf);
  std::atomic<bool> missing = false;
  released = g.faces.data();
  for (size_t begin = 0; begin < nf; begin += kFaceBlock) {
    const size_t end = std::min(nf, begin + kFaceBlock);
    in.faces.resize(end);
    in.face_gids.resize(end);
    tbb::parallel_for(tbb::blocked_range<size_t>(begin, end, 4096), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t f = range.begin(); f < range.end(); ++f) {
        in.face_gids[f] = g.faces[f].fid;
        for (int k = 0; k < 3; ++k) {
          const uint64_t gid = g.faces[f].v[k];
          const auto it = std::lower_bound(in.vertex_gids.begin(), in.vertex_gids.end(), gid);
          if (it == in.vertex_gids.end() || *it != gid) {
            missing = true;
            continue;
          }
          in.faces[f][k] = uint32_t(it - in.vertex_gids.begin());
        }
      }
    });
    released = engine::release_pages(released, g.faces.data() + end);
  }
  if (missing) throw Error(ErrorKind::internal, "state chunk lacks a vertex record");
  release_memory(g.faces);
  return in;
}

// `first_refreshes`: the best-edge refreshes of the first round's prepare (OocStats).
void run_patch_plan(PatchDecimator& d, const PatchPlan& plan, PhaseClock& clock, uint64_t& first_refreshes) {
  if (plan.kind == PatchPlan::Kind::summary_only) return;
  // The cut is known, so every round may skip the vertices whose edges all lie above
  // it (the summary after the epoch refreshes them with a plain prepare_round).
  for (size_t round = 0; round < plan.cuts.size(); ++round) {
    d.prepare_round(plan.cuts[round]);
    if (round == 0) first_refreshes += d.refreshes();
    d.apply_cut(plan.cuts[round]);
    if (round == 0) clock.charge(kFirstRound);
  }
}

struct Runner {
  Job& job;
  ScratchStore& scratch;
  const OocOptions& options;
  OocStats& stats;
  uint32_t patches = 1;
  uint64_t chunk_faces = 8192;  // faces per state chunk the export writes
  // Halo rings of the current pass: what its plan needs (pass_rings, set per pass) plus
  // what halo redos added for passes of that need (a redo's +2 sticks to the same kind
  // of pass: a summary-only pass does not widen the E-round passes' halos, nor back).
  int pass_rings = 0;
  // Faces the current pass's patches removed so far (its progress).
  uint64_t pass_removed = 0;
  // The job's progress through the epochs and the finish, in the epochs' span: the
  // first pass collapses nothing (it sums the first histograms), so the share of the
  // faces removed cannot move the bar through it (at 200M faces, minutes); it reports
  // the share of the state's faces its patches owned into the first kFirstPassShare,
  // and the rest of the span follows nodes::removed_share.
  double first_pass_progress(uint64_t faces_passed, uint64_t state_faces) const {
    return state_faces ? kFirstPassShare * double(faces_passed) / double(state_faces) : kFirstPassShare;
  }
  double removed_progress(uint64_t faces) const {
    return kFirstPassShare +
           (1 - kFirstPassShare) * nodes::removed_share(stats.input_faces, stats.target_faces, faces);
  }
  std::map<int, int> redo_rings;
  int rings() const {
    const auto it = redo_rings.find(pass_rings);
    return pass_rings + (it == redo_rings.end() ? 0 : it->second);
  }
  // The state's carried best edges are valid for this pass: the pass that wrote it ran
  // with the same params (false after the guards relax, until a pass rewrites it).
  bool carry_bests = false;
  std::vector<Box> owner_box;
  std::vector<double> owner_edge;  // mean edge length of the owned faces
  std::vector<uint64_t> owner_faces;

  // The parts each owner ran as in the last pass (one whole part unless it was split):
  // the next pass starts from them, so a split is found once, not every epoch.
  std::vector<std::vector<PatchPart>> owner_parts;

  // The part that runs after the current one (none at a pass's end): once the current
  // part is gathered, its owned runs are asked of the kernel (advise_next_gather), so
  // the disk reads them while this part decimates rather than while the next one waits.
  std::optional<PatchPart> next_part;

  void advise_next_gather(const MeshState& state) {
    if (!next_part) return;
    std::vector<FrameRef> frames;
    for (const RunRead& r : owned_runs(state, *next_part)) frames.push_back(state.chunks[r.chunk].frame);
    next_part.reset();
    job.io().submit(
        "advise next gather",
        [this, frames = std::move(frames)] {
          for (const FrameRef& f : frames) scratch.will_need(f.file, f.offset, f.bytes);
        },
        [](std::exception_ptr) {});  // advice: a failed one costs only the time it would have saved
  }

  // The least budget the in-core finish is known to need (0: none known), named by a
  // patch's refusal when it is more than the patch's.
  uint64_t finish_minimum = 0;

  void index_state(const MeshState& state) {
    owner_box.assign(patches, Box{});
    owner_faces.assign(patches, 0);
    for (const auto& c : state.chunks) {
      owner_box[c.meta.owner].add(c.meta.box);
      owner_faces[c.meta.owner] += c.meta.faces;
    }
    owner_parts.resize(patches);
    for (uint32_t p = 0; p < patches; ++p)
      if (owner_parts[p].empty()) owner_parts[p].push_back({p});
  }

  // The most a patch may hold: a quarter of the capacity stays free for the gather's
  // frame streams and the export's chunks (they take their own leases, or none, while
  // this one is held: no hold-and-wait on the whole budget).
  uint64_t patch_cap() const { return job.capacity() / 4 * 3; }

  // Where the part's owned faces are: the owner's box, cut to the region.
  Box owned_box(const PatchPart& part) const {
    return part.whole ? owner_box[part.owner] : owner_box[part.owner].intersected(part.region);
  }

  // Gathers a part's patch and builds it: the runs that may hold owned faces, then,
  // while the BFS is blocked at vertices whose fans were not read, the runs that hold
  // those vertices (one batch of reads per stop; each run is read at most once). The
  // BFS goes on over each batch (PatchBfs) rather than starting over. What is read
  // changes, never the patch. Holds at most `limit_bytes` (patch_bytes over the faces
  // and vertex shares of the runs read): a batch that would take it over is not read
  // (`g.over_limit`, nothing held, no patch: nullopt), but for the first, which is
  // read and counted without being held (the part's owned faces).
  std::optional<PatchInput> gather_and_build(const MeshState& state, const PatchPart& part, int rings,
                                             uint64_t limit_bytes, Gathered& g, PhaseClock& clock) {
    // The most faces it can hold (at most 3 vertex records each): arrays reserved up
    // front at these upper bounds (growth by doubling would hold the old and the new
    // arrays at once, a spike outside the patch lease); untouched reserved pages cost
    // no RSS.
    const uint64_t limit_faces = limit_bytes / kPatchBytesPerFace;
    g.faces.reserve(limit_faces);
    g.vertices.reserve(3 * limit_faces);
    UniqueVertexRecords unique_vertices(g.vertices);
    std::vector<RunMask> read(state.chunks.size(), 0);
    std::vector<RunRead> reads = owned_runs(state, part);
    PatchBfs bfs(part.owner, rings, limit_faces);
    RunCache cache;
    for (bool first = true;; first = false) {
      // Decided before the batch is read, from the metas: the same on every run.
      const auto [batch_faces, batch_units] = runs_size(state, reads);
      const uint64_t planned_faces = g.found_faces + batch_faces;
      const int64_t planned_units = g.share_units + batch_units;
      const uint64_t planned_bytes = patch_bytes(planned_faces, ChunkMeta::vertices_of(planned_units));
      g.found_faces = planned_faces;
      g.share_units = planned_units;
      if (planned_bytes > limit_bytes) {
        g.over_limit = true;
        release_memory(g.faces);
        release_memory(g.vertices);
        if (!first) return std::nullopt;
      }
      for (const RunRead& r : reads) read[r.chunk] |= r.runs;
      read_runs(job, scratch, state, reads, read, part, g, limit_bytes, planned_bytes, unique_vertices, cache);
      ++stats.gather_reads;
      clock.charge(kGather);
      if (!g.over_limit && g.faces.size() != g.found_faces)
        throw Error(ErrorKind::internal, "a gather read other faces than its runs hold");
      if (g.over_limit || g.owned_faces == 0) return std::nullopt;
      std::vector<Point> blocked;
      job.arena().execute([&] {
        bfs.add(g, unique_vertices);
        blocked = bfs.run(g);
      });
      clock.charge(kBuild);
      if (blocked.empty()) {
        cache.runs.clear();  // runs no batch asked for (none when the room was short)
        unique_vertices.release();  // the build reads records by index
        std::optional<PatchInput> input;
        job.arena().execute([&] { input = bfs.build(g, carry_bests); });
        clock.charge(kBuild);
        return input;
      }
      reads = runs_holding(state, blocked, read);
      if (reads.empty()) throw Error(ErrorKind::internal, "a vertex's faces are not in the mesh state");
    }
  }

  // Runs one part: gather and build under a lease of at most patch_cap(), run the
  // plan under `params`, summarize under `summary` (the charge may switch on between:
  // summary_params), export. False, with nothing run or kept, when the gather found
  // more faces than the lease holds.
  bool run_part(const MeshState& state, MeshState* next, PatchPart& part, const PatchPlan& plan,
                const DecimateParams& params, const DecimateParams& summary,
                std::vector<std::vector<Candidate>>* candidates, uint64_t needed, RoundSummary& total) {
    const uint32_t p = part.owner;
    PhaseClock clock(job, stats, p);
    for (;;) {
      job.check();
      const int rings = this->rings();
      // What the gather will hold is not known before it ran: the lease is what a patch
      // may hold (or the whole state, if less), trimmed to what was gathered.
      const uint64_t want =
          std::min(std::max<uint64_t>(1, patch_bytes(state.faces, state.vertices())), patch_cap());
      Lease lease = job.governor().acquire(job.owner("patch"), want, want, [this] { return job.stopped(); });
      job.check();
      Gathered g;
      std::optional<PatchInput> built = gather_and_build(state, part, rings, lease.bytes(), g, clock);
      advise_next_gather(state);
      stats.gathered_faces_total += g.found_faces;
      if (g.owned_faces == 0) return true;  // a region without owned faces
      if (g.over_limit) {
        part.stalled = g.owned_faces == part.parent_owned ? part.stalled + 1 : 0;
        if (g.owned_faces <= kSmallestPart || part.stalled >= kMostStalledHalvings) refuse_part(g);
        part.parent_owned = g.owned_faces;  // for its halves
        return false;
      }
      lease.shrink_to(patch_bytes(g.found_faces, g.found_vertices()));
      const uint64_t owned_faces = g.owned_faces;
      g = {};
      stats.patch_faces_max = std::max<uint64_t>(stats.patch_faces_max, built->faces.size());
      stats.patch_faces_total += built->faces.size();
      stats.owned_faces_total += owned_faces;
      bool ok = true;
      RoundSummary part_summary;
      std::vector<Candidate> owned;
      std::optional<PatchOutput> out;
      job.arena().execute([&] {
        PatchDecimator d(std::move(*built), params);
        stats.carried_bests += d.restored_bests();
        clock.charge(kSetup);
        run_patch_plan(d, plan, clock, stats.first_round_refreshes);
        clock.charge(kRounds);
        if (!(summary == d.params())) d.set_params(summary);
        d.prepare_owned_summary_round();
        // Without rounds the summary's prepare is the first.
        if (plan.cuts.empty()) stats.first_round_refreshes += d.refreshes();
        stats.patch_work += d.work();
        stats.frozen_refreshes += d.frozen_refreshes();
        stats.frozen_collapses += d.frozen_collapses();
        part_summary = d.summarize();
        if (candidates) owned = exact_cut_share(d.owned_candidates(), needed);
        clock.charge(kSummary);
        if (part_summary.inexact_candidates) {
          ok = false;
          return;
        }
        if (next) {
          out = d.extract(true, PatchDecimator::OutputOrder::local);  // export_patch orders the faces
          if (out->untrusted_vertices) ok = false;
        }
      });
      clock.charge(kExtract);  // the decimator's destruction included
      if (!ok) {
        redo_rings[pass_rings] += 2;
        ++stats.halo_redos;
        stats.max_rings = std::max(stats.max_rings, this->rings());
        continue;
      }
      total.add(part_summary);
      if (candidates) (*candidates).push_back(std::move(owned));
      if (next) {
        export_patch(*out, p, *next);
        pass_removed += owned_faces - out->faces.size();
      }
      clock.charge(kExport);
      return true;
    }
  }

  // A part this small is not split further: its patch is mostly halo, so halving it
  // would not make the patch fit.
  static constexpr uint64_t kSmallestPart = 2048;
  // Halvings in a row that keep every owned face before a part is refused: 16 per axis
  // shrink its region 65536 times around faces that all lie in it.
  static constexpr uint32_t kMostStalledHalvings = 48;

  // The gather stops once it holds too much, so the need is a lower bound; the budget
  // named is at least the one the finish needs (finish_minimum).
  [[noreturn]] void refuse_part(const Gathered& g) const {
    const uint64_t need = patch_bytes(g.found_faces, g.found_vertices());
    // patch_cap() is 3/4 of the job's capacity, which is the budget less the baseline and the trace.
    const uint64_t minimum = std::max(need / 3 * 4 + job.governor().baseline() + job.held_for_run(), finish_minimum);
    throw Error(ErrorKind::resource,
                "a patch of " + std::to_string(g.owned_faces) + " owned faces and its " + std::to_string(rings()) +
                    "-ring halo (over " + std::to_string(g.found_faces) + " faces) needs over " + config::format_size(need) +
                    " of memory but --mem-budget " + config::format_size(job.governor().budget()) +
                    " lets a patch hold " + config::format_size(patch_cap()) + "; this needs a budget of at least " +
                    config::format_budget(minimum));
  }

  // Halves a part's region across the longest axis of what it owns.
  std::pair<PatchPart, PatchPart> halve(const PatchPart& part) const {
    const Box owned = owned_box(part);
    int axis = 0;
    for (int k = 1; k < 3; ++k)
      if (owned.max[k] - owned.min[k] > owned.max[axis] - owned.min[axis]) axis = k;
    const double middle = 0.5 * (owned.min[axis] + owned.max[axis]);
    PatchPart low{part.owner, false, part.whole ? Box::unbounded() : part.region};
    PatchPart high = low;
    low.region.max[axis] = middle;
    high.region.min[axis] = middle;
    return {low, high};
  }

  // The part a pass runs after the parts `todo` (run from the back) of the owner at
  // `order[i]` are done.
  std::optional<PatchPart> first_part_after(size_t i, const std::vector<uint32_t>& order,
                                            const std::vector<PatchPart>& todo) const {
    if (!todo.empty()) return todo.back();
    for (size_t j = i + 1; j < order.size(); ++j)
      if (!owner_parts[order[j]].empty()) return owner_parts[order[j]].front();
    return std::nullopt;
  }

  // The owners with faces, those whose chunks were written last first (by the mean
  // index of their chunks in the state, which is the order they were written in).
  // Why: a state larger than the page cache loses its oldest pages first; a pass that
  // read the owners in the order they were written would read each chunk just after
  // its pages were evicted, where this order reads the ones still cached first. Each
  // pass writes in the order it runs, so the next one runs the other way round. The
  // order changes what is read when, not what a patch holds.
  std::vector<uint32_t> owners_newest_first(const MeshState& state) const {
    std::vector<double> index_sum(patches, 0.0);
    std::vector<uint64_t> chunks(patches, 0);
    for (size_t i = 0; i < state.chunks.size(); ++i) {
      index_sum[state.chunks[i].meta.owner] += double(i);
      ++chunks[state.chunks[i].meta.owner];
    }
    std::vector<uint32_t> order;
    for (uint32_t p = 0; p < patches; ++p)
      if (owner_faces[p] != 0) order.push_back(p);
    auto mean = [&](uint32_t p) { return index_sum[p] / double(chunks[p]); };
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return mean(a) > mean(b); });
    return order;
  }

  // One pass over the patches: each runs `plan` under `params`, summarizes under
  // `summary` and exports its owned faces into `next` (unless `candidates` is given:
  // then it only collects its exact-cut candidates).
  // An owner whose patch would not fit patch_cap() runs as parts: a part that does not
  // fit is halved before anything of it ran (its gather found too many faces), a part
  // of at most kSmallestPart owned faces that does not fit is refused; the next pass
  // starts from the parts this one ran.
  RoundSummary pass(const MeshState& state, MeshState* next, const PatchPlan& plan, const DecimateParams& params,
                    const DecimateParams& summary, std::vector<std::vector<Candidate>>* candidates,
                    uint64_t needed) {
    RoundSummary total;
    pass_removed = 0;
    const std::string stage = "epoch " + std::to_string(stats.ooc_epochs + 1);
    const bool first_pass = stats.ooc_epochs == 0 && !candidates;
    uint64_t faces_passed = 0;
    // The patches' big buffers, freed, serve the next ones (engine/retained_buffers.hpp).
    const engine::RetainedBuffers retained(job.governor());
    const std::vector<uint32_t> order = owners_newest_first(state);
    for (size_t i = 0; i < order.size(); ++i) {
      const uint32_t p = order[i];
      std::vector<PatchPart> todo(owner_parts[p].rbegin(), owner_parts[p].rend());
      std::vector<PatchPart> ran;
      while (!todo.empty()) {
        PatchPart part = std::move(todo.back());
        todo.pop_back();
        next_part = first_part_after(i, order, todo);
        if (run_part(state, next, part, plan, params, summary, candidates, needed, total)) {
          ran.push_back(std::move(part));
          continue;
        }
        auto [low, high] = halve(part);
        for (PatchPart* half : {&low, &high}) {
          half->parent_owned = part.parent_owned;
          half->stalled = part.stalled;
        }
        todo.push_back(std::move(high));
        todo.push_back(std::move(low));
        ++stats.patch_splits;
      }
      owner_parts[p] = std::move(ran);
      faces_passed += owner_faces[p];
      job.progress(first_pass ? first_pass_progress(faces_passed, state.faces)
                              : removed_progress(state.faces - pass_removed),
                   stage);
    }
    const engine::RetainedBuffers::Counts reuse = retained.counts();
    stats.reused_buffers += reuse.reused;
    stats.reused_buffer_bytes += reuse.reused_bytes;
    if (next) finish_state(job, scratch, *next);
    return total;
  }

  // `out` in the decimator's local order (extract's OutputOrder::local): its faces are
  // ordered here, by (Morton code, face id). The box's order does not matter: positions
  // are finite, and a -0.0 / +0.0 bound gives the same codes.
  void export_patch(const PatchOutput& out, uint32_t p, MeshState& next) {
    Box box;
    for (const auto& pos : out.positions) box.add(pos);
    // Faces in Morton order of their centroids: chunks of spatially close faces.
    std::vector<std::pair<uint32_t, uint32_t>> keyed(out.faces.size());
    job.arena().execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, out.faces.size(), 4096),
                        [&](const tbb::blocked_range<size_t>& range) {
                          for (size_t f = range.begin(); f < range.end(); ++f) {
                            Point c{};
                            for (uint32_t v : out.faces[f])
                              for (int k = 0; k < 3; ++k) c[k] += out.positions[v][k] / 3;
                            keyed[f] = {morton(c, box), uint32_t(f)};
                          }
                        });
    });
    // By code, then the faces of one code by id: the stable radix sort by code, then each
    // run of equal codes (a few faces; most codes are unique) sorted by id, where sorting
    // all by id first took a radix sort of its own.
    job.arena().execute([&] {  // the sort is parallel: in the arena, --threads holds
      radix_sort_by_key(keyed, [](const std::pair<uint32_t, uint32_t>& x) { return uint64_t{x.first}; });
    });
    for (size_t begin = 0, end; begin < keyed.size(); begin = end) {
      end = begin + 1;
      while (end < keyed.size() && keyed[end].first == keyed[begin].first) ++end;
      if (end - begin > 1)
        std::sort(keyed.begin() + ptrdiff_t(begin), keyed.begin() + ptrdiff_t(end),
                  [&](const auto& a, const auto& b) { return out.face_gids[a.second] < out.face_gids[b.second]; });
    }
    std::vector<uint32_t> order(keyed.size());
    for (size_t i = 0; i < keyed.size(); ++i) order[i] = keyed[i].second;
    release_memory(keyed);
    write_output_as_chunks(job, scratch, next, p, out, order, chunk_faces);
    job.io().drain();
    job.check();
  }
};

}  // namespace

// A state of `faces` faces in raw frames: chunks of n faces with their distinct
// vertices' records, at most 3 per face (a soup's, or a shuffled input's first state:
// a chunk then holds faces that share few corners), and per chunk the blob's counts
// (16 bytes) and the frame's header and checksum (56). Every chunk holds a face, so
// 16 + 56 + n (40 + 3 x 136) <= 520 n. The states shrink (a pass keeps owned faces,
// each patch's once: a halo redo runs before its export), so this bounds every state
// after a load of `faces` kept faces. It is a worst case (a soup's states are near
// it), far from a welded mesh's: raw runs peaked at 0.19-0.27 of
// raw_scratch_peak_bound (190-280 bytes a face: the 1M blob and terrain, the shared
// meshes) and a shuffled 300k blob at 0.53 (550 bytes a face: its first state's chunks
// share few corners).
// A state chunk's bytes beside its records: the blob's counts (16) and the raw frame's
// envelope.
constexpr uint64_t kChunkEnvelope = 16 + engine::frame_envelope_bytes;

uint64_t raw_state_bytes_bound(uint64_t faces) {
  return faces * (kChunkEnvelope + sizeof(FaceRecord) + 3 * sizeof(VertexRecord));
}

namespace {

// A state's raw bytes as they would be on disk: its blobs (exact) and a frame's
// envelope a chunk. Known when a pass starts, and the estimate auto sizes the pass's
// output by (ScratchStore::choose_codec's cap): that output is the patches' owned
// faces, fewer than the state's, chunked alike (chunk_faces a chunk, in Morton order),
// so it is typically smaller, but not surely (a patch's owned faces may fall into more,
// smaller chunks, each with its own copies of the vertices on its border).
uint64_t raw_state_bytes(const MeshState& state) {
  return state.blob_bytes_total + state.chunks.size() * engine::frame_envelope_bytes;
}

// The first state's raw bytes, estimated from the counts (the conversion writes it
// before any state is known): each face, and each vertex's record with a quarter more
// for the copies in the chunks that share it, and a chunk's envelope (16 + 56) for
// every chunk_faces faces; never above the bound. Measured (raw runs): the 1M demo's
// first state 118 bytes a face (0.57 records, 1.15 a vertex: chunks of 1,953 faces;
// estimate 125), the 20M proxy's 116 (chunks of 8,192); later states 117 a face. A
// shuffled input's chunks share few corners (a 300k blob: 428 bytes a face): the
// estimate is then far short, and the stage's cap turns it zstd.
uint64_t first_state_raw_estimate(uint64_t faces, uint64_t vertices, uint64_t chunk_faces) {
  const uint64_t estimate = faces * sizeof(FaceRecord) + vertices * sizeof(VertexRecord) * 5 / 4 +
                            (faces / std::max<uint64_t>(1, chunk_faces) + 1) * kChunkEnvelope;
  return std::min(estimate, raw_state_bytes_bound(faces));
}

}  // namespace

// On disk at once: the load's files (while it runs), then its blocks and vertex
// windows beside the first state (the conversion removes them after), then two states
// (the pass's input and its output; the input goes once the pass is done).
uint64_t raw_scratch_peak_bound(uint64_t faces, uint64_t vertices, bool small_load_frames) {
  const uint64_t state = raw_state_bytes_bound(faces);
  return std::max({engine::raw_load_scratch_bound(faces, vertices, small_load_frames),
                   engine::raw_loaded_blocks_bound(faces, vertices, small_load_frames) + state, 2 * state});
}

OocResult simplify_blocks(Job& job, ScratchStore& scratch, const engine::LoadedMesh& mesh, const OocOptions& options) {
  // The phases' spans end on this thread, some outside the arena: its track is named
  // for its arena slot ("compute-0"), not "thread-N".
  job.arena().execute([&] { job.trace().register_thread(); });
  OocResult result;
  OocStats& st = result.stats;
  st.input_faces = mesh.face_count;
  st.input_vertices = mesh.vertex_count;
  st.target_faces = target_face_count(mesh.face_count, options.simplify);
  const EpochOptions epoch = options.simplify.epochs;
  const uint64_t capacity = job.capacity();
  // The finish holds its lease while it gathers the state, whose frames need memory of
  // their own: a lease of the whole capacity would wait for them forever. So a forced
  // threshold (tests) is capped at what the budget allows.
  // The share of the capacity the finish's lease may take, and the capacity that gives
  // a lease of `bytes` its share.
  constexpr double kFinishShare = 0.9;
  auto capacity_for_finish = [&](uint64_t bytes) { return uint64_t(double(bytes) / kFinishShare); };
  const uint64_t in_core_bytes = uint64_t(kFinishShare * double(capacity));
  const uint64_t most_in_core_faces = in_core_bytes / kInCoreBytesPerFace;
  const uint64_t in_core_faces =
      options.in_core_faces ? std::min(options.in_core_faces, most_in_core_faces) : most_in_core_faces;
  // Faces alone do not size the finish: a soup (--no-weld) has 3 vertices per face.
  auto fits_in_core = [&](uint64_t faces, uint64_t vertices) {
    return faces <= in_core_faces && in_core_finish_bytes(faces, vertices) <= in_core_bytes;
  };
  // The output is made by the in-core finish, which holds at least the target's faces:
  // a target too large for the budget is refused now (DESIGN §3 'Bounded'), not run over
  // it. (Streaming a large output out of core is not implemented.)
  job.require_fits("the in-core finish of " + std::to_string(st.target_faces) + " output faces",
                   capacity_for_finish(st.target_faces * kInCoreBytesPerFace));

  // The finish holds the vertices its faces reference, not the input's others: 2M
  // unreferenced vertices beside a 20k-face grid asked 839 MiB (review16). Before the
  // state is made their count is bounded by 3 a kept face (the state's own count,
  // state->vertices(), sizes the finish itself).
  const uint64_t referenced_vertices = std::min(mesh.vertex_count, 3 * mesh.kept_faces());
  // A mesh that fits the finish needs no partition (no sampling, clusters or planes):
  // it goes in core at once. An explicit --clusters is kept (tests force epochs so).
  PartitionOptions partition_options = options.partition;
  if (partition_options.clusters == 0 && fits_in_core(mesh.kept_faces(), referenced_vertices)) partition_options.clusters = 1;
  // The job's progress (engine/job.hpp): the load took [0, kLoadShare] (ooc_command.cpp),
  // then the partition, the conversion, and the epochs with the finish, whose share is
  // nearly all of a run's time (the 20M blob at 1G: load, partition and conversion
  // 41 s of 427).
  job.progress_span(kLoadShare, kLoadShare + 0.01);
  job.progress(0, "partition");
  const Partition partition = partition_blocks(job, scratch, mesh, partition_options);
  st.patches = partition.clusters;
  // A surface too small to sample for two clusters (copies of one triangle) has nothing
  // to split it by: one patch, which has to be the finish. Refused with the finish's
  // minimum when that does not fit, rather than halving a part that cannot shrink.
  if (partition.clusters == 1 && partition_options.clusters != 1 && !fits_in_core(mesh.kept_faces(), referenced_vertices)) {
    job.require_fits("the in-core finish of " + std::to_string(mesh.kept_faces()) + " faces (their surface is too small to partition: " +
                         std::to_string(partition.samples) + " sample)",
                     capacity_for_finish(std::max<uint64_t>(1, in_core_finish_bytes(mesh.kept_faces(), referenced_vertices))));
  }

  auto state = std::make_unique<MeshState>();
  state->file = scratch.create_file("state-0");
  // At least ~32 chunks per patch: a gather reads a chunk's runs by their boxes, so
  // chunks much larger than a patch's halo band make small patches
  // (the 1M-face demo's 60K) read several times their own state. Any chunking gives
  // the same patches.
  const uint64_t chunk_faces = std::clamp<uint64_t>(mesh.kept_faces() / std::max<uint32_t>(1, partition.clusters) / 32,
                                                    std::min<uint64_t>(1024, options.chunk_faces), options.chunk_faces);
  // Raw when the bound fits; else when the estimate fits twice over: raw up to the
  // estimate (the cap), and room for the stage again in zstd should it pass the cap
  // (zstd -1 writes state chunks in at most their raw bytes: 0.14 of them in the
  // conversion, 0.61 in the epochs, on the 1M demo). The states shrink epoch by epoch:
  // a disk too small for the first may have room for a later one (and the state on
  // disk beside it is counted).
  auto choose_state_codec = [&](uint64_t faces, uint64_t raw_estimate, const std::string& stage) {
    scratch.choose_codec(raw_state_bytes_bound(faces), raw_estimate, raw_estimate, stage);
  };
  choose_state_codec(mesh.kept_faces(), first_state_raw_estimate(mesh.kept_faces(), referenced_vertices, chunk_faces),
                     "convert");
  job.progress_span(kLoadShare + 0.01, kEpochsFrom);
  convert_blocks(job, scratch, mesh, partition, chunk_faces, *state);
  if (order_fuzz_seed()) shuffle(state->chunks);
  // The conversion read the blocks (and an out-of-core load's vertex windows) for the
  // last time: their disk goes back before the epochs write each state beside the last
  // (at 200M faces about 6 GB of 31 GB).
  remove_load_files(job, scratch, mesh);
  st.scratch_epochs_start_bytes = scratch.bytes_on_disk();

  Runner runner{job, scratch, options, st};
  // The finish holds at least the isolated faces (a soup's: nothing collapses them,
  // each with its 3 vertices) beside what the rest of the mesh ends at (at most the
  // target's faces): a budget that cannot hold that is refused now, not after epochs
  // that cannot make the state fit (an unwelded soup ran two useless passes). The
  // minimum named then runs: the epochs go on until the state fits, at the latest once
  // the rest is within the target (if the rest stops above it, the finish's own check
  // below refuses with what the state then needs).
  if (state->isolated_faces && !fits_in_core(state->faces, state->vertices())) {
    const uint64_t isolated = state->isolated_faces;
    const uint64_t faces = std::min(state->faces, isolated + st.target_faces);
    const uint64_t bytes = capacity_for_finish(in_core_finish_bytes(faces, 3 * isolated + (faces - isolated) / 2));
    runner.finish_minimum = bytes + job.held_for_run() + job.governor().baseline();
    job.require_fits("the in-core finish of " + std::to_string(isolated) +
                         " isolated faces (nothing collapses them) and up to " + std::to_string(faces - isolated) +
                         " others",
                     bytes);
  }
  runner.patches = partition.clusters;
  runner.chunk_faces = chunk_faces;
  // A pass's halo: kTrustSpread rings per round of its plan, the decision radius, 2 to
  // spare, and kInitialQuadricRadius while the decimator computes the quadrics (the
  // first pass). The first pass and an exact cut's candidate pass run no rounds, so
  // their halos are a fraction of an E-round pass's. (--initial-rings: one count for all.)
  auto set_pass_rings = [&](size_t rounds, bool computes_quadrics) {
    runner.pass_rings = options.initial_rings
                            ? options.initial_rings
                            : int(kTrustSpread * rounds + kDecisionRadius + 2 +
                                  (computes_quadrics ? kInitialQuadricRadius : 0));
    st.max_rings = std::max(st.max_rings, runner.rings());
  };

  // The run's params (the guards relax once) and those of the last pass's summary, which
  // the next pass's rounds and the finish run under (summary_params: the charge off
  // until an epoch begins near the target); the face count that last pass began with.
  DecimateParams params = options.simplify.params;
  DecimateParams in_effect = params;
  uint64_t last_pass_faces = 0;
  bool relaxed = !(params.min_normal_cos > 0.0);
  bool first = true;
  RoundSummary summary;
  uint32_t generation = 0;
  auto new_state = [&] {
    auto s = std::make_unique<MeshState>();
    s->file = scratch.create_file("state-" + std::to_string(++generation));
    return s;
  };
  auto replace_state = [&](std::unique_ptr<MeshState> next) {
    const uint32_t old = state->file;
    job.io().call("remove state", [&] { scratch.remove(old); });
    state = std::move(next);
  };
  {
    engine::StageTimer timer(job, "epochs");
    job.progress_span(kEpochsFrom, kEpochsTo);
    while (!fits_in_core(state->faces, state->vertices()) && state->faces > st.target_faces) {
      runner.index_state(*state);
      PatchPlan plan;
      if (!first) {
        const EpochPlan e = plan_epoch(summary, state->faces, st.target_faces, relaxed, epoch);
        ++st.epochs;
        if (e.kind == EpochPlan::Kind::stop) break;
        if (e.kind == EpochPlan::Kind::relax) {
          params = relaxed_params(params);
          in_effect = relaxed_params(in_effect);  // the summary-only pass builds its patches with it
          relaxed = true;
          runner.carry_bests = false;  // found under the strict guards
        } else if (e.kind == EpochPlan::Kind::bin_cut) {
          plan = {PatchPlan::Kind::bin_cut, e.cuts};
        } else {
          std::vector<std::vector<Candidate>> lists;
          set_pass_rings(0, false);
          runner.pass(*state, nullptr, {}, in_effect, in_effect, &lists, e.needed);
          const std::vector<std::span<const Candidate>> spans(lists.begin(), lists.end());
          const auto cut = exact_cut(spans, e.needed);
          if (!cut) break;
          plan = {PatchPlan::Kind::exact_cut, {*cut}};
        }
      }
      set_pass_rings(plan.cuts.size(), first);
      choose_state_codec(state->faces, raw_state_bytes(*state), "epoch " + std::to_string(st.ooc_epochs + 1));
      auto next = new_state();
      const DecimateParams summary_as = summary_params(params, state->faces, st.target_faces, epoch);
      summary = runner.pass(*state, next.get(), plan, in_effect, summary_as, nullptr, 0);
      in_effect = summary_as;
      last_pass_faces = state->faces;
      st.rounds += plan.cuts.size();
      ++st.ooc_epochs;
      first = false;
      runner.carry_bests = true;  // the summary that exported them ran with `in_effect`
      replace_state(std::move(next));
      engine::trim_allocator();
    }
  }

  // Finish in core: the whole state as one patch (nothing incomplete, all owned).
  engine::StageTimer timer(job, "in core");
  st.in_core_faces = state->faces;
  st.in_core_vertices = state->vertices();
  runner.index_state(*state);
  // What the stages before freed but the allocator kept is covered by no lease: given
  // back here, else the finish's lease comes on top of it (a shuffled 300k at 84M
  // --clusters 2 went straight to the finish and peaked at 92 MiB, 39-65 MiB at its start).
  engine::trim_allocator();
  const engine::SoleJobPeakWindow finish_window(job.governor());  // the finish's own window (job.hpp)
  st.in_core_start_rss = engine::resident_bytes();
  // The epochs may stop short of a state that fits (nothing left to collapse: a soup's
  // isolated triangles): refused here with the minimum budget, before the gather, rather
  // than run over the budget (or wait forever for a lease of the whole capacity).
  const uint64_t finish_bytes = std::max<uint64_t>(1, in_core_finish_bytes(state->faces, state->vertices()));
  job.require_fits("the in-core finish of " + std::to_string(state->faces) + " faces and " +
                       std::to_string(state->vertices()) + " vertices",
                   capacity_for_finish(finish_bytes));
  Lease lease = job.governor().acquire(job.owner("in core"), std::min(capacity, finish_bytes),
                                       std::min(capacity, finish_bytes), [&] { return job.stopped(); });
  // The finish's stages as compute spans on this thread's track, like the patches' phases.
  std::optional<engine::Span> stage;
  auto begin = [&](const char* name) {
    stage.reset();
    stage.emplace(&job.trace(), &job.activity(), name);
  };
  PatchInput whole;
  {
    begin("finish gather");
    Gathered g = load_state(job, scratch, *state);
    begin("finish build");
    job.arena().execute([&] { whole = build_whole_patch(std::move(g), runner.carry_bests); });
  }
  stage.reset();
  replace_state(new_state());
  job.arena().execute([&] {
    {
      begin("finish setup");
      PatchDecimator d(std::move(whole), in_effect);
      st.in_core_carried_bests = d.restored_bests();
      begin("finish rounds");
      const EpochRunStats run = run_epochs(
          d, st.target_faces, epoch,
          [&](uint64_t, uint64_t faces) { job.progress(runner.removed_progress(faces), "in core"); },
          EpochRunStart{params, last_pass_faces});
      st.rounds += run.rounds;
      st.epochs += run.epochs;
      st.in_core_work = d.work();
      begin("finish extract");
      PatchOutput out = d.extract();
      copy_mesh(out, result.points, result.triangles);
    }  // the decimator's destruction in the extract's span
    stage.reset();
  });
  st.in_core_peak_rss = finish_window.peak();
  st.output_faces = result.triangles.size();
  st.output_vertices = result.points.size();
  return result;
}

}  // namespace qemflow::nodes::pipeline
