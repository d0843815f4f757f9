#include "measure/distance.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstring>

#include "measure/vec3.hpp"
#include "measure_test_meshes.hpp"
#include "util/error.hpp"

namespace qemflow::measure {
namespace {

using testing::TestMesh;

DistanceReport compare(const TestMesh& a, const TestMesh& b, CompareOptions options = {}) {
  return compare_meshes(a.points, a.triangles, b.points, b.triangles, options);
}

CompareOptions with_samples(uint64_t samples) {
  CompareOptions o;
  o.samples = samples;
  return o;
}

TEST(Distance, ParallelSquaresAreExactlyTheOffsetApart) {
  const double d = 0.1;  // not a float: the double positions must be kept exactly
  const TestMesh a = testing::square(1, 1.0, 0.0), b = testing::square(8, 1.0, d);
  const auto r = compare(a, b, with_samples(200'000));
  for (const auto* dir : {&r.a_to_b, &r.b_to_a}) {
    EXPECT_NEAR(dir->hausdorff, d, 1e-12);
    EXPECT_NEAR(dir->mean, d, 1e-12);
    EXPECT_NEAR(dir->rms, d, 1e-12);
  }
  EXPECT_NEAR(r.hausdorff, d, 1e-12);
  EXPECT_NEAR(r.bbox_diagonal, std::sqrt(2.0), 1e-15);
  EXPECT_NEAR(r.relative(r.hausdorff), d / std::sqrt(2.0), 1e-12);
  EXPECT_EQ(r.a_to_b.vertex_samples, 4u);
  EXPECT_EQ(r.b_to_a.vertex_samples, 81u);
  EXPECT_EQ(r.flipped_faces, 0u);
}

TEST(Distance, SphereAgainstScaledCopyIsOnePercentOfRadius) {
  const double radius = 2.0;
  const TestMesh a = testing::icosphere(4, radius);
  TestMesh b = a;
  for (auto& p : b.points) p = 1.01 * p;
  // Every distance lies in [0.01 c, 0.01] * radius, c = min over faces of (distance of
  // the face plane from the centre) / radius: A's points are inside every face plane
  // of B by at least 0.01 * plane distance, and within 0.01 |p| of their scaled copy.
  double c = 1.0;
  for (const auto& t : a.triangles) {
    const Point n = triangle_normal(a.points[t[0]], a.points[t[1]], a.points[t[2]]);
    c = std::min(c, dot(n, a.points[t[0]]) / std::sqrt(squared_length(n)) / radius);
  }
  ASSERT_GT(c, 0.99);
  const double lo = 0.01 * c * radius - 1e-12, hi = 0.01 * radius + 1e-12;
  const auto r = compare(a, b, with_samples(300'000));
  for (const auto* dir : {&r.a_to_b, &r.b_to_a}) {
    EXPECT_GE(dir->hausdorff, lo);
    EXPECT_LE(dir->hausdorff, hi);
    EXPECT_GE(dir->mean, lo);
    EXPECT_LE(dir->mean, dir->rms);
    EXPECT_LE(dir->rms, dir->hausdorff);
    EXPECT_GE(dir->vertex_samples, a.points.size());
  }
  EXPECT_EQ(r.flipped_faces, 0u);
  // Both meshes have the same face count, so B's face samples are N up to rounding.
  EXPECT_NEAR(double(r.b_to_a.face_samples), 300'000.0, 5 * std::sqrt(double(b.triangles.size())) + 1);
}

TEST(Distance, CubeMovedAlongAnAxis) {
  const double t = 0.25;
  const auto r = compare(testing::cube(), testing::cube({t, 0, 0}), with_samples(100'000));
  // The left face of A is t from B's left face; nothing of A is further from B (and
  // by symmetry the same holds for B against A). The corner vertices realise it exactly.
  EXPECT_DOUBLE_EQ(r.a_to_b.hausdorff, t);
  EXPECT_DOUBLE_EQ(r.b_to_a.hausdorff, t);
  EXPECT_DOUBLE_EQ(r.hausdorff, t);
  EXPECT_GT(r.mean, 0.0);
  EXPECT_LT(r.mean, t);
  EXPECT_DOUBLE_EQ(r.bbox_diagonal, std::sqrt(3.0));
}

TEST(Distance, TiltedPlaneHasAnalyticMeanAndRms) {
  // A: z = 0 on [0,1]^2. B: z = s x. A->B distance at (x, y) is s x / sqrt(1+s^2)
  // (the foot stays inside B); B->A at (x, y, s x) is s x. Over uniform x in [0,1]:
  // mean = k/2, rms = k/sqrt(3), max = k.
  const double s = 0.2;
  const TestMesh a = testing::square(32, 1.0, 0.0);
  const TestMesh b = testing::grid(32, 1.0, [s](double x, double) { return s * x; });
  const auto r = compare(a, b, with_samples(400'000));
  const double k_ab = s / std::sqrt(1 + s * s), k_ba = s;
  EXPECT_NEAR(r.a_to_b.hausdorff, k_ab, 1e-12);
  EXPECT_NEAR(r.b_to_a.hausdorff, k_ba, 1e-12);
  EXPECT_NEAR(r.a_to_b.mean, k_ab / 2, 2e-3 * k_ab);
  EXPECT_NEAR(r.b_to_a.mean, k_ba / 2, 2e-3 * k_ba);
  EXPECT_NEAR(r.a_to_b.rms, k_ab / std::sqrt(3.0), 2e-3 * k_ab);
  EXPECT_NEAR(r.b_to_a.rms, k_ba / std::sqrt(3.0), 2e-3 * k_ba);
  EXPECT_EQ(r.mean, r.b_to_a.mean);
}

TEST(Distance, IdenticalMeshesAreZeroApart) {
  const TestMesh a = testing::icosphere(3);
  const auto r = compare(a, a, with_samples(100'000));
  EXPECT_LE(r.hausdorff, 1e-15);
  EXPECT_LE(r.rms, 1e-15);
  EXPECT_EQ(r.flipped_faces, 0u);
}

TEST(Distance, FlippedFaceIsDetected) {
  const TestMesh a = testing::icosphere(3);
  TestMesh b = a;
  std::swap(b.triangles[17][1], b.triangles[17][2]);
  std::swap(b.triangles[300][0], b.triangles[300][1]);
  const auto r = compare(a, b, with_samples(10'000));
  EXPECT_EQ(r.flipped_faces, 2u);
  EXPECT_LE(r.hausdorff, 1e-15);  // same surface: distances do not see orientation
}

TEST(Distance, FaceOnTwoOppositeSheetsIsNotFlipped) {
  // A is a two-sided square (each triangle also present with reversed winding): for
  // every face of B both a same- and an opposite-facing face of A are nearest.
  TestMesh a = testing::square(4, 1.0, 0.0);
  const size_t n = a.triangles.size();
  for (size_t i = 0; i < n; ++i) a.triangles.push_back({a.triangles[i][0], a.triangles[i][2], a.triangles[i][1]});
  const auto up = compare(a, testing::square(3, 1.0, 0.0), with_samples(1000));
  EXPECT_EQ(up.flipped_faces, 0u);
  TestMesh down = testing::square(3, 1.0, 0.0);
  for (auto& t : down.triangles) std::swap(t[1], t[2]);
  EXPECT_EQ(compare(a, down, with_samples(1000)).flipped_faces, 0u);
  EXPECT_EQ(compare(testing::square(4, 1.0, 0.0), down, with_samples(1000)).flipped_faces, down.triangles.size());
}

bool same_bits(const DistanceReport& x, const DistanceReport& y) {
  auto eq = [](const DirectedDistance& a, const DirectedDistance& b) {
    return std::memcmp(&a.hausdorff, &b.hausdorff, sizeof(double)) == 0 &&
           std::memcmp(&a.mean, &b.mean, sizeof(double)) == 0 && std::memcmp(&a.rms, &b.rms, sizeof(double)) == 0 &&
           a.vertex_samples == b.vertex_samples && a.face_samples == b.face_samples;
  };
  return eq(x.a_to_b, y.a_to_b) && eq(x.b_to_a, y.b_to_a) && x.flipped_faces == y.flipped_faces &&
         std::memcmp(&x.mean, &y.mean, sizeof(double)) == 0;
}

TEST(Distance, BitIdenticalForAnyThreadCountAndChunkSize) {
  // A bumpy sphere against a coarse one: thousands of faces in several 1024-face blocks.
  TestMesh a = testing::icosphere(5);
  for (auto& p : a.points) p = (1.0 + 0.02 * std::sin(7 * p[0]) * std::cos(5 * p[1])) * p;
  const TestMesh b = testing::icosphere(3, 1.003);
  CompareOptions options = with_samples(150'000);
  DistanceReport serial, parallel, chunked;
  {
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    serial = compare(a, b, options);
  }
  {
    tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
    parallel = compare(a, b, options);
    options.chunk_faces = 1024;  // 20 chunks of A instead of one
    chunked = compare(a, b, options);
  }
  EXPECT_TRUE(same_bits(serial, parallel));
  EXPECT_TRUE(same_bits(serial, chunked));
  EXPECT_GT(serial.hausdorff, 0.01);
}

TEST(Distance, DifferentSeedsAgreeStatistically) {
  const TestMesh a = testing::icosphere(4);
  TestMesh b = testing::icosphere(2);
  CompareOptions options = with_samples(200'000);
  const auto first = compare(a, b, options);
  options.seed = 12345;
  const auto second = compare(a, b, options);
  EXPECT_NE(first.a_to_b.mean, second.a_to_b.mean);
  EXPECT_NEAR(first.a_to_b.mean, second.a_to_b.mean, 0.02 * first.a_to_b.mean);
  EXPECT_NEAR(first.b_to_a.rms, second.b_to_a.rms, 0.02 * first.b_to_a.rms);
}

TEST(Distance, EmptyMeshIsBadInput) {
  const TestMesh a = testing::cube();
  const TestMesh empty{{{0, 0, 0}}, {}};
  EXPECT_THROW(compare(a, empty), Error);
  EXPECT_THROW(compare(empty, a), Error);
}

TEST(Distance, DefaultSampleCount) {
  EXPECT_EQ(default_sample_count(10), 1'000'000u);
  EXPECT_EQ(default_sample_count(500'000), 5'000'000u);
}

}  // namespace
}  // namespace qemflow::measure
