#pragma once
// Synthetic scan-like meshes of any size, for the demo, the tests and the benchmarks.
//
// Contract:
// - Every mesh is closed (no boundary edge), 2-manifold (each edge in exactly two faces,
//   each vertex's faces one cycle), consistently oriented (outward), has no zero-area
//   face and no two vertices at one position. blob and terrain are spheres
//   topologically (Euler characteristic 2); figure has one handle (genus 1, Euler 0).
// - The face count is exactly `faces` rounded up to an even number (a closed triangle
//   mesh always has an even face count); counts are known before anything is made.
// - Output is a pure function of (shape, faces, seed): byte-identical on every run and
//   with any number of threads (vertices and faces are computed from their indices
//   alone; batches are handed to the sink in order).
// - Memory is bounded (a few batches of about 16k elements in flight), whatever `faces`.
// - Errors: Error(usage) for an unknown shape or a face count outside
//   [minimum_faces, maximum_faces]; the message lists the shapes / names the limit.
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "io/indexed_mesh.hpp"
#include "util/geometry.hpp"

namespace qemflow::gen {

struct GenOptions {
  std::string shape = "blob";  // one of shape_names()
  uint64_t faces = 0;          // requested triangle count
  uint64_t seed = 1;
};

inline constexpr uint64_t minimum_faces = 200;
inline constexpr uint64_t maximum_faces = 100'000'000'000ULL;

// "blob", "terrain", "figure".
const std::vector<std::string>& shape_names();

// What `generate` will make, computed without making it.
struct GenPlan {
  std::string shape;
  uint64_t vertex_count = 0;
  uint64_t face_count = 0;
  int euler_characteristic = 2;  // V - E + F
  std::string layout;            // e.g. "cube-sphere 6x40x40 grids + 12 quad centres"
};
GenPlan plan(const GenOptions& options);

// Receives the mesh as a stream: begin() once, then every vertex batch in index order,
// then every triangle batch in face order. Calls never overlap (one at a time), though
// they may come from different threads.
class MeshSink {
 public:
  virtual ~MeshSink() = default;
  virtual void begin(uint64_t vertex_count, uint64_t triangle_count) = 0;
  virtual void vertices(const Point* points, size_t count) = 0;
  virtual void triangles(const Triangle* triangles, size_t count) = 0;
};

// Streams the mesh into `sink`, using the current TBB arena's threads.
void generate(const GenOptions& options, MeshSink& sink);

// The whole mesh in memory (io's IndexedMesh, so io::write_mesh takes it as is); for
// tests and examples with small meshes.
io::IndexedMesh generate_in_memory(const GenOptions& options);

// The same surface with its vertices and its faces each in an order drawn from `seed`
// (a pure function of the mesh and the seed): an input without locality, whose face
// stream jumps across the whole mesh (what a scanner's merged or re-indexed output can
// look like), for the tests of what such an order costs out of core.
void shuffle(io::IndexedMesh& mesh, uint64_t seed);

// Streams the mesh to a file through io::open_mesh_writer (format by extension:
// .ply binary, .obj, optionally .zst); the file appears only when complete.
struct GenStats {
  uint64_t vertex_count = 0;
  uint64_t face_count = 0;
  uint64_t bytes_written = 0;
  double seconds = 0;
};
GenStats generate_to_file(const GenOptions& options, const std::filesystem::path& path);

// Face counts as users write them: "300000", "2M", "1.5M", "300M", "1G" — decimal
// multiples (K = 1e3, M = 1e6, G = 1e9), case-insensitive. Throws Error(usage).
uint64_t parse_face_count(std::string_view text);

}  // namespace qemflow::gen
