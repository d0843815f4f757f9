// The decimator on tiny meshes with known outcomes, and its safety, exact-target and
// determinism properties on generated meshes.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <set>

#include "nodes/decimate/simplify.hpp"
#include "nodes/weld.hpp"
#include "tests/nodes/mesh_fixtures.hpp"

namespace qemflow::nodes {
namespace {

using qemflow::testing::Mesh;
using qemflow::testing::topology;

SimplifyResult run(Mesh m, uint64_t target, bool weld = true) {
  SimplifyOptions o;
  o.target_faces = target;
  o.weld = weld;
  return simplify_in_core(std::move(m.points), std::move(m.triangles), o);
}

TEST(Decimate, TetrahedronCannotGoBelowFourFaces) {
  const auto r = run(qemflow::testing::tetrahedron(), 2);
  EXPECT_EQ(r.triangles.size(), 4u);
  EXPECT_EQ(r.points.size(), 4u);
}

TEST(Decimate, FlatGridCollapsesToFewFacesKeepingItsBorderOnItsLines) {
  const auto r = run(qemflow::testing::grid(16), 2);
  EXPECT_LE(r.triangles.size(), 8u);
  double lo_x = 1, hi_x = 0, lo_y = 1, hi_y = 0;
  for (const auto& p : r.points) {
    EXPECT_EQ(p[2], 0.0);
    lo_x = std::min(lo_x, p[0]), hi_x = std::max(hi_x, p[0]);
    lo_y = std::min(lo_y, p[1]), hi_y = std::max(hi_y, p[1]);
  }
  // The four corners survive and every vertex is on the square's border (to the
  // rounding of the 3x3 solve: the deviation charge's rounding-level values decide
  // among the zero-cost collapses, and some end at a corner computed, not copied).
  const double ulps = 1e-12;
  EXPECT_NEAR(lo_x, 0.0, ulps);
  EXPECT_NEAR(hi_x, 1.0, ulps);
  EXPECT_NEAR(lo_y, 0.0, ulps);
  EXPECT_NEAR(hi_y, 1.0, ulps);
  for (const auto& p : r.points) {
    auto on = [&](double x, double line) { return std::abs(x - line) <= ulps; };
    const bool on_border = on(p[0], 0.0) || on(p[0], 1.0) || on(p[1], 0.0) || on(p[1], 1.0);
    EXPECT_TRUE(on_border) << p[0] << " " << p[1];
  }
  const auto t = topology(r.points, r.triangles);
  EXPECT_EQ(t.nonmanifold_edges, 0u);
  EXPECT_EQ(t.degenerate_faces, 0u);
  EXPECT_EQ(qemflow::testing::count_flipped(r.points, r.triangles,
                                            [](const Point&) { return Point{0, 0, 1}; }),
            0u);
}

TEST(Decimate, HitsTheExactTargetOnClosedAndOpenMeshes) {
  for (uint64_t target : {1000u, 500u, 100u, 20u}) {
    const auto r = run(qemflow::testing::icosphere(4, 0.01), target);  // 5120 faces
    EXPECT_EQ(r.triangles.size(), target) << target;
  }
  // A closed mesh has an even face count: an odd target ends one above.
  EXPECT_EQ(run(qemflow::testing::icosphere(4, 0.01), 301).triangles.size(), 302u);
  // (An open mesh can end one above an odd remainder when no border edge is a candidate
  // at the end: the grid to 25..44 faces misses 5 of 20 targets with E = 4 and a fixed
  // cut, 7 of 20 with rising cuts; 33 is one of them now, 37 is not.)
  for (uint64_t target : {2001u, 777u, 100u, 37u}) {
    const auto r = run(qemflow::testing::grid(40, 0.002), target);  // 3200 faces
    EXPECT_EQ(r.triangles.size(), target) << target;
  }
}

TEST(Decimate, SafeOnANoisySphere) {
  auto m = qemflow::testing::icosphere(5, 0.02);  // 20480 faces
  const auto r = run(m, 200);
  EXPECT_EQ(r.triangles.size(), 200u);
  const auto t = topology(r.points, r.triangles);
  EXPECT_EQ(t.boundary_edges, 0u);
  EXPECT_EQ(t.nonmanifold_edges, 0u);
  EXPECT_EQ(t.misoriented_edges, 0u);
  EXPECT_EQ(t.degenerate_faces, 0u);
  EXPECT_EQ(qemflow::testing::count_flipped(r.points, r.triangles, [](const Point& c) { return c; }), 0u);
  for (const auto& p : r.points) {
    const double radius = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    EXPECT_NEAR(radius, 1.0, 0.08);
  }
}

TEST(Decimate, IdenticalOutputForOneAndTwoThreads) {
  auto solve = [](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    return run(qemflow::testing::icosphere(5, 0.03, 7), 1234);
  };
  const auto a = solve(1), b = solve(2);
  qemflow::testing::expect_identical(a.points, a.triangles, b.points, b.triangles);
}

TEST(Decimate, ReportsRoundsAndKeepsOutputOrderedById) {
  const auto r = run(qemflow::testing::icosphere(4, 0.01), 500);
  EXPECT_GT(r.stats.rounds, 1u);
  EXPECT_EQ(r.stats.output_faces, 500u);
}

// The work counters: a refresh computes validity checks and, with the deviation charge
// on, charges; plain QEM (weight 0) computes every cost exactly without one.
TEST(Decimate, CountsItsRefreshesChargesAndValidityChecks) {
  const auto charged = run(qemflow::testing::icosphere(4, 0.01), 500);
  EXPECT_GT(charged.stats.work.refreshes, charged.stats.input_vertices);  // every vertex at least once
  EXPECT_GT(charged.stats.work.validity_checks, 0u);
  EXPECT_GT(charged.stats.work.charges, 0u);
  SimplifyOptions o;
  o.target_faces = 500;
  o.params.deviation_weight = 0.0;
  Mesh m = qemflow::testing::icosphere(4, 0.01);
  const auto plain = simplify_in_core(std::move(m.points), std::move(m.triangles), o);
  EXPECT_EQ(plain.stats.work.charges, 0u);
  EXPECT_GT(plain.stats.work.validity_checks, 0u);
  EXPECT_GT(plain.stats.work.refreshes, plain.stats.input_vertices);
}

// Golden output: catches accidental changes of the in-core result (speed work must keep
// it). Update only deliberately, with a note in the commit message. Last changed by the
// fold check: no new fold where the fans had none (DecimateParams::new_fold_cos).
TEST(Decimate, GoldenHashOfTheInCoreResult) {
  SimplifyOptions o;
  o.target_faces = 700;
  auto m = qemflow::testing::icosphere(5, 0.03, 21);  // 20480 faces
  const auto r = simplify_in_core(std::move(m.points), std::move(m.triangles), o);
  uint64_t hash = 1469598103934665603ull;
  auto mix = [&](uint64_t x) { hash = (hash ^ x) * 1099511628211ull; };
  for (const auto& t : r.triangles)
    for (uint64_t v : t) mix(v);
  for (const auto& p : r.points)
    for (double x : p) mix(std::bit_cast<uint64_t>(x));
  EXPECT_EQ(r.triangles.size(), 700u);
  EXPECT_EQ(hash, 3466603322149900620ull) << hash;
}

TEST(Weld, MergesExactDuplicatesOnlyAndKeepsTheSmallestIndex) {
  const std::vector<Point> pts = {{1, 2, 3}, {0, 0, 0}, {1, 2, 3}, {-0.0, 0, 0}, {1, 2, 3.0000001}};
  const auto rep = weld_representatives(pts);
  EXPECT_EQ(rep, (std::vector<uint64_t>{0, 1, 0, 1, 4}));
}

TEST(Decimate, WeldClosesASeamAndNoWeldKeepsIt) {
  // A grid split into two halves whose shared column is duplicated.
  Mesh m = qemflow::testing::grid(8, 0.0);
  const size_t n = m.points.size();
  m.points.insert(m.points.end(), m.points.begin(), m.points.end());
  for (auto& f : m.triangles) {
    const auto& p0 = m.points[f[0]], &p1 = m.points[f[1]], &p2 = m.points[f[2]];
    if (p0[0] + p1[0] + p2[0] > 1.5)
      for (auto& v : f) v += n;  // right half uses the copies
  }
  const auto welded = run(m, m.triangles.size());
  const auto apart = run(m, m.triangles.size(), false);
  EXPECT_EQ(topology(welded.points, welded.triangles).boundary_edges, 32u);
  EXPECT_EQ(topology(apart.points, apart.triangles).boundary_edges, 32u + 16u);
  EXPECT_EQ(welded.stats.welded_vertices, n);
}

TEST(Decimate, NonManifoldAndDegenerateInputIsSimplifiedAroundNotDropped) {
  Mesh m = qemflow::testing::grid(12, 0.001);
  const uint64_t base = m.triangles.size();
  // A fin on an interior edge (non-manifold edge), a face with a repeated vertex, and
  // an unreferenced vertex.
  m.points.push_back({0.5, 0.5, 0.5});
  const uint64_t apex = m.points.size() - 1;
  const auto& e = m.triangles[base / 2];
  m.triangles.push_back({e[0], e[1], apex});
  m.triangles.push_back({e[2], e[2], e[0]});
  m.points.push_back({9, 9, 9});
  const auto r = run(m, 20);
  EXPECT_LE(r.triangles.size(), 40u);
  EXPECT_EQ(r.stats.dropped_faces, 1u);  // the repeated-vertex face, counted
  const auto t = topology(r.points, r.triangles);
  EXPECT_EQ(t.nonmanifold_edges, 1u);  // the fin's edge survives, no new one
  EXPECT_EQ(t.degenerate_faces, 0u);
  // The fin itself passes through untouched.
  bool apex_kept = false;
  for (const auto& p : r.points) apex_kept |= p == Point{0.5, 0.5, 0.5};
  EXPECT_TRUE(apex_kept);
  for (const auto& p : r.points) EXPECT_NE(p[0], 9.0);
}

}  // namespace
}  // namespace qemflow::nodes
