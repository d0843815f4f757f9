// Read -> write -> read round trips through every writer format, small and real meshes.
#include <gtest/gtest.h>

#include "io/indexed_mesh.hpp"
#include "io_test_support.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;
using testing::read_in_batches;
using testing::small_mesh;

// A loop on purpose: g++ 12 -O2 miscompiles the braced form
// `return {double(float(p[0])), double(float(p[1])), ...}` (its SLP vectorizer drops
// the rounding in the vector lanes).
Point as_float(Point p) {
  for (double& c : p) c = static_cast<float>(c);
  return p;
}

IndexedMesh rounded_to_float(IndexedMesh mesh) {
  for (auto& p : mesh.vertices) p = as_float(p);
  return mesh;
}

void expect_same(const IndexedMesh& a, const IndexedMesh& b) {
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  EXPECT_TRUE(a.vertices == b.vertices);
  EXPECT_TRUE(a.triangles == b.triangles);
}

class RoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(RoundTrip, FloatOutputKeepsFloatPositionsAndTriangles) {
  TempDir dir;
  auto path = dir / ("mesh" + GetParam());
  IndexedMesh original = small_mesh();
  write_mesh(path, original);
  IndexedMesh expected = rounded_to_float(original);
  for (size_t batch : {1, 2, 3, 5, 7, 1000}) {
    IndexedMesh back = read_in_batches(path, batch);
    ASSERT_EQ(back.vertices.size(), expected.vertices.size());
    ASSERT_EQ(back.triangles, expected.triangles);
    for (size_t i = 0; i < back.vertices.size(); ++i) {
      // OBJ float output is the shortest decimal that rereads as the same float.
      EXPECT_EQ(as_float(back.vertices[i]), expected.vertices[i]) << "vertex " << i;
    }
  }
}

TEST_P(RoundTrip, DoublePrecisionIsExact) {
  TempDir dir;
  auto path = dir / ("mesh" + GetParam());
  IndexedMesh original = small_mesh();
  original.vertices.push_back({1.0 / 3.0, -1e-300, 123456789.123456789});
  original.triangles.push_back({6, 0, 1});
  write_mesh(path, original, WriteOptions{.double_precision = true});
  for (size_t batch : {1, 4, 1000}) expect_same(read_in_batches(path, batch), original);
}

TEST_P(RoundTrip, ReadWriteReadIsIdentical) {
  TempDir dir;
  auto first = dir / ("first" + GetParam());
  auto second = dir / ("second" + GetParam());
  write_mesh(first, small_mesh());
  IndexedMesh once = read_mesh(first);
  write_mesh(second, once);
  expect_same(read_mesh(second), once);
}

INSTANTIATE_TEST_SUITE_P(Formats, RoundTrip,
                         ::testing::Values(".ply", ".ply.zst", ".obj", ".obj.zst", ".PLY"),
                         [](const auto& info) {
                           std::string name = info.param.substr(1);
                           for (char& c : name) if (c == '.') c = '_';
                           return name;
                         });

TEST(RoundTrip, EmptyMeshRoundTrips) {
  TempDir dir;
  for (const char* name : {"empty.ply", "empty.ply.zst", "empty.obj"}) {
    write_mesh(dir / name, IndexedMesh{});
    IndexedMesh back = read_mesh(dir / name);
    EXPECT_TRUE(back.vertices.empty());
    EXPECT_TRUE(back.triangles.empty());
  }
}

TEST(RoundTrip, SharedBunnyThroughPlyAndZst) {
  auto bunny = qemflow::testing::shared_mesh("stanford-bunny");
  QEMFLOW_REQUIRE_SHARED_MESH(bunny);
  auto reader = open_mesh_reader(bunny);
  EXPECT_EQ(reader->info().format, MeshFormat::ply_binary_le);
  EXPECT_TRUE(reader->info().zstd);
  EXPECT_EQ(reader->info().vertex_count, 35947u);
  EXPECT_EQ(reader->info().polygon_count, 69451u);
  IndexedMesh mesh = read_mesh(bunny);
  ASSERT_EQ(mesh.vertices.size(), 35947u);
  ASSERT_EQ(mesh.triangles.size(), 69451u);
  MeshBatch batch;
  while (reader->next(batch)) {
  }
  EXPECT_EQ(reader->bytes_read(), reader->info().file_size);
  TempDir dir;
  for (const char* name : {"bunny.ply", "bunny.ply.zst"}) {
    write_mesh(dir / name, mesh);
    expect_same(read_mesh(dir / name), mesh);
  }
  // Tiny batches hit every buffer and batch boundary.
  expect_same(read_in_batches(dir / "bunny.ply.zst", 7), mesh);
  // Float in, float out: the bytes are identical apart from the header comment.
  std::string written = testing::read_bytes(dir / "bunny.ply");
  EXPECT_EQ(written.size() - written.find("end_header\n"),
            size_t{35947} * 12 + size_t{69451} * 13 + 11);
}

}  // namespace
}  // namespace qemflow::io
