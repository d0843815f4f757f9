// The OBJ reader: every face form, relative indices, ignored statements, streaming
// batches that interleave vertices and triangles.
#include <gtest/gtest.h>

#include "io_test_support.hpp"
#include "ply_builder.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;
using testing::read_in_batches;

const char* kObj =
    "# a comment\n"
    "mtllib scene.mtl\n"
    "o thing\n"
    "v 0 0 0\n"
    "v 1 0 0 1.0\n"            // w
    "v 1 1 0 0.5 0.25 0.125\n"  // colours
    "vt 0 0\nvt 1 0\nvt 1 1\n"
    "vn 0 0 1\n"
    "g group\ns 1\nusemtl red\n"
    "f 1 2 3\n"
    "v\t0 1 0\r\n"
    "f 1/1 2/2 3/3 4/1\n"         // quad, v/vt
    "v -1 -1 +2.5e0\n"
    "f -5//1 -4//1 -1//1\n"       // relative, v//vn
    "f 2/2/1 3/3/1 5/1/1\n"       // v/vt/vn
    "l 1 2\np 3\n"
    "  f   1 3   5  \n"           // leading blanks, extra spaces
    "f 5 4 3 2 1";                // pentagon, no final newline

const std::vector<Point> kVertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {-1, -1, 2.5}};
const std::vector<Triangle> kTriangles = {{0, 1, 2}, {0, 1, 2}, {0, 2, 3}, {0, 1, 4}, {1, 2, 4},
                                          {0, 2, 4}, {4, 3, 2}, {4, 2, 1}, {4, 1, 0}};

TEST(ObjFormat, EveryFaceFormAndIgnoredStatement) {
  TempDir dir;
  testing::write_bytes(dir / "m.obj", kObj);
  testing::write_bytes(dir / "m.obj.zst", testing::zstd_compress(kObj));
  for (const char* name : {"m.obj", "m.obj.zst"}) {
    auto reader = open_mesh_reader(dir / name);
    EXPECT_EQ(reader->info().format, MeshFormat::obj);
    EXPECT_FALSE(reader->info().vertex_count.has_value());
    for (size_t batch : {1, 2, 3, 4, 5, 6, 7, 100}) {
      SCOPED_TRACE(std::string(name) + " batch " + std::to_string(batch));
      IndexedMesh mesh = read_in_batches(dir / name, batch);
      EXPECT_EQ(mesh.vertices, kVertices);
      EXPECT_EQ(mesh.triangles, kTriangles);
    }
  }
}

TEST(ObjFormat, BatchesInterleaveVerticesAndTriangles) {
  TempDir dir;
  testing::write_bytes(dir / "m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 1 1 0\nf 2 4 3\n");
  auto reader = open_mesh_reader(dir / "m.obj");
  MeshBatch batch;
  ASSERT_TRUE(reader->next(batch, 100));
  EXPECT_EQ(batch.vertices.size(), 4u);
  EXPECT_EQ(batch.triangles, (std::vector<Triangle>{{0, 1, 2}, {1, 3, 2}}));
  EXPECT_FALSE(reader->next(batch, 100));
}

TEST(ObjFormat, EmptyAndCommentOnlyFiles) {
  TempDir dir;
  testing::write_bytes(dir / "empty.obj", "");
  testing::write_bytes(dir / "comments.obj", "# nothing\n\n   \n# here");
  for (const char* name : {"empty.obj", "comments.obj"}) {
    IndexedMesh mesh = read_mesh(dir / name);
    EXPECT_TRUE(mesh.vertices.empty());
    EXPECT_TRUE(mesh.triangles.empty());
  }
}

}  // namespace
}  // namespace qemflow::io
