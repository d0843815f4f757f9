// The decimator on the real meshes in ../shared/data (skipped when absent): exact target
// and the safety properties - no new boundary, non-manifold or misoriented edges, no
// degenerate faces - and identical bytes for 1 and 2 threads.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <bit>

#include "io/indexed_mesh.hpp"
#include "nodes/decimate/simplify.hpp"
#include "nodes/weld.hpp"
#include "test_support.hpp"
#include "tests/nodes/mesh_fixtures.hpp"

namespace qemflow::nodes {
namespace {

using qemflow::testing::topology;

qemflow::testing::Topology welded_topology(const io::IndexedMesh& mesh) {
  const auto rep = weld_representatives(mesh.vertices);
  std::vector<Triangle> tris = mesh.triangles;
  for (auto& t : tris)
    for (auto& v : t) v = rep[v];
  return topology(mesh.vertices, tris);
}

void check_safe_simplification(const std::string& name, double ratio) {
  const auto path = qemflow::testing::shared_mesh(name);
  QEMFLOW_REQUIRE_SHARED_MESH(path);
  io::IndexedMesh mesh = io::read_mesh(path);
  const auto before = welded_topology(mesh);
  SimplifyOptions options;
  options.ratio = ratio;
  const uint64_t target = target_face_count(mesh.triangles.size(), options);
  const auto result = simplify_in_core(std::move(mesh.vertices), std::move(mesh.triangles), options);
  EXPECT_NEAR(double(result.triangles.size()), double(target), 1.0) << name;
  const auto after = topology(result.points, result.triangles);
  EXPECT_LE(after.boundary_edges, before.boundary_edges) << name;
  EXPECT_LE(after.nonmanifold_edges, before.nonmanifold_edges) << name;
  EXPECT_LE(after.misoriented_edges, before.misoriented_edges) << name;
  EXPECT_LE(after.degenerate_faces, before.degenerate_faces) << name;
}

TEST(DecimateSharedMeshes, BunnyAtOnePercent) { check_safe_simplification("stanford-bunny", 0.01); }
TEST(DecimateSharedMeshes, IgeaAtOnePercent) { check_safe_simplification("igea", 0.01); }
TEST(DecimateSharedMeshes, BeastAtOnePercent) { check_safe_simplification("beast", 0.01); }
TEST(DecimateSharedMeshes, OgreAtOnePercent) { check_safe_simplification("ogre", 0.01); }
TEST(DecimateSharedMeshes, NefertitiAtOnePercent) { check_safe_simplification("nefertiti", 0.01); }
TEST(DecimateSharedMeshes, DragonReachesOneTenthOfAPercent) {
  check_safe_simplification("stanford-dragon", 0.001);
}

TEST(DecimateSharedMeshes, BunnyIsIdenticalForOneAndTwoThreads) {
  const auto path = qemflow::testing::shared_mesh("stanford-bunny");
  QEMFLOW_REQUIRE_SHARED_MESH(path);
  auto solve = [&](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    io::IndexedMesh mesh = io::read_mesh(path);
    SimplifyOptions options;
    options.ratio = 0.02;
    return simplify_in_core(std::move(mesh.vertices), std::move(mesh.triangles), options);
  };
  const auto a = solve(1), b = solve(2);
  qemflow::testing::expect_identical(a.points, a.triangles, b.points, b.triangles);
}

}  // namespace
}  // namespace qemflow::nodes
