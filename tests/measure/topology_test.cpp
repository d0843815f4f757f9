#include "measure/topology.hpp"

#include <gtest/gtest.h>

#include "measure_test_meshes.hpp"
#include "util/error.hpp"
#include "test_support.hpp"

namespace qemflow::measure {
namespace {

using testing::TestMesh;

TopologyStats stats_of(const TestMesh& m) { return topology(m.points, m.triangles); }

TEST(Topology, SingleTriangle) {
  const auto s = stats_of({{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 2}}});
  EXPECT_EQ(s.vertices, 3u);
  EXPECT_EQ(s.faces, 1u);
  EXPECT_EQ(s.edges, 3u);
  EXPECT_EQ(s.boundary_edges, 3u);
  EXPECT_EQ(s.non_manifold_edges, 0u);
  EXPECT_EQ(*s.non_manifold_vertices, 0u);
  EXPECT_EQ(*s.degenerate_faces, 0u);
  EXPECT_EQ(*s.duplicate_faces, 0u);
  EXPECT_EQ(*s.connected_components, 1u);
  EXPECT_EQ(*s.unreferenced_vertices, 0u);
  EXPECT_EQ(s.passes, 1u);
}

TEST(Topology, TwoTrianglesSharingAnEdge) {
  const auto s = stats_of({{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}}, {{0, 1, 2}, {1, 3, 2}}});
  EXPECT_EQ(s.edges, 5u);
  EXPECT_EQ(s.boundary_edges, 4u);
  EXPECT_EQ(s.non_manifold_edges, 0u);
  EXPECT_EQ(s.oriented_duplicate_edges, 0u);
  EXPECT_EQ(*s.non_manifold_vertices, 0u);
  EXPECT_EQ(*s.connected_components, 1u);
}

TEST(Topology, InconsistentWindingIsCountedAsOrientedDuplicate) {
  // Second face walks the shared edge 1->2 in the same direction as the first.
  const auto s = stats_of({{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}}, {{0, 1, 2}, {1, 2, 3}}});
  EXPECT_EQ(s.boundary_edges, 4u);
  EXPECT_EQ(s.oriented_duplicate_edges, 1u);
}

TEST(Topology, ThreeTrianglesOnOneEdge) {
  const auto s = stats_of({{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}},
                           {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}}});
  EXPECT_EQ(s.non_manifold_edges, 1u);
  EXPECT_EQ(s.boundary_edges, 6u);
  EXPECT_EQ(s.edges, 7u);
  EXPECT_EQ(*s.non_manifold_vertices, 0u);  // the faces at 0 and 1 are linked through the edge
  EXPECT_EQ(*s.connected_components, 1u);
}

TEST(Topology, BowTieHasOneNonManifoldVertex) {
  const auto s = stats_of({{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {-1, 0, 0}, {-1, -1, 0}}, {{0, 1, 2}, {0, 3, 4}}});
  EXPECT_EQ(*s.non_manifold_vertices, 1u);
  EXPECT_EQ(s.non_manifold_edges, 0u);
  EXPECT_EQ(s.boundary_edges, 6u);
  EXPECT_EQ(*s.connected_components, 1u);  // faces sharing a vertex are one component
}

TEST(Topology, DegenerateDuplicateAndUnreferenced) {
  TestMesh m{{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}, {5, 5, 5}, {7, 7, 7}},
             {{0, 1, 2},
              {2, 0, 1},   // duplicate (same set, rotated)
              {0, 2, 1},   // duplicate (same set, flipped)
              {0, 0, 1},   // repeated index
              {0, 1, 3}}}; // zero area (collinear)
  const auto s = stats_of(m);
  EXPECT_EQ(*s.degenerate_faces, 2u);
  EXPECT_EQ(*s.duplicate_faces, 2u);
  EXPECT_EQ(*s.unreferenced_vertices, 2u);
  EXPECT_EQ(*s.connected_components, 1u);
  // Edges 0-1 (three copies of the face plus the sliver), 1-2 and 0-2 (three copies).
  EXPECT_EQ(s.non_manifold_edges, 3u);
}

TEST(Topology, ClosedMeshesAndComponents) {
  auto sphere = testing::icosphere(2);
  const auto s = stats_of(sphere);
  EXPECT_EQ(s.faces, 320u);
  EXPECT_EQ(s.vertices, 162u);
  EXPECT_EQ(s.edges, 480u);
  EXPECT_EQ(s.boundary_edges + s.non_manifold_edges + s.oriented_duplicate_edges, 0u);
  EXPECT_EQ(*s.non_manifold_vertices + *s.degenerate_faces + *s.duplicate_faces, 0u);
  EXPECT_EQ(*s.connected_components, 1u);

  // Two cubes side by side: two components.
  auto a = testing::cube(), b = testing::cube({3, 0, 0});
  for (auto t : b.triangles) a.triangles.push_back({t[0] + 8, t[1] + 8, t[2] + 8});
  a.points.insert(a.points.end(), b.points.begin(), b.points.end());
  const auto two = stats_of(a);
  EXPECT_EQ(*two.connected_components, 2u);
  EXPECT_EQ(two.boundary_edges, 0u);
  EXPECT_DOUBLE_EQ(two.bbox.hi[0], 4.0);
}

// A source that hides its size, so the pass planner must discover it by overflowing.
class HintlessSource final : public MeshSource {
 public:
  explicit HintlessSource(const MeshSource& inner) : inner_(inner) {}
  const std::string& name() const override { return inner_.name(); }
  std::optional<uint64_t> triangle_count_hint() const override { return std::nullopt; }
  void scan(const MeshScan& scan) const override { inner_.scan(scan); }

 private:
  const MeshSource& inner_;
};

TEST(Topology, PartitionedPassesGiveTheSameCounts) {
  // A sphere with the faces around vertex 0 cut out, a dangling triangle at vertex 1
  // (on the hole's rim: a bow-tie there) and a duplicate face, ~80k faces: about 12 MB
  // of records, so a 1 MiB cap needs many passes.
  auto m = testing::icosphere(6);
  std::erase_if(m.triangles, [](const Triangle& t) { return t[0] == 0 || t[1] == 0 || t[2] == 0; });
  m.triangles.push_back(m.triangles[5]);
  m.points.push_back({3, 3, 3});
  m.points.push_back({3, 4, 3});
  m.triangles.push_back({1, m.points.size() - 2, m.points.size() - 1});
  const auto one = topology(m.points, m.triangles);
  EXPECT_EQ(one.passes, 1u);
  EXPECT_GT(one.boundary_edges, 0u);
  EXPECT_EQ(*one.duplicate_faces, 1u);
  EXPECT_EQ(*one.non_manifold_vertices, 1u);

  const auto source = memory_mesh_source(m.points, m.triangles);
  for (bool hinted : {true, false}) {
    HintlessSource hintless(*source);
    const MeshSource& s = hinted ? *source : static_cast<const MeshSource&>(hintless);
    const auto many = topology(s, {TopologyOptions::Scope::full, 1 << 20});
    EXPECT_GT(many.passes, 8u) << hinted;
    EXPECT_EQ(many.edges, one.edges);
    EXPECT_EQ(many.boundary_edges, one.boundary_edges);
    EXPECT_EQ(many.non_manifold_edges, one.non_manifold_edges);
    EXPECT_EQ(many.oriented_duplicate_edges, one.oriented_duplicate_edges);
    EXPECT_EQ(many.non_manifold_vertices, one.non_manifold_vertices);
    EXPECT_EQ(many.duplicate_faces, one.duplicate_faces);
    EXPECT_EQ(many.connected_components, one.connected_components);
    EXPECT_EQ(many.degenerate_faces, one.degenerate_faces);
    EXPECT_EQ(many.faces, one.faces);

    const auto edges_only = topology(s, {TopologyOptions::Scope::edges, 1 << 20});
    EXPECT_EQ(edges_only.boundary_edges, one.boundary_edges);
    EXPECT_EQ(edges_only.non_manifold_edges, one.non_manifold_edges);
    EXPECT_FALSE(edges_only.non_manifold_vertices.has_value());
  }
}

TEST(Topology, BadIndexIsBadInput) {
  std::vector<Point> points{{0, 0, 0}, {1, 0, 0}};
  std::vector<Triangle> triangles{{0, 1, 2}};
  try {
    topology(points, triangles);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("face 0"), std::string::npos) << e.what();
  }
}

struct ManifestRow {
  const char* name;
  uint64_t vertices, faces, boundary, non_manifold, oriented;
};

// MANIFEST.md's counts, exactly.
TEST(Topology, SharedMeshesMatchTheManifest) {
  const ManifestRow rows[] = {{"stanford-bunny", 35947, 69451, 223, 0, 0},
                              {"stanford-dragon", 437645, 871414, 4270, 0, 0},
                              {"beast", 32311, 64618, 0, 2, 4},
                              {"igea", 134345, 268686, 0, 0, 0},
                              {"ogre", 62194, 124008, 236, 0, 0},
                              {"nefertiti", 49971, 99938, 0, 0, 0}};
  for (const auto& row : rows) {
    const auto path = qemflow::testing::shared_mesh(row.name);
    QEMFLOW_REQUIRE_SHARED_MESH(path);
    const auto s = topology(*file_mesh_source(path), {TopologyOptions::Scope::edges});
    EXPECT_EQ(s.vertices, row.vertices) << row.name;
    EXPECT_EQ(s.faces, row.faces) << row.name;
    EXPECT_EQ(s.boundary_edges, row.boundary) << row.name;
    EXPECT_EQ(s.non_manifold_edges, row.non_manifold) << row.name;
    EXPECT_EQ(s.oriented_duplicate_edges, row.oriented) << row.name;
  }
  const auto bunny = qemflow::testing::shared_mesh("stanford-bunny");
  QEMFLOW_REQUIRE_SHARED_MESH(bunny);
  const auto full = topology(*file_mesh_source(bunny));
  EXPECT_EQ(*full.unreferenced_vertices, 1113u);  // as MANIFEST.md says
  EXPECT_EQ(full.boundary_edges, 223u);
}

}  // namespace
}  // namespace qemflow::measure
