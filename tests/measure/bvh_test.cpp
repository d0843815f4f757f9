#include "measure/bvh.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <random>

#include "measure/point_triangle.hpp"

namespace qemflow::measure {
namespace {

TEST(ClosestPointOnTriangle, EachVoronoiRegion) {
  const Point a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0};
  auto expect = [&](Point p, Point q) {
    const Point got = closest_point_on_triangle(p, a, b, c);
    for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(got[k], q[k]) << p[0] << "," << p[1] << "," << p[2];
  };
  expect({-1, -1, 1}, a);
  expect({2, -0.5, 0}, b);
  expect({-0.5, 2, 3}, c);
  expect({0.5, -1, 0}, {0.5, 0, 0});   // edge ab
  expect({-1, 0.25, 0}, {0, 0.25, 0}); // edge ac
  expect({1, 1, 0}, {0.5, 0.5, 0});    // edge bc
  expect({0.25, 0.25, 5}, {0.25, 0.25, 0});
}

TEST(ClosestPointOnTriangle, DegenerateTriangles) {
  // A segment and a point pretending to be triangles.
  const Point q = closest_point_on_triangle({0.5, 1, 0}, {0, 0, 0}, {1, 0, 0}, {2, 0, 0});
  EXPECT_NEAR(q[0], 0.5, 1e-15);
  EXPECT_NEAR(q[1], 0, 1e-15);
  EXPECT_DOUBLE_EQ(squared_distance_point_triangle({1, 1, 1}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}), 3.0);
}

TEST(ClosestPointOnTriangle, CoincidentCornersNeverGiveNaN) {
  // Triangles with two equal corners (simplifiers' outputs have them): every corner
  // order and query direction must give the distance to the segment they span.
  const Point s0{0, 0, 0}, s1{1, 0, 0};
  const Point queries[] = {{-1, 0, 0}, {2, 0, 0}, {0.5, 1, 0}, {0.5, -1, 2}, {0, 0, 1}, {1, 0, -1}};
  const std::array<Point, 3> orders[] = {{s0, s0, s1}, {s0, s1, s0}, {s1, s0, s0},
                                         {s1, s1, s0}, {s1, s0, s1}, {s0, s1, s1}};
  for (const auto& t : orders)
    for (const Point& p : queries) {
      const double d2 = squared_distance_point_triangle(p, t[0], t[1], t[2]);
      const double expected = squared_distance(p, closest_point_on_segment(p, s0, s1));
      EXPECT_DOUBLE_EQ(d2, expected) << p[0] << "," << p[1] << "," << p[2];
    }
}

TEST(ClosestPointOnTriangle, NoPointOfTheTriangleIsCloser) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1, 1), w(0, 1);
  for (int trial = 0; trial < 2000; ++trial) {
    const Point a{u(rng), u(rng), u(rng)}, b{u(rng), u(rng), u(rng)}, c{u(rng), u(rng), u(rng)};
    const Point p{2 * u(rng), 2 * u(rng), 2 * u(rng)};
    const double d2 = squared_distance_point_triangle(p, a, b, c);
    for (int k = 0; k < 50; ++k) {
      double r1 = w(rng), r2 = w(rng);
      if (r1 + r2 > 1) r1 = 1 - r1, r2 = 1 - r2;
      const Point x = a + r1 * (b - a) + r2 * (c - a);
      ASSERT_LE(d2, squared_distance(p, x) + 1e-12);
    }
  }
}

std::vector<TriangleCorners> random_triangles(size_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> centre(-10, 10), spread(-0.5, 0.5);
  std::vector<TriangleCorners> tris(count);
  for (auto& t : tris) {
    const Point c{centre(rng), centre(rng), centre(rng)};
    for (auto& p : t) p = c + Point{spread(rng), spread(rng), spread(rng)};
  }
  return tris;
}

TEST(TriangleBvh, NearestMatchesBruteForce) {
  for (size_t count : {1u, 3u, 17u, 1000u, 20000u}) {
    const auto tris = random_triangles(count, count);
    const TriangleBvh bvh = TriangleBvh::build(tris);
    ASSERT_EQ(bvh.size(), count);
    std::mt19937_64 rng(99);
    std::uniform_real_distribution<double> u(-12, 12);
    for (int q = 0; q < 300; ++q) {
      const Point p{u(rng), u(rng), u(rng)};
      double best = std::numeric_limits<double>::infinity();
      size_t best_index = 0;
      for (size_t i = 0; i < tris.size(); ++i) {
        const double d2 = squared_distance_point_triangle(p, tris[i][0], tris[i][1], tris[i][2]);
        if (d2 < best) best = d2, best_index = i;
      }
      TriangleBvh::Hit hit;
      ASSERT_TRUE(bvh.nearest(p, hit));
      EXPECT_EQ(hit.squared_distance, best);  // same kernel on the same triangle: bit-identical
      const auto& t = bvh.triangle(hit.primitive);
      EXPECT_EQ(squared_distance_point_triangle(p, t[0], t[1], t[2]), best);
      if (bvh.id(hit.primitive) != best_index) {  // only an exact tie may pick another triangle
        const auto& other = tris[bvh.id(hit.primitive)];
        EXPECT_EQ(squared_distance_point_triangle(p, other[0], other[1], other[2]), best);
      }
    }
  }
}

TEST(TriangleBvh, WarmStartAndRadiusQueryMatchBruteForce) {
  const auto tris = random_triangles(3000, 11);
  const TriangleBvh bvh = TriangleBvh::build(tris);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-12, 12);
  std::uniform_int_distribution<uint32_t> any(0, 2999);
  for (int q = 0; q < 200; ++q) {
    const Point p{u(rng), u(rng), u(rng)};
    TriangleBvh::Hit cold, warm;
    ASSERT_TRUE(bvh.nearest(p, cold));
    bvh.nearest_from(p, any(rng), warm);
    EXPECT_EQ(warm.squared_distance, cold.squared_distance);
    const double radius2 = cold.squared_distance * 4 + 1;
    size_t expected = 0, got = 0;
    for (const auto& t : tris) expected += squared_distance_point_triangle(p, t[0], t[1], t[2]) <= radius2;
    bvh.for_each_within(p, radius2, [&](uint32_t, double d2) {
      EXPECT_LE(d2, radius2);
      ++got;
    });
    EXPECT_EQ(got, expected);
  }
}

TEST(TriangleBvh, BoundLimitsTheSearch) {
  const auto tris = random_triangles(500, 3);
  const TriangleBvh bvh = TriangleBvh::build(tris);
  const Point p{0, 0, 0};
  TriangleBvh::Hit hit;
  ASSERT_TRUE(bvh.nearest(p, hit));
  const double best = hit.squared_distance;
  EXPECT_FALSE(bvh.nearest(p, best, hit));  // nothing strictly closer than the best
  EXPECT_TRUE(bvh.nearest(p, std::nextafter(best, 1e300), hit));
  EXPECT_EQ(hit.squared_distance, best);
}

TEST(TriangleBvh, ManyIdenticalTrianglesStillBuildAndQuery) {
  std::vector<TriangleCorners> tris(5000, TriangleCorners{Point{0, 0, 0}, Point{1, 0, 0}, Point{0, 1, 0}});
  const TriangleBvh bvh = TriangleBvh::build(tris);
  TriangleBvh::Hit hit;
  ASSERT_TRUE(bvh.nearest({0.25, 0.25, 2}, hit));
  EXPECT_DOUBLE_EQ(hit.squared_distance, 4.0);
  EXPECT_FALSE(TriangleBvh().nearest({0, 0, 0}, hit));
}

}  // namespace
}  // namespace qemflow::measure
