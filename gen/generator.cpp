#include "gen/generator.hpp"

#include <tbb/concurrent_queue.h>
#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>

#include "gen/noise.hpp"
#include "gen/surfaces.hpp"
#include "util/error.hpp"

namespace qemflow::gen {
namespace {

using detail::CentreSpread;
using detail::Surface;
using io::IndexedMesh;

struct ShapeKind {
  const char* name;
  uint64_t (*quads)(uint64_t m);
  std::unique_ptr<Surface> (*make)(uint64_t m, uint64_t seed);
  uint64_t smallest_m;
};

const ShapeKind kShapes[] = {
    {"blob", detail::blob_quads, detail::make_blob, 2},
    {"terrain", detail::terrain_quads, detail::make_terrain, 3},
    {"figure", detail::figure_quads, detail::make_figure, 3},
};

std::string shape_list() {
  std::string list;
  for (const auto& name : shape_names()) list += (list.empty() ? "" : ", ") + name;
  return list;
}

const ShapeKind& shape_kind(const std::string& name) {
  for (const auto& kind : kShapes)
    if (name == kind.name) return kind;
  throw Error(ErrorKind::usage, "unknown shape '" + name + "' (shapes: " + shape_list() + ")");
}

// A surface sized for the request: the largest grid whose 2 triangles per quad fit,
// and as many quads with a centre vertex (2 extra triangles each) as make up the rest.
struct Fitted {
  std::unique_ptr<Surface> surface;
  CentreSpread centres;
  uint64_t vertex_count = 0, face_count = 0;
};

Fitted fit(const GenOptions& options) {
  const ShapeKind& kind = shape_kind(options.shape);
  if (options.faces < minimum_faces)
    throw Error(ErrorKind::usage, "--faces " + std::to_string(options.faces) + " is too small: shape '" +
                                      options.shape + "' needs at least " + std::to_string(minimum_faces));
  if (options.faces > maximum_faces)
    throw Error(ErrorKind::usage, "--faces " + std::to_string(options.faces) + " is too large: at most " +
                                      std::to_string(maximum_faces));
  const uint64_t target_quads = (options.faces + 1) / 2;  // triangles / 2, rounded up to even faces
  uint64_t lo = kind.smallest_m, hi = uint64_t{1} << 22;   // quads(lo) <= target < quads(hi)
  while (hi - lo > 1) {
    const uint64_t mid = lo + (hi - lo) / 2;
    (kind.quads(mid) <= target_quads ? lo : hi) = mid;
  }
  Fitted fitted;
  fitted.surface = kind.make(lo, options.seed);
  const uint64_t quads = fitted.surface->quad_count();
  if (quads > target_quads || target_quads - quads > quads)
    throw Error(ErrorKind::internal, "gen: cannot fit " + std::to_string(options.faces) + " faces");
  fitted.centres = {quads, target_quads - quads};
  fitted.vertex_count = fitted.surface->lattice_vertex_count() + fitted.centres.extra;
  fitted.face_count = 2 * target_quads;
  return fitted;
}

// One unit of work: a run of lattice-vertex rows, of centre vertices, or of quad rows.
struct Chunk {
  enum Kind { lattice, centres, quads } kind = lattice;
  uint64_t begin = 0, end = 0;
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};

constexpr uint64_t kChunkElements = 16384;

class Generator {
 public:
  Generator(const Fitted& fitted, uint64_t seed)
      : surface_(*fitted.surface), centres_(fitted.centres), diagonal_seed_(noise::derive(seed, 1000)) {}

  // Serial: the next chunk in output order, or false when all are handed out.
  bool next(Chunk& chunk) {
    const Surface& s = surface_;
    if (phase_ == Chunk::lattice && cursor_ == s.vertex_rows()) advance(Chunk::centres);
    if (phase_ == Chunk::centres && cursor_ == centres_.extra) advance(Chunk::quads);
    if (phase_ == Chunk::quads && cursor_ == s.quad_rows()) return false;
    chunk.kind = phase_;
    chunk.begin = cursor_;
    if (phase_ == Chunk::centres) {
      cursor_ = std::min(centres_.extra, cursor_ + kChunkElements);
    } else {
      auto first = [&](uint64_t row) {
        return phase_ == Chunk::lattice ? s.vertex_row_first(row) : s.quad_row_first(row);
      };
      const uint64_t rows = phase_ == Chunk::lattice ? s.vertex_rows() : s.quad_rows();
      const uint64_t start = first(cursor_);
      do ++cursor_;
      while (cursor_ < rows && first(cursor_) - start < kChunkElements / 2);
    }
    chunk.end = cursor_;
    return true;
  }

  // Parallel: computes a chunk's elements from their ids alone.
  void fill(Chunk& chunk) const {
    const Surface& s = surface_;
    switch (chunk.kind) {
      case Chunk::lattice: {
        const uint64_t first = s.vertex_row_first(chunk.begin);
        chunk.points.resize(s.vertex_row_first(chunk.end) - first);
        for (uint64_t row = chunk.begin; row < chunk.end; ++row)
          s.vertex_row(row, chunk.points.data() + (s.vertex_row_first(row) - first));
        break;
      }
      case Chunk::centres: {
        chunk.points.resize(chunk.end - chunk.begin);
        const uint64_t first_id = s.lattice_vertex_count();
        for (uint64_t c = chunk.begin; c < chunk.end; ++c)
          chunk.points[c - chunk.begin] = s.quad_centre(centres_.quad_of(c), first_id + c);
        break;
      }
      case Chunk::quads: {
        const uint64_t q0 = s.quad_row_first(chunk.begin), q1 = s.quad_row_first(chunk.end);
        chunk.triangles.resize(2 * (q1 - q0) + 2 * (centres_.before(q1) - centres_.before(q0)));
        Triangle* out = chunk.triangles.data();
        for (uint64_t q = q0; q < q1; ++q) out = triangulate(q, out);
        break;
      }
    }
  }

 private:
  void advance(Chunk::Kind phase) {
    phase_ = phase;
    cursor_ = 0;
  }

  // A quad becomes a fan around its centre vertex, or two triangles split along a
  // diagonal picked by hash, so the triangulation is irregular like a scan's.
  Triangle* triangulate(uint64_t quad, Triangle* out) const {
    uint64_t c[4];
    surface_.quad_corners(quad, c);
    if (centres_.has(quad)) {
      const uint64_t m = surface_.lattice_vertex_count() + centres_.before(quad);
      *out++ = {c[0], c[1], m};
      *out++ = {c[1], c[2], m};
      *out++ = {c[2], c[3], m};
      *out++ = {c[3], c[0], m};
    } else if (noise::hash(diagonal_seed_, static_cast<int64_t>(quad)) & 1) {
      *out++ = {c[0], c[1], c[2]};
      *out++ = {c[0], c[2], c[3]};
    } else {
      *out++ = {c[0], c[1], c[3]};
      *out++ = {c[1], c[2], c[3]};
    }
    return out;
  }

  const Surface& surface_;
  CentreSpread centres_;
  uint64_t diagonal_seed_;
  Chunk::Kind phase_ = Chunk::lattice;
  uint64_t cursor_ = 0;
};

class MemorySink final : public MeshSink {
 public:
  explicit MemorySink(IndexedMesh& mesh) : mesh_(mesh) {}
  void begin(uint64_t vertex_count, uint64_t triangle_count) override {
    mesh_.vertices.reserve(vertex_count);
    mesh_.triangles.reserve(triangle_count);
  }
  void vertices(const Point* points, size_t count) override {
    mesh_.vertices.insert(mesh_.vertices.end(), points, points + count);
  }
  void triangles(const Triangle* triangles, size_t count) override {
    mesh_.triangles.insert(mesh_.triangles.end(), triangles, triangles + count);
  }

 private:
  IndexedMesh& mesh_;
};

}  // namespace

const std::vector<std::string>& shape_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> list;
    for (const auto& kind : kShapes) list.emplace_back(kind.name);
    return list;
  }();
  return names;
}

GenPlan plan(const GenOptions& options) {
  const Fitted fitted = fit(options);
  GenPlan result;
  result.shape = options.shape;
  result.vertex_count = fitted.vertex_count;
  result.face_count = fitted.face_count;
  result.euler_characteristic = fitted.surface->euler_characteristic();
  result.layout = fitted.surface->layout();
  if (fitted.centres.extra) result.layout += " + " + std::to_string(fitted.centres.extra) + " quad centres";
  return result;
}

void generate(const GenOptions& options, MeshSink& sink) {
  const Fitted fitted = fit(options);
  sink.begin(fitted.vertex_count, fitted.face_count);
  Generator generator(fitted, options.seed);
  // Chunks are recycled so their buffers are allocated once per token.
  const size_t tokens = 2 * static_cast<size_t>(tbb::this_task_arena::max_concurrency()) + 2;
  std::vector<std::unique_ptr<Chunk>> pool;
  tbb::concurrent_queue<Chunk*> free_chunks;
  for (size_t t = 0; t < tokens; ++t) {
    pool.push_back(std::make_unique<Chunk>());
    free_chunks.push(pool.back().get());
  }
  tbb::parallel_pipeline(
      tokens,
      tbb::make_filter<void, Chunk*>(tbb::filter_mode::serial_in_order,
                                     [&](tbb::flow_control& control) -> Chunk* {
                                       Chunk* chunk = nullptr;
                                       free_chunks.try_pop(chunk);  // never empty: one per token
                                       if (!generator.next(*chunk)) {
                                         free_chunks.push(chunk);
                                         control.stop();
                                         return nullptr;
                                       }
                                       return chunk;
                                     }) &
          tbb::make_filter<Chunk*, Chunk*>(tbb::filter_mode::parallel,
                                           [&](Chunk* chunk) {
                                             generator.fill(*chunk);
                                             return chunk;
                                           }) &
          tbb::make_filter<Chunk*, void>(tbb::filter_mode::serial_in_order, [&](Chunk* chunk) {
            if (chunk->kind == Chunk::quads) sink.triangles(chunk->triangles.data(), chunk->triangles.size());
            else sink.vertices(chunk->points.data(), chunk->points.size());
            free_chunks.push(chunk);
          }));
}

IndexedMesh generate_in_memory(const GenOptions& options) {
  IndexedMesh mesh;
  MemorySink sink(mesh);
  generate(options, sink);
  return mesh;
}

uint64_t parse_face_count(std::string_view text) {
  auto fail = [&](const char* why) -> uint64_t {
    throw Error(ErrorKind::usage, "invalid face count '" + std::string(text) + "': " + why +
                                      " (examples: 100000, 2M, 1.5M, 1G; K/M/G are 1e3/1e6/1e9)");
  };
  size_t digits = 0;
  while (digits < text.size() && (std::isdigit(static_cast<unsigned char>(text[digits])) || text[digits] == '.'))
    ++digits;
  if (digits == 0) return fail("expected a number");
  const std::string_view unit = text.substr(digits);
  double scale = 1;
  if (unit.size() > 1) return fail("unknown suffix");
  if (unit.size() == 1) {
    switch (std::toupper(static_cast<unsigned char>(unit[0]))) {
      case 'K': scale = 1e3; break;
      case 'M': scale = 1e6; break;
      case 'G': scale = 1e9; break;
      default: return fail("unknown suffix");
    }
  }
  const std::string_view number = text.substr(0, digits);
  if (number.find('.') == std::string_view::npos) {
    uint64_t value = 0;
    auto [end, ec] = std::from_chars(number.data(), number.data() + number.size(), value);
    if (ec != std::errc() || end != number.data() + number.size()) return fail("out of range");
    const auto factor = static_cast<uint64_t>(scale);
    if (value != 0 && factor > UINT64_MAX / value) return fail("out of range");
    return value * factor;
  }
  double value = 0;
  auto [end, ec] = std::from_chars(number.data(), number.data() + number.size(), value);
  if (ec != std::errc() || end != number.data() + number.size()) return fail("expected a number");
  const double faces = std::round(value * scale);
  if (!(faces >= 0) || faces > 1.8e19) return fail("out of range");
  return static_cast<uint64_t>(faces);
}

}  // namespace qemflow::gen
