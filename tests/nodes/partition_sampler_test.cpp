// Poisson-disk sampler and proximity graph (nodes/partition): spacing, coverage, cap,
// independence from batch order, sheet separation, graph symmetry.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>

#include "nodes/partition/counter_hash.hpp"
#include "nodes/partition/partition_budget.hpp"
#include "nodes/partition/proximity_graph.hpp"
#include "nodes/partition/surface_sampler.hpp"
#include "nodes/partition_test_surfaces.hpp"

namespace qemflow::nodes::partition {
namespace {

bool same_samples(const SampleSet& a, const SampleSet& b) {
  if (a.radius != b.radius || a.samples.size() != b.samples.size()) return false;
  for (size_t i = 0; i < a.samples.size(); ++i)
    if (a.samples[i].position != b.samples[i].position || a.samples[i].normal != b.samples[i].normal ||
        a.samples[i].face_id != b.samples[i].face_id)
      return false;
  return true;
}

// Faces in a hash-shuffled order.
std::vector<PositionedFace> shuffled(std::vector<PositionedFace> faces, uint64_t seed) {
  std::sort(faces.begin(), faces.end(), [&](const PositionedFace& a, const PositionedFace& b) {
    return counter_hash(seed, a.id, 0) < counter_hash(seed, b.id, 0);
  });
  return faces;
}

TEST(PartitionSampler, AreaSumIsExactInAnyOrder) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(5));
  SurfaceAreaSum forward;
  forward.add_faces(faces);
  const auto mixed = shuffled(faces, 7);
  SurfaceAreaSum first_half, second_half;
  first_half.add_faces(std::span(mixed).first(mixed.size() / 3));
  second_half.add_faces(std::span(mixed).subspan(mixed.size() / 3));
  second_half.merge(first_half);
  EXPECT_EQ(forward.total(), second_half.total());
  EXPECT_NEAR(forward.total(), 4 * std::numbers::pi, 0.01 * 4 * std::numbers::pi);
}

TEST(PartitionSampler, SameSamplesWhateverTheBatchOrder) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(5, 0.15));
  SamplerOptions options;
  options.radius = 0.08;
  options.seed = 3;
  SurfaceSampler in_order(options);
  in_order.add_faces(faces);
  const SampleSet reference = in_order.finish();
  ASSERT_GT(reference.samples.size(), 500u);

  const auto mixed = shuffled(faces, 11);
  SurfaceSampler left(options), right(options);
  size_t at = 0;
  for (size_t batch = 1; at < mixed.size(); batch = batch * 3 % 1000 + 1) {  // uneven batches
    const size_t n = std::min(batch, mixed.size() - at);
    (at % 2 ? left : right).add_faces(std::span(mixed).subspan(at, n));
    at += n;
  }
  right.merge(std::move(left));
  EXPECT_TRUE(same_samples(reference, right.finish()));

  options.seed = 4;  // the seed does matter
  SurfaceSampler other_seed(options);
  other_seed.add_faces(faces);
  EXPECT_FALSE(same_samples(reference, other_seed.finish()));
}

TEST(PartitionSampler, SamplesAreSpacedAndCoverTheSurface) {
  const auto surface = shapes::icosphere(5, 0.15);
  const auto faces = shapes::positioned_faces(surface);
  const SampleSet set = sample_faces(faces, 1500, 1);
  const auto& s = set.samples;
  const double r = set.radius;
  // Spacing: no two samples closer than r in approximate geodesic distance.
  size_t closest_pairs = 0;
  for (size_t i = 0; i < s.size(); ++i)
    for (size_t j = i + 1; j < s.size(); ++j)
      if (approx_geodesic(s[i].position, s[i].normal, s[j].position, s[j].normal, {}) < r) ++closest_pairs;
  EXPECT_EQ(closest_pairs, 0u);
  // Count near the target the radius was chosen for.
  EXPECT_GT(s.size(), 1500 * 0.75);
  EXPECT_LT(s.size(), 1500 * 1.25);
  // Coverage (near-maximal sampling): every vertex has a sample within 1.5 r, and
  // nearly all within r.
  size_t within_r = 0;
  double worst = 0;
  for (const auto& v : surface.vertices) {
    double nearest = INFINITY;
    for (const auto& sample : s) nearest = std::min(nearest, squared_distance(v, sample.position));
    nearest = std::sqrt(nearest);
    worst = std::max(worst, nearest);
    within_r += nearest < r;
  }
  EXPECT_LT(worst, 1.5 * r);
  EXPECT_GT(static_cast<double>(within_r) / surface.vertices.size(), 0.97);
  // Normals are unit and samples lie on their faces' planes.
  for (const auto& sample : s) {
    EXPECT_NEAR(norm(sample.normal), 1.0, 1e-6);
    const auto& f = faces[sample.face_id];
    EXPECT_NEAR(dot(sub(sample.position, f.corners[0]), sample.normal), 0.0, 1e-6);
  }
}

TEST(PartitionSampler, CapGrowsTheRadius) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(4));
  SamplerOptions options;
  options.radius = 0.05;
  SurfaceSampler free_sampler(options);
  free_sampler.add_faces(faces);
  const size_t natural = free_sampler.finish().samples.size();
  options.max_samples = natural / 3;
  SurfaceSampler capped(options);
  capped.add_faces(faces);
  const SampleSet set = capped.finish();
  EXPECT_LE(set.samples.size(), natural / 3);
  EXPECT_GT(set.samples.size(), natural / 6);
  EXPECT_GT(set.radius, options.radius);
}

// A pancake (ellipsoid 1 × 1 × 0.02): top and bottom sheets closer than the radius.
TEST(PartitionSampler, ThinShapesGetBothSheetsAndNoCrossEdges) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(5, 0.0, {1, 1, 0.02}));
  const SampleSet set = sample_faces(faces, 800, 2);
  ASSERT_GT(set.radius, 0.04);
  size_t top = 0, bottom = 0;
  for (const auto& sample : set.samples) {
    top += sample.normal[2] > 0.9;
    bottom += sample.normal[2] < -0.9;
  }
  EXPECT_GT(top, set.samples.size() / 3);
  EXPECT_GT(bottom, set.samples.size() / 3);
  const ProximityGraph graph = build_proximity_graph(set.samples, set.radius);
  size_t cross = 0;
  for (uint32_t i = 0; i < graph.size(); ++i)
    for (uint32_t j : graph.neighbours_of(i)) cross += set.samples[i].normal[2] * set.samples[j].normal[2] < -0.8;
  EXPECT_EQ(cross, 0u);
}

TEST(PartitionGraph, ApproximateGeodesicIsExactOnACircle) {
  for (double angle : {0.1, 0.5, 1.0, 2.0}) {
    const Point p{1, 0, 0}, q{std::cos(angle), std::sin(angle), 0};
    EXPECT_NEAR(approx_geodesic(p, p, q, q, {}), angle, 1e-9) << angle;
    EXPECT_EQ(approx_geodesic(p, p, q, q, {}), approx_geodesic(q, q, p, p, {}));
  }
  // Opposite normals: another sheet.
  EXPECT_TRUE(std::isinf(approx_geodesic({0, 0, 0}, {0, 0, 1}, {0.01, 0, 0.001}, {0, 0, -1}, {})));
  // Parallel sheets stacked along their normal: the chord leaves the tangent plane.
  EXPECT_TRUE(std::isinf(approx_geodesic({0, 0, 0}, {0, 0, 1}, {0.01, 0, 0.1}, {0, 0, 1}, {})));
}

TEST(PartitionGraph, SymmetricSortedAndConnectedOnASphere) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(5, 0.15));
  const SampleSet set = sample_faces(faces, 2000, 5);
  const ProximityGraph graph = build_proximity_graph(set.samples, set.radius);
  ASSERT_EQ(graph.size(), set.samples.size());
  size_t edges = 0;
  for (uint32_t i = 0; i < graph.size(); ++i) {
    const auto n = graph.neighbours_of(i);
    const auto l = graph.lengths_of(i);
    EXPECT_TRUE(std::is_sorted(n.begin(), n.end()));
    EXPECT_GE(n.size(), 3u) << i;
    for (size_t e = 0; e < n.size(); ++e) {
      ASSERT_NE(n[e], i);
      const auto back = graph.neighbours_of(n[e]);
      const auto found = std::lower_bound(back.begin(), back.end(), i);
      ASSERT_TRUE(found != back.end() && *found == i);
      EXPECT_EQ(graph.lengths_of(n[e])[found - back.begin()], l[e]);
      EXPECT_GE(l[e], set.radius * 0.999);
      EXPECT_LE(l[e], 2.5 * set.radius);
    }
    edges += n.size();
  }
  const auto component = connected_components(graph);
  EXPECT_EQ(*std::max_element(component.begin(), component.end()), 0u);
  EXPECT_GT(static_cast<double>(edges) / graph.size(), 6.0);  // mean degree
}

// The budget estimate covers what the sampler really keeps, and its inverse fits.
TEST(PartitionBudget, EstimateCoversTheSampler) {
  const auto faces = shapes::positioned_faces(shapes::icosphere(6, 0.15));
  SurfaceAreaSum area;
  area.add_faces(faces);
  SamplerOptions options;
  options.radius = radius_for_sample_count(area.total(), 4000);
  SurfaceSampler sampler(options);
  sampler.add_faces(faces);
  const size_t samples = sampler.finish().samples.size();
  EXPECT_GT(samples, 3600u);  // the radius helper hits its target within 10%
  EXPECT_LT(samples, 4400u);
  const PartitionFootprint footprint;
  EXPECT_LE(2 * sampler.kept_candidates() * sizeof(SurfaceSampler::Candidate),
            samples * footprint.sampling_bytes_per_sample);
  const uint64_t budget = 256ull << 20;
  const uint64_t fitting = max_samples_for_budget(budget, 64, 8);
  EXPECT_LE(partition_peak_bytes(fitting, 64, 8), budget);
  EXPECT_GT(partition_peak_bytes(fitting + 2000, 64, 8), budget);
  EXPECT_GT(fitting, 100'000u);
}

}  // namespace
}  // namespace qemflow::nodes::partition
