#pragma once
// Streaming mesh access. Readers hand out vertices and triangles in bounded batches
// and never hold a whole file (one 4 MiB buffer plus the caller's batch); writers
// accept them in batches and publish the file only on commit(). Formats: PLY
// (ascii, binary LE/BE), OBJ, each optionally .zst, chosen by file name
// (".ply", ".obj", then optionally ".zst", case-insensitive; any other name is
// Error(usage)). For PLY the header decides ascii/binary.
//
// Errors: malformed input is Error(bad_input) with one line "FILE: PLACE: PROBLEM",
// PLACE being "byte N" (binary PLY; for .zst, N counts decompressed bytes),
// "line N" (PLY header, ascii PLY, OBJ) or "cannot open". Output that cannot be
// written is Error(resource) naming the file; writer misuse is Error(internal).
// Small meshes: io/indexed_mesh.hpp (read_mesh / write_mesh). Scratch chunks:
// io/chunk_file.hpp.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "util/geometry.hpp"

namespace qemflow::io {

enum class MeshFormat { ply_ascii, ply_binary_le, ply_binary_be, obj };
std::string to_string(MeshFormat format);

struct MeshInfo {
  MeshFormat format = MeshFormat::ply_binary_le;
  bool zstd = false;
  std::optional<uint64_t> vertex_count;   // known up front for PLY, not for OBJ
  std::optional<uint64_t> polygon_count;  // PLY face element count; triangles may be more
  uint64_t file_size = 0;                 // bytes on disk (compressed size for .zst)
};

// One batch of a stream. Vertices and triangles arrive in file order; a triangle's
// indices refer to vertices of earlier or the same batch (OBJ interleaves them; PLY
// sends every vertex before the first triangle). Polygons are fan-triangulated, so
// the global face id of a triangle is its position in the triangle stream.
struct MeshBatch {
  uint64_t first_vertex = 0;    // global index of vertices[0]
  uint64_t first_triangle = 0;  // global id of triangles[0]
  std::vector<Point> vertices;
  std::vector<Triangle> triangles;
  void clear() { vertices.clear(); triangles.clear(); }
};

class MeshReader {
 public:
  virtual ~MeshReader() = default;
  virtual const MeshInfo& info() const = 0;
  // Fills `batch` with up to about `max_elements` vertices plus triangles (a
  // polygon's fan may be cut between batches, so a polygon of millions of vertices
  // costs no more than a batch; a batch may exceed it by a polygon of fewer than
  // ply_binary::streamed_polygon_vertices, read whole);
  // returns false once the stream is exhausted (batch then empty). Every index is
  // checked (< vertex count, PLY; already defined, OBJ), every coordinate finite.
  // Throws Error(bad_input) naming file, byte offset or line, and problem.
  virtual bool next(MeshBatch& batch, size_t max_elements = 1 << 16) = 0;
  // Bytes consumed from the (possibly compressed) file so far, for progress.
  virtual uint64_t bytes_read() const = 0;
};

std::unique_ptr<MeshReader> open_mesh_reader(const std::filesystem::path& path);

struct WriteOptions {
  bool double_precision = false;  // PLY vertex type: float (default) or double;
                                  // OBJ: shortest text that rereads as the same float / double
  int zstd_level = 3;             // for .zst outputs
};

// Counts are declared up front (PLY headers need them). Vertices must all be written
// before triangles for PLY; OBJ may interleave, a face naming only vertices already
// written. Output goes to "PATH.tmp-<pid>-<random>" beside PATH and is renamed into
// place by commit(), which checks the declared counts (mismatch: Error(internal)).
// Destroying a writer without commit() removes its temporary file, so no
// half-written output is ever left at `path` (an existing file there is untouched).
// PLY output: binary little-endian, float or double xyz, "list uchar int" faces
// ("uint" above 2^31 vertices).
class MeshWriter {
 public:
  virtual ~MeshWriter() = default;
  virtual void write_vertices(const Point* points, size_t count) = 0;
  virtual void write_triangles(const Triangle* triangles, size_t count) = 0;
  virtual void commit() = 0;
  virtual uint64_t bytes_written() const = 0;
  // Pre-encoded body bytes, for callers that encode on their own threads so that
  // the writing thread only moves bytes: `count` records made by io/ply_bulk.hpp's
  // encode_ply_vertices (float or double as ply_vertex_double() says) or
  // encode_ply_triangles (max_index: the largest index among them). Binary PLY
  // writers only: ply_vertex_double() is nullopt for the others, whose
  // write_encoded_* throw Error(internal). Same counts and checks as write_*.
  virtual std::optional<bool> ply_vertex_double() const { return std::nullopt; }
  virtual void write_encoded_vertices(const char* bytes, size_t count);
  virtual void write_encoded_triangles(const char* bytes, size_t count, uint64_t max_index);
};

std::unique_ptr<MeshWriter> open_mesh_writer(const std::filesystem::path& path,
                                             uint64_t vertex_count, uint64_t triangle_count,
                                             const WriteOptions& options = {});

}  // namespace qemflow::io
