// The PLY reader against every encoding, property type and layout it must accept.
#include <gtest/gtest.h>

#include "io/ply_header.hpp"
#include "io_test_support.hpp"
#include "ply_builder.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;
using testing::PlyBuilder;
using testing::read_in_batches;

// Coordinates exact in float, so every encoding must give them back unchanged.
const std::vector<Point> kVertices = {{0, 0, 0}, {1, 0, 0.5}, {1, 1, -0.25}, {0, 1, 3}, {-2, 0.5, 1}};
const std::vector<std::vector<int>> kPolygons = {{0, 1, 2}, {0, 2, 3, 4}, {4, 3, 2, 1, 0}, {1, 2, 3}};

std::vector<Triangle> fan(const std::vector<std::vector<int>>& polygons) {
  std::vector<Triangle> triangles;
  for (const auto& p : polygons) {
    for (size_t i = 1; i + 1 < p.size(); ++i) {
      triangles.push_back({uint64_t(p[0]), uint64_t(p[i]), uint64_t(p[i + 1])});
    }
  }
  return triangles;
}

struct Layout {
  std::string format = "binary_little_endian";
  std::string coordinate = "float";
  std::string count = "uchar";
  std::string index = "int";
  std::string index_name = "vertex_indices";
  int extras = 0;  // 0 none; 1 extra scalars, shuffled x/y/z; 2 plus lists and extra elements
};

std::string describe(const Layout& l) {
  return l.format + " " + l.coordinate + " list " + l.count + " " + l.index + " " + l.index_name +
         " extras=" + std::to_string(l.extras);
}

std::string build(const Layout& l) {
  PlyBuilder ply(l.format);
  if (l.extras >= 2) {
    ply.header_line("element camera 2");
    ply.header_line("property float px");
    ply.header_line("property list uchar int ids");
  }
  ply.header_line("element vertex " + std::to_string(kVertices.size()));
  if (l.extras == 0) {
    for (const char* axis : {"x", "y", "z"}) ply.header_line("property " + l.coordinate + " " + axis);
  } else {
    ply.header_line("property uchar red");
    ply.header_line("property " + l.coordinate + " z");
    ply.header_line("property double nx");
    ply.header_line("property " + l.coordinate + " x");
    if (l.extras >= 2) ply.header_line("property list ushort short tags");
    ply.header_line("property " + l.coordinate + " y");
    ply.header_line("property int16 confidence");
  }
  if (l.extras >= 2) {
    ply.header_line("element material 1");
    ply.header_line("property uchar r");
  }
  ply.header_line("element face " + std::to_string(kPolygons.size()));
  if (l.extras >= 1) ply.header_line("property uchar flags");
  ply.header_line("property list " + l.count + " " + l.index + " " + l.index_name);
  if (l.extras >= 2) ply.header_line("property list uchar float texcoord");
  if (l.extras >= 2) {
    ply.header_line("element edge 3");
    ply.header_line("property int vertex1");
    ply.header_line("property list int uint extra");
  }
  if (l.extras >= 2) {
    for (int c = 0; c < 2; ++c) {
      ply.value("float", 1.5 * c);
      ply.value("uchar", c + 1);
      for (int k = 0; k <= c; ++k) ply.value("int", 100 + k);
      ply.end_record();
    }
  }
  for (size_t v = 0; v < kVertices.size(); ++v) {
    const Point& p = kVertices[v];
    if (l.extras == 0) {
      for (double c : p) ply.value(l.coordinate, c);
    } else {
      ply.value("uchar", 200 + v);
      ply.value(l.coordinate, p[2]);
      ply.value("double", -7.5);
      ply.value(l.coordinate, p[0]);
      if (l.extras >= 2) {
        ply.value("ushort", v % 3);
        for (size_t k = 0; k < v % 3; ++k) ply.value("short", -k);
      }
      ply.value(l.coordinate, p[1]);
      ply.value("int16", -300);
    }
    ply.end_record();
  }
  if (l.extras >= 2) {
    ply.value("uchar", 9);
    ply.end_record();
  }
  for (const auto& polygon : kPolygons) {
    if (l.extras >= 1) ply.value("uchar", 0xAB);
    ply.value(l.count, static_cast<double>(polygon.size()));
    for (int v : polygon) ply.value(l.index, v);
    if (l.extras >= 2) {
      ply.value("uchar", 2);
      ply.value("float", 0.25);
      ply.value("float", 0.75);
    }
    ply.end_record();
  }
  if (l.extras >= 2) {
    for (int e = 0; e < 3; ++e) {
      ply.value("int", e);
      ply.value("int", e);
      for (int k = 0; k < e; ++k) ply.value("uint", k);
      ply.end_record();
    }
  }
  return ply.bytes();
}

void expect_reads_back(const std::filesystem::path& path, MeshFormat format) {
  auto reader = open_mesh_reader(path);
  EXPECT_EQ(reader->info().format, format);
  EXPECT_EQ(reader->info().vertex_count, kVertices.size());
  EXPECT_EQ(reader->info().polygon_count, kPolygons.size());
  for (size_t batch : {1, 2, 3, 5, 7, 64}) {
    SCOPED_TRACE("batch " + std::to_string(batch));
    IndexedMesh mesh = read_in_batches(path, batch);
    EXPECT_EQ(mesh.vertices, kVertices);
    EXPECT_EQ(mesh.triangles, fan(kPolygons));
  }
}

MeshFormat format_of(const std::string& name) {
  if (name == "ascii") return MeshFormat::ply_ascii;
  if (name == "binary_big_endian") return MeshFormat::ply_binary_be;
  return MeshFormat::ply_binary_le;
}

TEST(PlyFormats, EveryEncodingTypeAndLayout) {
  TempDir dir;
  const std::vector<std::pair<std::string, std::string>> lists = {
      {"uchar", "int"}, {"uchar", "uint"}, {"ushort", "int"}, {"int", "uint"},
      {"uint8", "int32"}, {"char", "short"}, {"uint", "ushort"}, {"int8", "uint8"}};
  int file = 0;
  for (std::string format : {"ascii", "binary_little_endian", "binary_big_endian"}) {
    for (std::string coordinate : {"float", "double", "float32", "float64"}) {
      for (const auto& [count, index] : lists) {
        for (int extras : {0, 1, 2}) {
          Layout layout{format, coordinate, count, index, file % 2 ? "vertex_index" : "vertex_indices",
                        extras};
          SCOPED_TRACE(describe(layout));
          std::string bytes = build(layout);
          auto plain = dir / ("m" + std::to_string(file) + ".ply");
          testing::write_bytes(plain, bytes);
          expect_reads_back(plain, format_of(format));
          if (file % 5 == 0) {  // .zst of a spread of layouts
            auto packed = dir / ("m" + std::to_string(file) + ".ply.zst");
            testing::write_bytes(packed, testing::zstd_compress(bytes));
            expect_reads_back(packed, format_of(format));
          }
          ++file;
        }
      }
    }
  }
}

TEST(PlyFormats, CrlfHeaderAndAsciiBody) {
  TempDir dir;
  std::string text =
      "ply\r\nformat ascii 1.0\r\ncomment hi\r\nobj_info scanner\r\nelement vertex 3\r\n"
      "property float x\r\nproperty float y\r\nproperty float z\r\nelement face 1\r\n"
      "property list uchar int vertex_indices\r\nend_header\r\n"
      "0 0 0\r\n1 0 0\r\n0 1 0\r\n3 0 1 2\r\n";
  testing::write_bytes(dir / "crlf.ply", text);
  IndexedMesh mesh = read_mesh(dir / "crlf.ply");
  EXPECT_EQ(mesh.vertices.size(), 3u);
  ASSERT_EQ(mesh.triangles.size(), 1u);
  EXPECT_EQ(mesh.triangles[0], (Triangle{0, 1, 2}));
}

TEST(PlyFormats, PointCloudWithoutFacesAndEmptyElements) {
  TempDir dir;
  PlyBuilder ply("binary_little_endian");
  ply.header_line("element nothing 0");
  ply.header_line("property list uchar int stuff");
  ply.header_line("element vertex 2");
  for (const char* axis : {"x", "y", "z"}) ply.header_line(std::string("property float ") + axis);
  for (int i = 0; i < 6; ++i) ply.value("float", i);
  testing::write_bytes(dir / "cloud.ply", ply.bytes());
  auto reader = open_mesh_reader(dir / "cloud.ply");
  EXPECT_EQ(reader->info().polygon_count, 0u);
  IndexedMesh mesh = read_mesh(dir / "cloud.ply");
  EXPECT_EQ(mesh.vertices, (std::vector<Point>{{0, 1, 2}, {3, 4, 5}}));
  EXPECT_TRUE(mesh.triangles.empty());
}

// Whitespace after the last element is read past; other bytes there are bad input
// (BadInput.DataAfterTheLastElementNamesItsOffset).
TEST(PlyFormats, TrailingWhitespaceAfterTheLastElementIsAccepted) {
  TempDir dir;
  std::string bytes = build(Layout{});
  testing::write_bytes(dir / "tail.ply", bytes + "\r\n \n");
  expect_reads_back(dir / "tail.ply", MeshFormat::ply_binary_le);
}

// Records straddle the 4 MiB read buffer many times over: the result must still be
// exact, for both the triangle fast path and the general path.
TEST(PlyFormats, LargeFileAcrossBufferBoundaries) {
  TempDir dir;
  const int n = 400000;  // ~5 MiB of face records
  for (std::string index : {"int", "ushort"}) {
    PlyBuilder ply("binary_little_endian");
    ply.header_line("element vertex 60000");
    for (const char* axis : {"x", "y", "z"}) ply.header_line(std::string("property float ") + axis);
    ply.header_line("element face " + std::to_string(n));
    ply.header_line("property list uchar " + index + " vertex_indices");
    for (int v = 0; v < 60000; ++v) {
      ply.value("float", v);
      ply.value("float", -v);
      ply.value("float", 0.5);
    }
    for (int f = 0; f < n; ++f) {
      ply.value("uchar", 3);
      for (int k = 0; k < 3; ++k) ply.value(index, (f + k) % 60000);
    }
    testing::write_bytes(dir / "big.ply", ply.bytes());
    for (size_t batch : {size_t{1} << 16, size_t{777}}) {
      IndexedMesh mesh = read_in_batches(dir / "big.ply", batch);
      ASSERT_EQ(mesh.vertices.size(), 60000u);
      ASSERT_EQ(mesh.triangles.size(), size_t(n));
      EXPECT_EQ(mesh.vertices[59999], (Point{59999, -59999, 0.5}));
      for (int f = 0; f < n; f += 997) {
        EXPECT_EQ(mesh.triangles[f], (Triangle{uint64_t(f % 60000), uint64_t((f + 1) % 60000),
                                               uint64_t((f + 2) % 60000)}));
      }
    }
  }
}

}  // namespace
}  // namespace qemflow::io
