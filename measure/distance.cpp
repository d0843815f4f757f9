#include "measure/distance.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include "measure/bvh.hpp"
#include "measure/point_triangle.hpp"
#include "measure/surface_sampler.hpp"
#include "measure/topology.hpp"
#include "measure/vec3.hpp"
#include "util/error.hpp"

namespace qemflow::measure {
namespace {

// Faces per fixed block: partial sums are formed per block and added in block order,
// which is what makes sums independent of threads and chunking.
constexpr uint64_t kBlockFaces = 1024;
constexpr double kInfinity = std::numeric_limits<double>::infinity();
constexpr uint32_t kNoGuess = std::numeric_limits<uint32_t>::max();

struct Accumulator {
  double max = 0, face_sum = 0, face_sum2 = 0, vertex_sum = 0, vertex_sum2 = 0;
  uint64_t face_samples = 0, vertex_samples = 0;

  void add_face_sample(double d) {
    max = std::max(max, d);
    face_sum += d;
    face_sum2 += d * d;
    ++face_samples;
  }
  void add_vertex_sample(double d) {
    max = std::max(max, d);
    vertex_sum += d;
    vertex_sum2 += d * d;
    ++vertex_samples;
  }
  void merge(const Accumulator& o) {
    max = std::max(max, o.max);
    face_sum += o.face_sum;
    face_sum2 += o.face_sum2;
    vertex_sum += o.vertex_sum;
    vertex_sum2 += o.vertex_sum2;
    face_samples += o.face_samples;
    vertex_samples += o.vertex_samples;
  }
  DirectedDistance finish() const {
    DirectedDistance d;
    d.hausdorff = max;
    d.face_samples = face_samples;
    d.vertex_samples = vertex_samples;
    const bool by_area = face_samples > 0;
    const double n = static_cast<double>(by_area ? face_samples : vertex_samples);
    if (n > 0) {
      d.mean = (by_area ? face_sum : vertex_sum) / n;
      d.rms = std::sqrt((by_area ? face_sum2 : vertex_sum2) / n);
    }
    return d;
  }
};

// Runs body(block) for every block in [0, blocks), one block per task, and returns
// the per-block results in block order.
template <class Result, class Body>
std::vector<Result> for_each_block(uint64_t blocks, const Body& body) {
  std::vector<Result> results(blocks);
  tbb::parallel_for(
      tbb::blocked_range<uint64_t>(0, blocks, 1),
      [&](const tbb::blocked_range<uint64_t>& r) {
        for (uint64_t b = r.begin(); b != r.end(); ++b) results[b] = body(b);
      },
      tbb::simple_partitioner());
  return results;
}

uint64_t block_count(uint64_t faces) { return (faces + kBlockFaces - 1) / kBlockFaces; }

// Bit k of the mask: corner k is the first reference to its vertex in face order, so
// each referenced vertex is sampled exactly once.
uint8_t first_reference_mask(const Triangle& t, std::vector<bool>& seen) {
  uint8_t mask = 0;
  for (int k = 0; k < 3; ++k) {
    if (seen[t[k]]) continue;
    seen[t[k]] = true;
    mask |= uint8_t(1u << k);
  }
  return mask;
}

// B = SIMPLIFIED, in memory: its BVH, its samples' layout and their running minima.
struct SimplifiedSide {
  const Mesh& mesh;
  uint64_t seed;
  double density = 0;
  std::vector<uint8_t> vertex_mask;       // per face, see first_reference_mask
  std::vector<uint64_t> face_samples;     // per face, area samples
  std::vector<uint64_t> sample_offset;    // per face + 1: vertex samples then area samples
  std::vector<double> best_squared;       // per sample: running min over A's chunks
  std::vector<Point> normal;              // per face
  std::vector<double> centroid_best;       // distance from the centroid to the nearest A face so far
  std::vector<double> centroid_agreement;  // dot of B's normal with the unit normal of that face
  double tie_tolerance = 0;
  TriangleBvh bvh;

  SimplifiedSide(const Mesh& m, uint64_t samples, uint64_t s) : mesh(m), seed(s) {
    const auto& tris = mesh.triangles;
    const uint64_t faces = tris.size();
    std::vector<double> area(faces);
    std::vector<TriangleCorners> corners(faces);
    normal.resize(faces);
    tbb::parallel_for(uint64_t{0}, faces, [&](uint64_t f) {
      corners[f] = {mesh.points[tris[f][0]], mesh.points[tris[f][1]], mesh.points[tris[f][2]]};
      normal[f] = triangle_normal(corners[f][0], corners[f][1], corners[f][2]);
      area[f] = 0.5 * std::sqrt(squared_length(normal[f]));
    });
    double total_area = 0;
    for (const auto& partial : for_each_block<double>(block_count(faces), [&](uint64_t b) {
           double sum = 0;
           for (uint64_t f = b * kBlockFaces; f < std::min(faces, (b + 1) * kBlockFaces); ++f) sum += area[f];
           return sum;
         }))
      total_area += partial;
    density = total_area > 0 ? static_cast<double>(samples) / total_area : 0.0;

    std::vector<bool> seen(mesh.points.size(), false);
    vertex_mask.resize(faces);
    face_samples.resize(faces);
    sample_offset.resize(faces + 1);
    for (uint64_t f = 0; f < faces; ++f) {
      vertex_mask[f] = first_reference_mask(tris[f], seen);
      face_samples[f] = face_sample_count(area[f], density, seed, f);
      sample_offset[f + 1] = sample_offset[f] + std::popcount(vertex_mask[f]) + face_samples[f];
    }
    best_squared.assign(sample_offset[faces], kInfinity);
    centroid_best.assign(faces, kInfinity);
    centroid_agreement.assign(faces, 0.0);
    BoundingBox box;
    for (const Point& p : mesh.points) box.grow(p);
    tie_tolerance = 1e-9 * box.diagonal();
    bvh = TriangleBvh::build(std::move(corners));
  }

  // Calls visit(point, is_vertex_sample, sample_index) for every sample of face f.
  template <class Visit>
  void for_each_sample(uint64_t f, const Visit& visit) const {
    const Triangle& t = mesh.triangles[f];
    uint64_t s = sample_offset[f];
    for (int k = 0; k < 3; ++k)
      if (vertex_mask[f] >> k & 1) visit(mesh.points[t[k]], true, s++);
    const Point &a = mesh.points[t[0]], &b = mesh.points[t[1]], &c = mesh.points[t[2]];
    for (uint64_t k = 0; k < face_samples[f]; ++k) visit(face_sample(a, b, c, seed, f, k), false, s++);
  }

  // B->A and flips against one chunk of A's faces.
  void update(const TriangleBvh& chunk) {
    const uint64_t faces = mesh.triangles.size();
    tbb::parallel_for(
        tbb::blocked_range<uint64_t>(0, faces, 256),
        [&](const tbb::blocked_range<uint64_t>& r) {
          TriangleBvh::Hit hit;
          uint32_t guess = kNoGuess;  // the previous hit: neighbouring samples share nearest faces
          for (uint64_t f = r.begin(); f != r.end(); ++f) {
            for_each_sample(f, [&](const Point& p, bool, uint64_t s) {
              double bound = best_squared[s];
              if (guess != kNoGuess) {
                const auto& t = chunk.triangle(guess);
                bound = std::min(bound, squared_distance_point_triangle(p, t[0], t[1], t[2]));
              }
              if (chunk.nearest(p, bound, hit)) {
                best_squared[s] = hit.squared_distance;
                guess = hit.primitive;
              } else {
                best_squared[s] = bound;
              }
            });
            update_flip(chunk, f);
          }
        });
  }

  // The nearest A face to the centroid decides; faces of A within tie_tolerance of the
  // nearest distance tie, and the best-agreeing one of a tie is taken, so a face lying
  // on two coincident opposite sheets (or on an edge of A) is not called flipped.
  void update_flip(const TriangleBvh& chunk, uint64_t f) {
    if (squared_length(normal[f]) == 0) return;
    const Triangle& t = mesh.triangles[f];
    const Point centroid = (1.0 / 3.0) * (mesh.points[t[0]] + mesh.points[t[1]] + mesh.points[t[2]]);
    const double best = centroid_best[f];
    const double bound = std::isinf(best) ? kInfinity : (best + tie_tolerance) * (best + tie_tolerance);
    TriangleBvh::Hit hit;
    if (!chunk.nearest(centroid, bound, hit)) return;
    const double nearest = std::sqrt(hit.squared_distance);
    const double radius = nearest + tie_tolerance;
    double agreement = -kInfinity;
    chunk.for_each_within(centroid, radius * radius, [&](uint32_t primitive, double) {
      const auto& o = chunk.triangle(primitive);
      const Point n = triangle_normal(o[0], o[1], o[2]);
      const double length = std::sqrt(squared_length(n));
      agreement = std::max(agreement, length > 0 ? dot(normal[f], n) / length : 0.0);
    });
    if (nearest < best - tie_tolerance) {
      centroid_best[f] = nearest;
      centroid_agreement[f] = agreement;
    } else {
      centroid_best[f] = std::min(best, nearest);
      centroid_agreement[f] = std::max(centroid_agreement[f], agreement);
    }
  }

  DirectedDistance finish_b_to_a() const {
    const uint64_t faces = mesh.triangles.size();
    Accumulator total;
    for (const auto& partial : for_each_block<Accumulator>(block_count(faces), [&](uint64_t b) {
           Accumulator acc;
           for (uint64_t f = b * kBlockFaces; f < std::min(faces, (b + 1) * kBlockFaces); ++f)
             for_each_sample(f, [&](const Point&, bool is_vertex, uint64_t s) {
               const double d = std::sqrt(best_squared[s]);
               is_vertex ? acc.add_vertex_sample(d) : acc.add_face_sample(d);
             });
           return acc;
         }))
      total.merge(partial);
    return total.finish();
  }

  uint64_t flipped_faces() const {
    uint64_t flipped = 0;
    for (double d : centroid_agreement) flipped += d < 0;
    return flipped;
  }
};

// A = ORIGINAL, streamed: positions so far, which vertices were sampled, and the
// A->B accumulator that blocks are merged into in global block order.
struct OriginalSide {
  uint64_t seed;
  double density;
  PositionStore positions;
  BoundingBox bbox;
  std::vector<bool> seen;
  Accumulator a_to_b;
  uint64_t faces = 0;

  void add_vertices(std::span<const Point> points) {
    positions.append(points);
    for (const Point& p : points) bbox.grow(p);
  }

  // `chunk` holds faces first .. first+size-1; first is a multiple of kBlockFaces.
  void process_chunk(uint64_t first, const std::vector<Triangle>& chunk, SimplifiedSide& simplified) {
    const uint64_t n = chunk.size();
    faces = first + n;
    seen.resize(positions.size(), false);
    std::vector<uint8_t> mask(n);
    for (uint64_t i = 0; i < n; ++i) mask[i] = first_reference_mask(chunk[i], seen);

    std::vector<TriangleCorners> corners(n);
    tbb::parallel_for(uint64_t{0}, n, [&](uint64_t i) {
      corners[i] = {positions[chunk[i][0]], positions[chunk[i][1]], positions[chunk[i][2]]};
    });

    // A->B: this chunk's samples against B's tree.
    const TriangleBvh& target = simplified.bvh;
    for (const auto& partial : for_each_block<Accumulator>(block_count(n), [&](uint64_t b) {
           Accumulator acc;
           TriangleBvh::Hit hit;
           // Warm start from the previous hit: the minimum is the same, found faster.
           auto distance = [&](const Point& p) {
             if (hit.primitive == kNoGuess) target.nearest(p, hit);
             else target.nearest_from(p, hit.primitive, hit);
             return std::sqrt(hit.squared_distance);
           };
           hit.primitive = kNoGuess;
           for (uint64_t i = b * kBlockFaces; i < std::min(n, (b + 1) * kBlockFaces); ++i) {
             const auto& [pa, pb, pc] = corners[i];
             for (int k = 0; k < 3; ++k)
               if (mask[i] >> k & 1) acc.add_vertex_sample(distance(corners[i][k]));
             const uint64_t face = first + i;
             const uint64_t count = face_sample_count(triangle_area(pa, pb, pc), density, seed, face);
             for (uint64_t k = 0; k < count; ++k) acc.add_face_sample(distance(face_sample(pa, pb, pc, seed, face, k)));
           }
           return acc;
         }))
      a_to_b.merge(partial);

    // B->A: B's samples against this chunk's tree.
    std::vector<uint64_t> ids(n);
    for (uint64_t i = 0; i < n; ++i) ids[i] = first + i;
    const TriangleBvh chunk_tree = TriangleBvh::build(std::move(corners), std::move(ids));
    simplified.update(chunk_tree);
  }
};

}  // namespace

uint64_t default_sample_count(uint64_t simplified_faces) {
  return std::max<uint64_t>(1'000'000, 10 * simplified_faces);
}

DistanceReport compare_streamed(const MeshSource& original, const Mesh& simplified, const CompareOptions& options,
                                const std::string& simplified_name) {
  if (simplified.triangles.empty()) throw_bad_input(simplified_name, "end", "mesh has no triangles");
  for (uint64_t f = 0; f < simplified.triangles.size(); ++f)
    for (uint64_t v : simplified.triangles[f])
      if (v >= simplified.points.size())
        throw_bad_input(simplified_name, "face " + std::to_string(f), "vertex index out of range");
  const uint64_t samples = options.samples ? options.samples : default_sample_count(simplified.triangles.size());
  const uint64_t chunk_faces =
      std::max<uint64_t>(1, (options.chunk_faces + kBlockFaces - 1) / kBlockFaces) * kBlockFaces;

  SimplifiedSide b_side(simplified, samples, options.seed);
  OriginalSide a_side{options.seed, b_side.density, {}, {}, {}, {}, 0};

  std::vector<Triangle> chunk;
  chunk.reserve(std::min<uint64_t>(chunk_faces, original.triangle_count_hint().value_or(chunk_faces)));
  uint64_t chunk_first = 0;
  MeshScan scan;
  scan.on_vertices = [&](uint64_t, std::span<const Point> points) { a_side.add_vertices(points); };
  scan.on_triangles = [&](uint64_t, std::span<const Triangle> triangles) {
    while (!triangles.empty()) {
      const uint64_t take = std::min<uint64_t>(triangles.size(), chunk_faces - chunk.size());
      chunk.insert(chunk.end(), triangles.begin(), triangles.begin() + take);
      triangles = triangles.subspan(take);
      if (chunk.size() == chunk_faces) {
        a_side.process_chunk(chunk_first, chunk, b_side);
        chunk_first += chunk.size();
        chunk.clear();
      }
    }
  };
  original.scan(scan);
  if (!chunk.empty()) a_side.process_chunk(chunk_first, chunk, b_side);
  if (a_side.faces == 0) throw_bad_input(original.name(), "end", "mesh has no triangles");

  DistanceReport report;
  report.a_to_b = a_side.a_to_b.finish();
  report.b_to_a = b_side.finish_b_to_a();
  report.hausdorff = std::max(report.a_to_b.hausdorff, report.b_to_a.hausdorff);
  report.mean = std::max(report.a_to_b.mean, report.b_to_a.mean);
  report.rms = std::max(report.a_to_b.rms, report.b_to_a.rms);
  report.bbox_diagonal = a_side.bbox.diagonal();
  report.sample_density = b_side.density;
  report.flipped_faces = b_side.flipped_faces();
  return report;
}

DistanceReport compare_meshes(const std::vector<Point>& original_points,
                              const std::vector<Triangle>& original_triangles,
                              const std::vector<Point>& simplified_points,
                              const std::vector<Triangle>& simplified_triangles, const CompareOptions& options) {
  const auto original = memory_mesh_source(original_points, original_triangles, "<original mesh>");
  // The simplified mesh is small by assumption; one copy keeps a single code path.
  const Mesh simplified{simplified_points, simplified_triangles};
  return compare_streamed(*original, simplified, options);
}

}  // namespace qemflow::measure
