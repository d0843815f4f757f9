#include "engine/reencode.hpp"

#include <oneapi/tbb/parallel_sort.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <optional>
#include <span>
#include <type_traits>

#include "engine/process_memory.hpp"
#include "engine/report.hpp"
#include "engine/scratch.hpp"
#include "engine/stream_pass.hpp"
#include "io/mesh_file_kind.hpp"
#include "io/mesh_stream.hpp"
#include "io/ply_bulk.hpp"
#include "util/error.hpp"
#include "util/memory.hpp"

namespace qemflow::engine {

namespace {

constexpr uint64_t vertices_per_write = 1 << 18;

// Binary PLY output is encoded here, on compute threads, and the I/O thread only
// appends the bytes (DESIGN §2); other formats are still encoded by their writer on
// the I/O thread.
bool encodes_here(const io::MeshWriter& writer) { return writer.ply_vertex_double().has_value(); }

struct EncodedBytes {
  std::unique_ptr<char[]> bytes;
  Lease lease;
};

// Writes points [0, n) through the I/O thread; they must stay valid until it drains.
// Float PLY vertices are encoded here first when a buffer for them fits the budget
// right now (never waiting for memory: callers may hold leases others wait for).
void submit_vertices(Job& job, io::MeshWriter& writer, const Point* points, uint64_t n) {
  for (uint64_t first = 0; first < n; first += vertices_per_write) {
    const uint64_t count = std::min(vertices_per_write, n - first);
    const Point* slice = points + first;
    Lease lease;
    if (encodes_here(writer) && !*writer.ply_vertex_double()) {
      lease = job.governor().try_acquire(job.owner("vertex writes"), count * 12);
    }
    if (!lease) {
      job.io().submit("write vertices", [&writer, slice, count] { writer.write_vertices(slice, count); },
                      job.error_handler(), count * sizeof(Point));
      continue;
    }
    auto held = std::make_shared<EncodedBytes>();
    held->bytes = std::make_unique_for_overwrite<char[]>(count * 12);
    io::encode_ply_vertices(slice, count, false, held->bytes.get());
    held->lease = std::move(lease);
    job.io().submit(
        "write vertices",
        [&writer, held, count] {
          writer.write_encoded_vertices(held->bytes.get(), count);
          held->bytes.reset();
          held->lease.release();
        },
        job.error_handler(), count * 12);
  }
}

// Writes `n` vertices given as xyz floats (valid until the I/O thread drains): to a
// float binary PLY they are its bytes already, written with no copy; any other output
// gets them widened, a slice at a time, each written before the next.
// With `release`, a float PLY's slices are handed back to the kernel as they are written
// (the floats read as zeros afterwards; the caller frees them next): the output's page
// cache is then filled from pages the VM's host backs already (release_pages), where
// fresh ones cost the host a fault each.
void submit_float_vertices(Job& job, io::MeshWriter& writer, const float* xyz, uint64_t n, bool release = false) {
  const bool as_they_are = encodes_here(writer) && !*writer.ply_vertex_double();
  for (uint64_t first = 0; first < n; first += vertices_per_write) {
    const uint64_t count = std::min(vertices_per_write, n - first);
    const float* slice = xyz + 3 * first;
    if (as_they_are) {
      job.io().submit(
          "write vertices",
          [&writer, slice, count, release] {
            writer.write_encoded_vertices(reinterpret_cast<const char*>(slice), count);
            if (release) release_pages(slice, slice + 3 * count);
          },
          job.error_handler(), count * 12);
      continue;
    }
    for (uint64_t at = 0; at < count; at += 4096) {
      const uint64_t m = std::min<uint64_t>(4096, count - at);
      std::vector<Point> points(m);
      for (uint64_t i = 0; i < m; ++i) {
        const float* p = slice + 3 * (at + i);
        points[i] = {p[0], p[1], p[2]};
      }
      job.io().call("write vertices", [&] { writer.write_vertices(points.data(), m); });
    }
  }
}

// Hands `count` PLY triangles, encoded at `bytes` (with the lease that covers them),
// to the I/O thread to write.
// With `spare`, the buffer is kept there once written (with its lease), for the next
// to be encoded into: a fresh buffer is fresh pages, each faulted in (and on this
// project's VM, each fetched from the host again).
template <class Buffer>
void submit_encoded_triangles(Job& job, io::MeshWriter& writer, Buffer bytes, uint64_t count, uint64_t max_index,
                              Lease lease, std::shared_ptr<FramePool> spare = nullptr) {
  auto held = std::make_shared<std::pair<Buffer, Lease>>(std::move(bytes), std::move(lease));
  job.io().submit(
      "write triangles",
      [&job, &writer, held, count, max_index, spare] {
        writer.write_encoded_triangles(reinterpret_cast<const char*>(held->first.data()), count, max_index);
        if constexpr (std::is_same_v<Buffer, Bytes>) {
          // Kept bytes are not released: waiters are woken to look again (see FramePool).
          if (spare && spare->keep(held->first, held->second, 8)) job.governor().wake_all();
        }
        held->first = Buffer();
        held->second.release();
      },
      job.error_handler(), count * io::ply_triangle_bytes);
}

// u32 triangle records (12 bytes) to PLY face records (13 bytes, io::encode_ply_triangles'
// bytes) at `out`, which may be `records` itself when it has room: backwards, so that
// each record is read before anything is written over it (record i goes to 13i, at or
// after where it was, 12i). Returns the largest index.
uint64_t encode_triangle32_records(const std::byte* records, uint64_t count, std::byte* out) {
  uint32_t largest = 0;
  for (uint64_t i = count; i-- > 0;) {
    uint32_t abc[3];
    std::memcpy(abc, records + i * triangle32_record_size, sizeof abc);
    largest = std::max({largest, abc[0], abc[1], abc[2]});
    io::put_ply_triangle(abc[0], abc[1], abc[2], out + i * io::ply_triangle_bytes);
  }
  return largest;
}

// Block records (u32 or u64 triangle records) as PLY face records at `out`.
uint64_t encode_block_triangles(const std::byte* records, uint64_t count, uint32_t record_size, char* out) {
  uint64_t max_index = 0;
  if (record_size == triangle32_record_size) {
    max_index = encode_triangle32_records(records, count, reinterpret_cast<std::byte*>(out));
  } else {
    io::encode_ply_triangles(reinterpret_cast<const Triangle*>(records), count, out, max_index);
  }
  return max_index;
}

// Writes every vertex, in index order, through the I/O thread.
void write_vertices(Job& job, ScratchStore& scratch, const LoadedMesh& mesh, io::MeshWriter& writer) {
  StageStats& stage = job.stage("write");
  const VertexStore& store = mesh.vertices;
  if (mesh.vertices_delivered) return;  // written by the loader's dereference
  if (store.is_resident()) {
    if (!store.resident_xyz.empty()) {
      submit_float_vertices(job, writer, store.resident_xyz.data(), store.count, true);  // freed below
    } else {
      submit_vertices(job, writer, store.resident.data(), store.count);
    }
    job.io().drain();
    job.check();
    return;
  }
  for (uint64_t w = 0; w < store.windows.size(); ++w) {
    uint64_t first = w * store.window;
    if (first >= store.count) break;
    uint64_t n = std::min(store.window, store.count - first);
    Lease lease = job.governor().acquire(job.owner("vertex window"), n * sizeof(Point), n * sizeof(Point));
    UninitializedVector<Point> positions(n);
    load_vertex_window(job, scratch, store, w, positions.data());
    submit_vertices(job, writer, positions.data(), n);
    job.io().drain();
    job.check();
    job.progress(0.8 + 0.1 * double(w + 1) / double(store.windows.size()), "write");
  }
  (void)stage;
}

// Hands `n` Triangles at the front of `triangles` (with the lease that covers them) to
// the I/O thread to write.
template <class Buffer>
void submit_triangles(Job& job, io::MeshWriter& writer, Buffer triangles, uint64_t n, Lease lease) {
  auto held = std::make_shared<std::pair<Buffer, Lease>>(std::move(triangles), std::move(lease));
  job.io().submit(
      "write triangles",
      [&writer, held, n] {
        writer.write_triangles(reinterpret_cast<const Triangle*>(held->first.data()), n);
        held->first = Buffer();
        held->second.release();
      },
      job.error_handler(), n * sizeof(Triangle));
}

// The largest index a block's PLY face record may hold: each was checked against the
// vertex count when it was made (the writer checks what it is told).
uint64_t ply_records_max_index(const LoadedMesh& mesh) { return mesh.vertex_count ? mesh.vertex_count - 1 : 0; }

// Blocks held in memory as PLY face records, to binary PLY: the pages are the output's
// bytes, handed to the I/O thread as they lie (a full page is large enough for the
// sink to write without a copy) and freed once written. Their lease goes back at the
// end: nothing else asks for memory while they are written.
uint64_t write_resident_ply_records(Job& job, LoadedMesh& mesh, io::MeshWriter& writer) {
  constexpr uint64_t triangles_per_task = 1 << 18;
  const uint64_t max_index = ply_records_max_index(mesh);
  std::vector<Bytes*> pages;
  for (auto& cell : mesh.resident_blocks)
    for (Bytes& page : cell) pages.push_back(&page);
  uint64_t written = 0;
  for (size_t first = 0; first < pages.size();) {
    auto batch = std::make_shared<std::vector<Bytes>>();
    uint64_t n = 0;
    size_t end = first;
    while (end < pages.size() && (n == 0 || n + pages[end]->size() / ply_triangle_record_size <= triangles_per_task)) {
      n += pages[end]->size() / ply_triangle_record_size;
      batch->push_back(std::move(*pages[end++]));
    }
    job.io().submit(
        "write triangles",
        [&writer, batch, max_index] {
          for (Bytes& page : *batch) {
            writer.write_encoded_triangles(reinterpret_cast<const char*>(page.data()),
                                           page.size() / ply_triangle_record_size, max_index);
            // Its pages straight back to the kernel (free() would keep them in the heap),
            // which then fills the output's page cache from them: pages the VM's host
            // has backed already, where fresh ones cost the host a fault each.
            release_pages(page.data(), page.data() + page.size());
            page = Bytes();
          }
        },
        job.error_handler(), n * io::ply_triangle_bytes);
    written += n;
    first = end;
    job.progress(0.9 + 0.1 * double(first) / double(pages.size()), "write");
  }
  job.io().drain();
  job.check();
  mesh.resident_blocks.clear();
  mesh.resident_blocks_lease.release();
  return written;
}

// Blocks held in memory, to binary PLY: pages encoded here, a few MiB at a time (few,
// large writes), while the I/O thread writes the ones before; pages are freed as they go.
uint64_t write_resident_triangles_encoded(Job& job, LoadedMesh& mesh, io::MeshWriter& writer) {
  constexpr uint64_t triangles_per_write = 1 << 18;
  const uint32_t record = mesh.block_record_size;
  if (record == ply_triangle_record_size) return write_resident_ply_records(job, mesh, writer);
  std::vector<Bytes*> pages;
  for (auto& cell : mesh.resident_blocks)
    for (Bytes& page : cell) pages.push_back(&page);
  uint64_t written = 0;
  auto spare = std::make_shared<FramePool>();  // shared with the I/O tasks
  for (size_t first = 0; first < pages.size();) {
    size_t end = first;
    uint64_t n = 0;
    while (end < pages.size() && (n == 0 || n + pages[end]->size() / record <= triangles_per_write)) {
      n += pages[end++]->size() / record;
    }
    const uint64_t bytes_needed = n * io::ply_triangle_bytes;
    // A buffer written already, kept with its lease (see submit_encoded_triangles), or a
    // new one; before waiting for memory, the kept ones go back.
    Bytes bytes;
    Lease lease;
    if (std::optional<FramePool::Kept> kept = spare->take(bytes_needed)) {
      lease = std::move(kept->lease);
      bytes = std::move(kept->buffer);
    } else if (!(lease = job.governor().try_acquire(job.owner("triangle writes"), bytes_needed))) {
      job.io().drain();
      spare->clear();
      lease = job.governor().acquire(job.owner("triangle writes"), bytes_needed, bytes_needed,
                                     [&job] { return job.stopped(); });
    }
    job.check();
    bytes.resize(bytes_needed);
    char* out = reinterpret_cast<char*>(bytes.data());
    uint64_t max_index = 0;
    for (size_t p = first; p < end; ++p) {
      Bytes& page = *pages[p];
      const uint64_t count = page.size() / record;
      max_index = std::max(max_index, encode_block_triangles(page.data(), count, record, out));
      out += count * io::ply_triangle_bytes;
      mesh.resident_blocks_lease.shrink_to(mesh.resident_blocks_lease.bytes() -
                                           std::min<uint64_t>(mesh.resident_blocks_lease.bytes(), page.capacity()));
      page = Bytes();
    }
    submit_encoded_triangles(job, writer, std::move(bytes), n, max_index, std::move(lease), spare);
    written += n;
    first = end;
    job.progress(0.9 + 0.1 * double(first) / double(pages.size()), "write");
  }
  job.io().drain();
  spare->clear();
  job.check();
  mesh.resident_blocks.clear();
  mesh.resident_blocks_lease.release();
  return written;
}

// Blocks held in memory (triangle records, the loader's resident_blocks): each page
// widened to Triangles here while the I/O thread writes the one before; pages are
// freed as they go.
uint64_t write_resident_triangles(Job& job, LoadedMesh& mesh, io::MeshWriter& writer) {
  if (encodes_here(writer)) return write_resident_triangles_encoded(job, mesh, writer);
  uint64_t written = 0, pages = 0, done = 0;
  for (const auto& cell : mesh.resident_blocks) pages += cell.size();
  for (auto& cell : mesh.resident_blocks) {
    for (Bytes& page : cell) {
      const uint64_t n = page.size() / mesh.block_record_size;
      Lease lease = job.governor().acquire(job.owner("triangle writes"), n * sizeof(Triangle), n * sizeof(Triangle),
                                           [&job] { return job.stopped(); });
      job.check();
      UninitializedVector<Triangle> triangles(n);
      unpack_block_triangles(page.data(), n, mesh.block_record_size, triangles.data());
      mesh.resident_blocks_lease.shrink_to(mesh.resident_blocks_lease.bytes() - std::min<uint64_t>(mesh.resident_blocks_lease.bytes(), page.capacity()));
      page = Bytes();
      submit_triangles(job, writer, std::move(triangles), n, std::move(lease));
      written += n;
      job.progress(0.9 + 0.1 * double(++done) / double(pages), "write");
    }
  }
  job.io().drain();
  job.check();
  mesh.resident_blocks.clear();
  mesh.resident_blocks_lease.release();
  return written;
}

// Out-of-core blocks hold (face id, triangle) records (blocks.hpp) in an order that
// depends on the loader's vertex chunk: each block is written in face-id order, as
// the resident load files it, so the bytes depend on the input alone.
//
// A stream pass over groups (a block, or part of one): the I/O thread reads a group's
// frames; a compute thread decodes them, splits them into their runs in id order (a
// block is a few: the loader's chunks, then the spanning faces), merges the runs
// straight into output records, in pieces of at most ~2 MiB (so buffers come from the
// heap and are reused, not faulted in afresh), or sorts the records when there are
// many runs (tiny windows); the sink hands the pieces to the I/O thread in order.
// A block too large for a quarter of the free memory goes in groups of consecutive
// id ranges, found from a count of its ids by slab (one more read of the block, and
// each group reads it again, keeping its ids): memory stays bounded and the bytes
// are the same.
struct IdTriangle32 {
  uint32_t id;
  uint32_t v[3];
};
struct IdTriangle64 {
  uint64_t id;
  Triangle v;
};
static_assert(sizeof(IdTriangle32) == id_triangle32_record_size && sizeof(IdTriangle64) == id_triangle64_record_size);

uint64_t record_id(const std::byte* record, uint32_t record_size) {
  if (record_size == id_triangle32_record_size) {
    uint32_t id;
    std::memcpy(&id, record, sizeof id);
    return id;
  }
  uint64_t id;
  std::memcpy(&id, record, sizeof id);
  return id;
}

// Output records, appended in pieces of at most `piece_faces`: PLY face records
// (io::ply_triangle_bytes) or Triangles.
struct OutputPieces {
  bool ply = true;
  uint64_t piece_faces = 1;
  std::shared_ptr<FramePool> spare;  // written pieces kept for reuse
  Lease reused;  // the leases of the kept pieces taken: their pages are resident already
  std::vector<Bytes> pieces;
  std::vector<uint64_t> faces, max_index;
  uint64_t bytes_per_face() const { return ply ? io::ply_triangle_bytes : sizeof(Triangle); }
  // Records [begin, end), a piece's worth at a time.
  template <class Record>
  void add(const Record* begin, const Record* end) {
    while (begin != end) {
      if (pieces.empty() || faces.back() == piece_faces) {
        // A kept piece keeps its own lease: the group's covers only what the group
        // writes, which for a small block is less than a piece.
        std::optional<FramePool::Kept> kept = spare ? spare->take(piece_faces * bytes_per_face()) : std::nullopt;
        if (kept) {
          pieces.push_back(std::move(kept->buffer));
          reused.merge(std::move(kept->lease));
          pieces.back().resize(piece_faces * bytes_per_face());
        } else {
          pieces.emplace_back(piece_faces * bytes_per_face());
        }
        faces.push_back(0);
        max_index.push_back(0);
      }
      const uint64_t n = std::min<uint64_t>(uint64_t(end - begin), piece_faces - faces.back());
      std::byte* at = pieces.back().data() + faces.back() * bytes_per_face();
      max_index.back() = std::max(max_index.back(), put(begin, n, at));
      faces.back() += n;
      begin += n;
    }
  }
  // n records as output records at `at`; returns the largest index.
  uint64_t put(const IdTriangle32* r, uint64_t n, std::byte* at) const {
    uint32_t largest = 0;
    for (uint64_t i = 0; i < n; ++i) {
      largest = std::max({largest, r[i].v[0], r[i].v[1], r[i].v[2]});
      if (ply) {
        io::put_ply_triangle(r[i].v[0], r[i].v[1], r[i].v[2], at + i * io::ply_triangle_bytes);
      } else {
        const Triangle t{r[i].v[0], r[i].v[1], r[i].v[2]};
        std::memcpy(at + i * sizeof t, &t, sizeof t);
      }
    }
    return largest;
  }
  uint64_t put(const IdTriangle64* r, uint64_t n, std::byte* at) const {
    uint64_t largest = 0;
    for (uint64_t i = 0; i < n; ++i) {
      if (ply) {
        io::encode_ply_triangles(&r[i].v, 1, reinterpret_cast<char*>(at + i * io::ply_triangle_bytes), largest);
      } else {
        largest = std::max({largest, r[i].v[0], r[i].v[1], r[i].v[2]});
        std::memcpy(at + i * sizeof(Triangle), &r[i].v, sizeof(Triangle));
      }
    }
    return largest;
  }
  void finish() {  // the last piece to its size
    if (!pieces.empty()) pieces.back().resize(faces.back() * bytes_per_face());
  }
};

// How a group got into face-id order.
enum class Ordering { already, merged, sorted };

// Records (in decoded frames) to `out` in face-id order. Runs in id order (each frame's, cut where an id goes down) are
// merged, the run with the smallest head emitting while it stays below every other
// head: a scan of the heads per switch between runs, and switches are few when runs
// interleave little (a block's chunks and spanning faces). Past `max_breaks` places
// where the order goes down, or `max_runs` runs, the records are gathered and sorted.
template <class Record>
Ordering merge_in_face_id_order(Job& job, const std::vector<std::span<std::byte>>& frames, OutputPieces& out) {
  constexpr size_t max_breaks = 64, max_runs = 1024;
  struct Run {
    const Record* at;
    const Record* end;
  };
  std::vector<Run> runs;
  uint64_t n = 0;
  for (const std::span<std::byte> frame : frames) {
    const auto* records = reinterpret_cast<const Record*>(frame.data());
    const uint64_t count = frame.size() / sizeof(Record);
    n += count;
    for (uint64_t begin = 0, i = 1; begin < count; ++i) {
      if (i == count || records[i].id < records[i - 1].id) {
        runs.push_back({records + begin, records + i});
        begin = i;
      }
    }
  }
  size_t breaks = 0;
  for (size_t r = 1; r < runs.size(); ++r) breaks += runs[r].at->id < (runs[r - 1].end - 1)->id;
  auto by_id = [](const Record& a, const Record& b) { return a.id < b.id; };
  if (breaks > max_breaks || runs.size() > max_runs) {  // gathered to the front and sorted there
    // No copy: a copy of the records is memory no lease counts. The frames lie in one
    // buffer in address order, so each moves down next to the one before it (the
    // space between them is frame headers and checksums, or nothing).
    Record* all = reinterpret_cast<Record*>(frames[0].data());
    uint64_t at = 0;
    for (const std::span<std::byte> frame : frames) {
      if (reinterpret_cast<std::byte*>(all + at) > frame.data()) {
        throw Error(ErrorKind::internal, "frames to sort in place are not in address order");
      }
      std::memmove(static_cast<void*>(all + at), frame.data(), frame.size());
      at += frame.size() / sizeof(Record);
    }
    job.arena().execute([&] { tbb::parallel_sort(all, all + n, by_id); });
    out.add(all, all + n);
    return Ordering::sorted;
  }
  while (!runs.empty()) {
    size_t best = 0;
    uint64_t second = UINT64_MAX;
    for (size_t r = 1; r < runs.size(); ++r) {
      if (runs[r].at->id < runs[best].at->id) {
        second = runs[best].at->id;
        best = r;
      } else {
        second = std::min<uint64_t>(second, runs[r].at->id);
      }
    }
    Run& run = runs[best];
    const Record* stop = run.at + 1;
    while (stop != run.end && stop->id < second) ++stop;
    out.add(run.at, stop);
    run.at = stop;
    if (run.at == run.end) runs.erase(runs.begin() + int64_t(best));
  }
  return breaks > 0 ? Ordering::merged : Ordering::already;
}

struct FaceIdOrderStats {
  uint64_t written = 0;
  uint64_t groups = 0;  // stream items: one per block unless a block was too large
  uint64_t merged = 0;  // groups that were a few runs in id order, merged
  uint64_t sorted = 0;  // groups of many runs, sorted
};

FaceIdOrderStats write_blocks_in_face_id_order(Job& job, ScratchStore& scratch, LoadedMesh& mesh,
                                               io::MeshWriter& writer, uint64_t group_faces_limit) {
  const uint32_t record = mesh.block_record_size;
  const bool ply = encodes_here(writer);
  // A group in memory: its records (read, then decoded) and its output records.
  const uint64_t per_face = 2 * record + (ply ? io::ply_triangle_bytes : sizeof(Triangle));
  // Groups of at most half of what is free now: two in flight, so that one is read
  // while the other is put in order.
  const uint64_t limit = group_faces_limit ? group_faces_limit
                                           : std::max<uint64_t>(job.governor().available() / 2 / per_face, 1024);
  const std::string owner = job.owner("block in face-id order");
  FaceIdOrderStats stats;
  // Written output pieces, kept for the next groups' (a whole-blocks pass's only).
  // Shared with the I/O tasks, which may outlive this call when it throws.
  auto spare_pieces = std::make_shared<FramePool>();
  auto merge = [&](const std::vector<std::span<std::byte>>& frames, OutputPieces& out) {
    out.ply = ply;
    out.piece_faces = (2u << 20) / out.bytes_per_face();
    const Ordering ordering = record == id_triangle32_record_size ? merge_in_face_id_order<IdTriangle32>(job, frames, out)
                                                                  : merge_in_face_id_order<IdTriangle64>(job, frames, out);
    out.finish();
    return ordering;
  };
  // Output pieces to the I/O thread, in order, each with its part of `lease`.
  auto submit = [&](OutputPieces& out, Ordering ordering, Lease& lease) {
    lease.merge(std::move(out.reused));
    for (size_t p = 0; p < out.pieces.size(); ++p) {
      Lease piece_lease = lease.split(std::min<uint64_t>(lease.bytes(), out.pieces[p].capacity()));
      if (ply) {
        submit_encoded_triangles(job, writer, std::move(out.pieces[p]), out.faces[p], out.max_index[p],
                                 std::move(piece_lease), out.spare);
      } else {
        submit_triangles(job, writer, std::move(out.pieces[p]), out.faces[p], std::move(piece_lease));
      }
      stats.written += out.faces[p];
    }
    ++stats.groups;
    stats.merged += ordering == Ordering::merged;
    stats.sorted += ordering == Ordering::sorted;
    job.progress(0.9 + 0.1 * double(stats.written) / double(std::max<uint64_t>(mesh.face_count, 1)), "write");
  };

  // Whole blocks that fit, [first, end): a stream pass, an item a block. A block's
  // frames are read whole (header and payload, one read each) into one buffer, at
  // 8-byte aligned offsets, and raw records are merged from where they lie. The buffer
  // an item leaves is read into again by a later one (a FramePool, as for_each_frame's:
  // fresh buffers are fresh pages, faulted in one by one, most of this pass's faults).
  // A kept buffer serves a block whose frames it holds, and whose lease it does not
  // exceed: the lease counts a decoded copy of the records that raw frames never make,
  // so a buffer up to that much larger than the frames stays within it.
  struct BlockItem {
    uint32_t cell = 0;
    Bytes frames;
    std::vector<std::pair<uint64_t, uint64_t>> at;  // (offset, bytes) of each frame in `frames`
    OutputPieces out;
    Ordering ordering = Ordering::already;
  };
  auto frames_bytes = [&](uint32_t cell) {
    uint64_t bytes = 0;
    for (const FrameRef& ref : mesh.blocks[cell]) bytes += (ref.bytes + 7) / 8 * 8;
    return bytes;
  };
  // How much larger than its frames a block's buffer may be: raw frames are merged
  // where they lie, so the decoded records the lease counts are never made.
  const bool raw_frames = scratch.codec().raw;
  auto slack = [&](uint32_t cell) { return raw_frames ? mesh.block_faces[cell] * record : 0; };
  FramePool pool;
  using Kept = FramePool::Kept;
  std::optional<Kept> taken;  // the pump's (I/O thread): for block `next`
  auto write_whole_blocks = [&](uint32_t first, uint32_t end) {
    uint32_t next = first;
    auto skip_empty = [&] {
      while (next < end && mesh.block_faces[next] == 0) ++next;
    };
    StreamPass<BlockItem> pass;
    pass.stage = "write";
    pass.read_name = "read scratch";
    pass.transform_name = "face-id order";
    pass.owner = "block in face-id order";
    pass.max_in_flight = 2;
    pass.next_item_bytes = [&] {
      skip_empty();
      if (next == end) return uint64_t(1);
      const uint64_t room = frames_bytes(next);
      const uint64_t need = mesh.block_faces[next] * (per_face - record) + room;  // decoded and output records
      pool.choose(taken, [&](const Kept& kept) {
        return kept.buffer.capacity() >= room && kept.lease.bytes() <= room + slack(next);
      });
      return taken ? std::max<uint64_t>(need - taken->lease.bytes(), 1) : need;
    };
    pass.read = [&](BlockItem& item, Lease& lease) {
      skip_empty();
      if (next == end) return false;
      item.cell = next++;
      if (taken) {
        item.frames = std::move(taken->buffer);
        lease.merge(std::move(taken->lease));
        taken.reset();
      }
      const uint64_t room = frames_bytes(item.cell);
      // A fresh buffer gets room for larger blocks later, within what the lease allows.
      if (item.frames.capacity() < room) item.frames.reserve(std::min(room + room / 2, room + slack(item.cell)));
      item.frames.resize(room);
      uint64_t offset = 0;
      for (const FrameRef& ref : mesh.blocks[item.cell]) {
        if (ref.bytes < frame_header_bytes) throw Error(ErrorKind::internal, "a block frame shorter than its header");
        scratch.read(ref.file, ref.offset, item.frames.data() + offset, ref.bytes);
        scratch.discard(ref.file, ref.offset, ref.bytes);  // read once: its pages serve the output's writes
        item.at.emplace_back(offset, ref.bytes);
        offset += (ref.bytes + 7) / 8 * 8;
        job.stage("write").bytes_read += ref.bytes;
      }
      return true;
    };
    pass.transform = [&](BlockItem& item, Lease&) {
      item.out.spare = spare_pieces;
      std::vector<std::span<std::byte>> records;
      // Raw frames are merged (or sorted) where they lie in `frames`. Compressed ones
      // (the frames of a zstd scratch, or of another job's codec in this process) are
      // decoded one after another into one buffer, the decoded copy the lease counts,
      // with any raw ones among them copied beside: a sort then works in place either way.
      Bytes decoded;
      uint64_t faces = 0;
      bool in_place = raw_frames;
      for (size_t f = 0; in_place && f < item.at.size(); ++f) {
        std::byte* frame = item.frames.data() + item.at[f].first;
        Bytes unexpected;  // a compressed frame's records, dropped: decoded again below
        const FrameHeader header = decode_frame_in_place(frame, item.at[f].second, record, unexpected, "block frame");
        in_place = header.raw;
        records.emplace_back(frame + frame_header_bytes, header.count * record);
        faces += header.count;
      }
      if (!in_place) {
        records.clear();
        faces = 0;
        decoded.resize(mesh.block_faces[item.cell] * record);
        for (const auto& [offset, bytes] : item.at) {
          std::byte* at = decoded.data() + faces * record;
          const FrameHeader header = decode_frame_into(item.frames.data() + offset, bytes, record, at,
                                                       mesh.block_faces[item.cell] - faces, "block frame");
          records.emplace_back(at, header.count * record);
          faces += header.count;
        }
      }
      if (faces != mesh.block_faces[item.cell]) throw Error(ErrorKind::internal, "a block holds other faces than it counted");
      item.ordering = merge(records, item.out);
    };
    pass.sink = [&](BlockItem& item, Lease& lease) {
      // The frames' buffer is kept (its part of the lease with it) before the output
      // pieces take theirs.
      if (pool.keep(item.frames, lease)) job.governor().wake_all();
      submit(item.out, item.ordering, lease);
    };
    // Parked: nothing kept but the buffer taken for this read (counted in what it waits for).
    pass.parked_for_memory = [&] {
      pool.clear();
      spare_pieces->clear();
    };
    run_stream_pass(job, pass);
    // Nothing kept past the pass (its last pieces written first): a large block next
    // waits for memory.
    taken.reset();
    pool.clear();
    job.io().drain();
    spare_pieces->clear();
    job.check();
  };

  // A block too large for one group: its ids counted by slab, slabs grouped while they
  // fit, and each group gathered from a read of the whole block (frame by frame),
  // then put in order and written. The slab counts and the groups live in one working
  // lease taken before any read, at most half of what is free then: the frames read
  // meanwhile come from the other half, so a job never holds its working set while
  // waiting for more, and two jobs on one governor cannot leave each other no room.
  auto write_large_block = [&](uint32_t cell) {
    const std::vector<FrameRef>& frames = mesh.blocks[cell];
    const uint64_t slabs = std::clamp<uint64_t>(2 * ((mesh.face_count + limit - 1) / limit), 64, uint64_t{1} << 20);
    const uint64_t width = std::max<uint64_t>((mesh.face_count + slabs - 1) / slabs, 1);
    const uint64_t group_bytes_per_face = per_face - record;
    const uint64_t counts_bytes = slabs * sizeof(uint64_t);
    Lease working = job.governor().acquire_share(
        owner, counts_bytes + 1024 * group_bytes_per_face,
        [&](uint64_t free) { return std::min(free / 2, counts_bytes + limit * group_bytes_per_face); },
        [&job] { return job.stopped(); });
    job.check();
    const uint64_t working_bytes = working.bytes();
    const uint64_t group_limit = (working_bytes - counts_bytes) / group_bytes_per_face;
    std::vector<uint64_t> per_slab(slabs, 0);
    for_each_frame(job, scratch, "write", "block frames", frames, record, {},
                   [&](const FrameHeader& header, Bytes& records, Lease&) {
                     for (uint64_t i = 0; i < header.count; ++i) {
                       const uint64_t slab = record_id(records.data() + i * record, record) / width;
                       if (slab >= slabs) throw Error(ErrorKind::internal, "a face id past the face count");
                       ++per_slab[slab];
                     }
                   },
                   0);
    for (uint64_t first = 0; first < slabs;) {
      uint64_t end = first, faces = 0;
      while (end < slabs && (end == first || faces + per_slab[end] <= group_limit)) faces += per_slab[end++];
      if (end == first + 1 && faces > group_limit) {
        throw Error(ErrorKind::resource, "re-encode: " + std::to_string(faces) + " faces of one block within " +
                                             std::to_string(width) + " face ids do not fit the memory budget");
      }
      const uint64_t first_id = first * width, end_id = end * width;
      first = end;
      if (faces == 0) continue;
      Lease lease = working.split(faces * group_bytes_per_face);
      std::vector<Bytes> group(1);
      group[0].resize(faces * record);
      uint64_t at = 0;
      for_each_frame(
          job, scratch, "write", "block frames", frames, record,
          [&](const FrameHeader& header, Bytes& records, Lease&) {  // the group's records, to the front
            uint64_t kept = 0;
            for (uint64_t i = 0; i < header.count; ++i) {
              const std::byte* r = records.data() + i * record;
              const uint64_t id = record_id(r, record);
              if (id < first_id || id >= end_id) continue;
              if (kept != i) std::memmove(records.data() + kept * record, r, record);
              ++kept;
            }
            records.resize(kept * record);
          },
          [&](const FrameHeader&, Bytes& records, Lease&) {
            if (at + records.size() > group[0].size()) throw Error(ErrorKind::internal, "a block holds more faces than it counted");
            std::memcpy(group[0].data() + at, records.data(), records.size());
            at += records.size();
          },
          0);
      if (at != group[0].size()) throw Error(ErrorKind::internal, "a block holds fewer faces than it counted");
      OutputPieces out;
      const Ordering ordering = merge({std::span<std::byte>(group[0])}, out);
      release_memory(group);
      submit(out, ordering, lease);
      // The output pieces took their part of the lease to the I/O thread; once they
      // are written it is free again, and the working set is made whole for the next
      // group (only bytes this job just gave back are waited for).
      working.merge(std::move(lease));
      job.io().drain();
      job.check();
      const uint64_t deficit = working_bytes - working.bytes();
      if (first < slabs && deficit > 0 && !working.try_grow(deficit)) {
        working.merge(job.governor().acquire(owner, deficit, deficit, [&job] { return job.stopped(); }));
        job.check();
      }
    }
  };

  for (uint32_t c = 0; c < mesh.blocks.size();) {
    if (mesh.block_faces[c] > limit) {
      write_large_block(c++);
      continue;
    }
    uint32_t end = c;
    while (end < mesh.blocks.size() && mesh.block_faces[end] <= limit) ++end;
    write_whole_blocks(c, end);
    c = end;
  }
  job.io().drain();
  job.check();
  return stats;
}

// Reads every block and writes its triangles through the I/O thread.
uint64_t write_triangles(Job& job, ScratchStore& scratch, LoadedMesh& mesh, io::MeshWriter& writer) {
  if (mesh.blocks_resident()) return write_resident_triangles(job, mesh, writer);
  std::vector<FrameRef> frames;
  for (const auto& block : mesh.blocks) frames.insert(frames.end(), block.begin(), block.end());
  uint64_t written = 0;
  size_t done = 0;
  // Triangle records to PLY bytes on the compute threads; the largest index rides in
  // 8 bytes after them, for the writer's check.
  const bool encode = encodes_here(writer) && is_triangle_record(mesh.block_record_size);
  for_each_frame(
      job, scratch, "write", "block frames", frames, mesh.block_record_size,
      [&mesh, encode](const FrameHeader& header, Bytes& records, Lease&) {
        if (encode && mesh.block_record_size == ply_triangle_record_size) return;  // the output's bytes already
        if (encode && mesh.block_record_size == triangle32_record_size) {
          // In place: the frame's read left room for the PLY records (out_record_size).
          records.resize(header.count * io::ply_triangle_bytes + sizeof(uint64_t));
          const uint64_t max_index = encode_triangle32_records(records.data(), header.count, records.data());
          std::memcpy(records.data() + header.count * io::ply_triangle_bytes, &max_index, sizeof max_index);
          return;
        }
        if (encode) {
          Bytes out(header.count * io::ply_triangle_bytes + sizeof(uint64_t));
          uint64_t max_index = encode_block_triangles(records.data(), header.count, mesh.block_record_size,
                                                      reinterpret_cast<char*>(out.data()));
          std::memcpy(out.data() + header.count * io::ply_triangle_bytes, &max_index, sizeof max_index);
          records.swap(out);
          return;
        }
        if (is_triangle_record(mesh.block_record_size)) {
          Bytes out(header.count * sizeof(Triangle));
          unpack_block_triangles(records.data(), header.count, mesh.block_record_size,
                                 reinterpret_cast<Triangle*>(out.data()));
          records.swap(out);
          return;
        }
        // Triangles packed in place at the front of the decoded records (both block
        // layouts hold the vertex ids at bytes 8..32).
        auto* out = reinterpret_cast<Triangle*>(records.data());
        for (uint64_t i = 0; i < header.count; ++i) {
          Triangle t;
          std::memcpy(&t, records.data() + i * mesh.block_record_size + 8, sizeof t);
          out[i] = t;
        }
      },
      [&](const FrameHeader& header, Bytes& records, Lease& lease) {
        if (encode) {
          uint64_t max_index = ply_records_max_index(mesh);
          if (mesh.block_record_size != ply_triangle_record_size) {
            std::memcpy(&max_index, records.data() + header.count * io::ply_triangle_bytes, sizeof max_index);
          }
          submit_encoded_triangles(job, writer, std::move(records), header.count, max_index, lease.split(lease.bytes()));
          written += header.count;
          job.progress(0.9 + 0.1 * double(++done) / double(frames.size()), "write");
          return;
        }
        const uint64_t n = header.count;
        submit_triangles(job, writer, std::move(records), n, lease.split(lease.bytes()));
        written += n;
        job.progress(0.9 + 0.1 * double(++done) / double(frames.size()), "write");
      },
      encode && mesh.block_record_size == ply_triangle_record_size ? 0
      : encode                                                     ? uint32_t(io::ply_triangle_bytes) + 1
               : is_triangle_record(mesh.block_record_size) ? uint32_t(sizeof(Triangle)) : 0,
      false, encode && mesh.block_record_size == triangle32_record_size, nullptr, /*read_once=*/true);
  job.io().drain();
  job.check();
  return written;
}

}  // namespace

// Measured: 1.7x a binary PLY's size written to scratch for a 100M-face mesh (less on
// disk at once: files are removed after each pass); a .zst input is ~2.5x smaller.
uint64_t expected_scratch_bytes(uint64_t input_file_bytes, bool zstd_input) {
  return (zstd_input ? 5 : 2) * input_file_bytes;
}

// Raw frames: blocks are 16 bytes a face out of core (face id and triangle), bucketed
// local faces 16, vertex chunks 24 bytes a vertex, 12 when float (~44 a face; spanning
// faces cost more, ~170, but are few in real meshes); a binary PLY holds ~19 bytes a
// face (13 a face, 12 a vertex, half as many vertices as faces).
uint64_t expected_raw_scratch_bytes(uint64_t input_file_bytes, bool zstd_input) {
  return (zstd_input ? 10 : 4) * input_file_bytes;
}

ReencodeResult run_reencode(Governor& governor, const ReencodeOptions& options, const JobHooks& hooks) {
  JobSettings settings;
  settings.threads = options.threads;
  settings.trace_events = options.trace_path.empty() ? 0 : options.trace_events;
  if (!options.job_name.empty()) settings.owner_prefix = options.job_name + "/";
  Job job(governor, hooks, settings);
  ReencodeResult result;
  run_then_write_trace(job, options.trace_path, [&] {
    std::error_code ec;
    uint64_t input_bytes = std::filesystem::file_size(options.input, ec);
    if (ec) throw Error(ErrorKind::bad_input, options.input.string() + ": cannot read: " + ec.message());
    bool zstd_input = options.input.extension() == ".zst";
    ScratchStore scratch(options.scratch_dir, expected_scratch_bytes(input_bytes, zstd_input),
                         expected_raw_scratch_bytes(input_bytes, zstd_input), options.scratch_codec);
    // Declared after the store, so destroyed first: no queued scratch write may
    // outlive the store, whatever threw.
    struct DrainIo {
      Job& job;
      ~DrainIo() { job.io().drain(); }
    } drain_before_scratch_goes{job};
    // The output writer: opened once the counts and the coordinate type are known
    // (by the loader's `counted` hook when it goes out of core, so that it can write
    // the vertices as its dereference loads them; else after the load). It lives and
    // dies on the I/O thread: its destructor removes a half-written temporary file
    // when something failed.
    std::unique_ptr<io::MeshWriter> writer;
    struct WriterOnIo {
      Job& job;
      std::unique_ptr<io::MeshWriter>& writer;
      ~WriterOnIo() {
        job.io().drain();
        try {
          job.io().call("close output", [&] { writer.reset(); });
        } catch (...) {
        }
      }
    } writer_guard{job, writer};
    auto open_output = [&](const LoadedMesh& mesh) {
      if (writer) return;
      io::WriteOptions write_options;
      // OBJ text is read back as double, so only the shortest double text keeps the bits.
      std::string name = options.output.filename().string();
      bool obj = name.ends_with(".obj") || name.ends_with(".obj.zst");
      write_options.double_precision = !mesh.float_exact || obj;
      writer = job.io().call("open output", [&] {
        return io::open_mesh_writer(options.output, mesh.vertex_count, mesh.face_count, write_options);
      });
    };
    LoadHooks hooks;
    hooks.counted = open_output;
    hooks.vertices = [&](uint64_t, const Point* points, uint64_t n) { submit_vertices(job, *writer, points, n); };
    hooks.float_vertices = [&](uint64_t, const float* xyz, uint64_t n) { submit_float_vertices(job, *writer, xyz, n); };
    // The input as it is: re-encode keeps every vertex and face.
    LoadOptions load = LoadOptions::verbatim(options.load);
    // A PLY output's face records are kept as they will be written (blocks.hpp).
    load.ply_triangle_records = !io::mesh_file_kind(options.output).obj;
    LoadedMesh mesh = load_into_blocks(job, scratch, options.input, load, hooks);
    open_output(mesh);
    // Ended before the report is made, which reads the stage's totals.
    std::optional<StageTimer> timer(std::in_place, job, "write");
    const bool blocks_in_memory = mesh.blocks_resident();
    write_vertices(job, scratch, mesh, *writer);
    release_memory(mesh.vertices.resident);
    release_memory(mesh.vertices.resident_xyz);
    mesh.resident_lease.release();
    FaceIdOrderStats in_order;
    const bool ids_in_blocks = is_id_triangle_record(mesh.block_record_size);
    if (ids_in_blocks) {
      in_order = write_blocks_in_face_id_order(job, scratch, mesh, *writer, options.group_faces);
    }
    uint64_t faces = ids_in_blocks ? in_order.written : write_triangles(job, scratch, mesh, *writer);
    if (faces != mesh.face_count) {
      throw Error(ErrorKind::internal, "re-encode wrote " + std::to_string(faces) + " of " +
                                           std::to_string(mesh.face_count) + " triangles");
    }
    job.io().call("commit output", [&] { writer->commit(); });
    job.stage("write").bytes_written = writer->bytes_written();
    timer.reset();
    job.progress(1.0, "done");

    result.vertices = mesh.vertex_count;
    result.faces = faces;
    result.report = job_report(job, governor);
    result.report["input"] = options.input.string();
    result.report["output"] = options.output.string();
    result.report["input_vertices"] = mesh.vertex_count;
    result.report["output_vertices"] = mesh.vertex_count;
    result.report["input_faces"] = mesh.face_count;
    result.report["output_faces"] = faces;
    result.report["patches"] = 0;
    result.report["rounds"] = 0;
    result.report["blocks"] = mesh.grid.count();
    result.report["out_of_core_dereference"] = mesh.out_of_core;
    result.report["blocks_in_memory"] = blocks_in_memory;
    result.report["local_faces"] = mesh.local_faces;
    result.report["block_record_bytes"] = mesh.block_record_size;
    result.report["spanning_faces"] = mesh.corner_faces;
    result.report["block_groups"] = in_order.groups;  // out of core: buffers put in face-id order
    result.report["block_groups_merged"] = in_order.merged;  // of them: a few runs in id order, merged
    result.report["block_groups_sorted"] = in_order.sorted;  // many runs, sorted
    report_scratch(result.report, scratch);
    result.report["input_bytes"] = input_bytes;
    result.report["output_bytes"] = writer->bytes_written();
    result.summary = format_summary(result.report);
  });
  if (!options.report_path.empty()) write_json(options.report_path, result.report);
  return result;
}

}  // namespace qemflow::engine
