#pragma once
// Metro-style surface distances (Cignoni, Rocchini, Scopigno 1998) between
// A = ORIGINAL and B = SIMPLIFIED, plus the flipped-face count of B against A.
//
// What is measured:
// - Samples on each surface: every referenced vertex once, plus area-weighted face
//   samples at one density rho = N / area(B) on both meshes (N = options.samples, or
//   default_sample_count()). A gets about N * area(A) / area(B) face samples; using
//   B's density lets A be sampled in the same single streamed pass that reads it.
//   Samples are counter-based hashes of (seed, face id, k): see surface_sampler.hpp.
// - Each sample's distance to the other surface is exact (closest point on triangle
//   through a TriangleBvh). Hausdorff = max over all samples (vertices sharpen it);
//   mean and RMS = over the face samples only, so they estimate the area integrals
//   (1/|S| int d and sqrt(1/|S| int d^2)); a mesh with zero area falls back to its
//   vertex samples. The symmetric value of each is the max of the two directions.
//   Relative values divide by the bounding-box diagonal of A (all its vertices).
// - flipped_faces: faces of B whose normal points against the normal of the face of
//   A nearest to B's face centroid (dot < 0); zero-area faces are never flipped.
//
// Determinism: results are bit-identical for any thread count and any chunk_faces
// (sums are taken per fixed block of 1024 global face ids and added in block order;
// minima and maxima do not depend on order).
//
// Streaming (compare_streamed): B is in memory (its BVH is built once). A is read once:
// A->B samples are generated per face as A streams by; for B->A, A's faces are cut
// into chunks of chunk_faces, a BVH per chunk updates each B sample's running minimum
// (8 B per B sample). Memory growing with A: its vertex positions (12 B per vertex for
// float coordinates, 24 B otherwise) and one bit per vertex; the rest is bounded by
// chunk_faces (about 180 B per face of chunk).
#include <cstdint>
#include <string>
#include <vector>

#include "measure/mesh_source.hpp"
#include "util/geometry.hpp"

namespace qemflow::measure {

struct CompareOptions {
  uint64_t samples = 0;  // face samples on B; 0 = default_sample_count(faces of B)
  uint64_t seed = 0x5eedf00dULL;
  uint64_t chunk_faces = uint64_t{1} << 21;  // rounded up to a multiple of 1024
};

// max(1,000,000, 10 x faces of B): Metro's 10 samples per face, with a floor that keeps
// small simplified meshes well sampled.
uint64_t default_sample_count(uint64_t simplified_faces);

struct DirectedDistance {
  double hausdorff = 0, mean = 0, rms = 0;
  uint64_t vertex_samples = 0, face_samples = 0;
};

struct DistanceReport {
  DirectedDistance a_to_b, b_to_a;
  double hausdorff = 0, mean = 0, rms = 0;  // symmetric: max of the two directions
  double bbox_diagonal = 0;                 // of A
  double sample_density = 0;                // face samples per unit area
  uint64_t flipped_faces = 0;
  // absolute / bbox_diagonal (0 when the diagonal is 0).
  double relative(double absolute) const { return bbox_diagonal > 0 ? absolute / bbox_diagonal : 0.0; }
};

// In-memory meshes. Indices must be in range; a mesh without triangles is an error.
DistanceReport compare_meshes(const std::vector<Point>& original_points,
                              const std::vector<Triangle>& original_triangles,
                              const std::vector<Point>& simplified_points,
                              const std::vector<Triangle>& simplified_triangles,
                              const CompareOptions& options = {});

// ORIGINAL streamed from any source (one scan), SIMPLIFIED in memory.
// `simplified_name` names B in error messages.
DistanceReport compare_streamed(const MeshSource& original, const Mesh& simplified,
                                const CompareOptions& options = {},
                                const std::string& simplified_name = "<simplified mesh>");

}  // namespace qemflow::measure
