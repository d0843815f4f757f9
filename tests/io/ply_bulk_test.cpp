// The bulk binary PLY path (io/ply_bulk.hpp): raw byte ranges decoded in order must
// give exactly what the streaming reader gives, for every range size (records cut
// anywhere), every layout it accepts, and every bad input, word for word; the
// encoders must make exactly the writer's bytes.
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "io/ply_bulk.hpp"
#include "io_test_support.hpp"
#include "ply_builder.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;
using testing::PlyBuilder;

// The whole file through the bulk reader, ranges of about `max_bytes`; with `records`
// 12, faces ranges through decode_triangles32, with 13 through decode_ply_triangles,
// with 16 through decode_id_triangles32 (each widened back here, the PLY records
// checked against the writer's encode, the ids against the triangles' places); with
// `in_place` and 13, each faces range first through check_ply_triangles (its records
// are then the range's own bytes), as the resident re-encode reads them; and
// vertex ranges through decode_float_vertices where it takes them (floats "x y z"; to
// each range's own vector with 16, as the out-of-core load decodes them).
IndexedMesh bulk_read(const std::filesystem::path& path, size_t max_bytes, uint32_t records_of = 0,
                      bool in_place = false) {
  const bool triangles32 = records_of != 0;
  auto reader = open_ply_bulk_reader(path);
  EXPECT_TRUE(reader) << path;
  IndexedMesh mesh;
  if (!reader) return mesh;
  RawChunk chunk;
  MeshBatch batch;
  const uint64_t capacity = reader->info().vertex_count.value_or(0);
  std::vector<float> xyz(3 * capacity + 1, -7.0f);  // one past: nothing lands there
  while (reader->read(chunk, max_bytes)) {
    uint64_t first = 0, count = 0;
    UninitializedVector<float> own(7, -7.0f);  // whatever a reused buffer held is overwritten
    if (records_of == 16 && reader->decode_float_vertices(chunk, own, first, count)) {
      EXPECT_EQ(first, mesh.vertices.size());
      EXPECT_EQ(own.size(), 3 * count);
      for (uint64_t v = 0; v < count; ++v) mesh.vertices.push_back({own[3 * v], own[3 * v + 1], own[3 * v + 2]});
      continue;
    }
    if (records_of != 16 && triangles32 && reader->decode_float_vertices(chunk, xyz.data(), capacity, first, count)) {
      EXPECT_EQ(first, mesh.vertices.size());
      for (uint64_t v = first; v < first + count; ++v) mesh.vertices.push_back({xyz[3 * v], xyz[3 * v + 1], xyz[3 * v + 2]});
      EXPECT_EQ(xyz.back(), -7.0f);
      continue;
    }
    if (triangles32 && chunk.part == RawChunk::Part::faces) {
      Bytes records(5);  // whatever a reused buffer held is overwritten
      uint64_t first = 0, checked = 0;
      if (in_place && reader->check_ply_triangles(chunk, first, checked)) {
        EXPECT_EQ(chunk.size, checked * ply_triangle_bytes);
        const auto* bytes = reinterpret_cast<const std::byte*>(chunk.bytes.get());
        records.assign(bytes, bytes + chunk.size);
      } else if (records_of == ply_triangle_bytes) {
        reader->decode_ply_triangles(chunk, records, first);
      } else if (records_of == 16) {
        reader->decode_id_triangles32(chunk, records, first);
      } else {
        reader->decode_triangles32(chunk, records, first);
      }
      EXPECT_EQ(first, mesh.triangles.size());
      EXPECT_EQ(records.size() % records_of, 0u);
      const size_t before = mesh.triangles.size();
      for (size_t at = 0; at + records_of <= records.size(); at += records_of) {
        uint32_t abc[3];
        std::memcpy(abc, records.data() + at + (records_of == ply_triangle_bytes ? 1 : records_of == 16 ? 4 : 0), sizeof abc);
        if (records_of == 16) {
          uint32_t id;
          std::memcpy(&id, records.data() + at, sizeof id);
          EXPECT_EQ(id, mesh.triangles.size());
        }
        mesh.triangles.push_back({abc[0], abc[1], abc[2]});
      }
      if (records_of == ply_triangle_bytes) {  // the very bytes the writer makes
        std::string encoded((mesh.triangles.size() - before) * ply_triangle_bytes, '\0');
        uint64_t max_index = 0;
        encode_ply_triangles(mesh.triangles.data() + before, mesh.triangles.size() - before, encoded.data(), max_index);
        EXPECT_EQ(encoded, std::string(reinterpret_cast<const char*>(records.data()), records.size()));
      }
      continue;
    }
    reader->decode(chunk, batch);
    EXPECT_EQ(batch.first_vertex, mesh.vertices.size());
    EXPECT_EQ(batch.first_triangle, mesh.triangles.size());
    mesh.vertices.insert(mesh.vertices.end(), batch.vertices.begin(), batch.vertices.end());
    mesh.triangles.insert(mesh.triangles.end(), batch.triangles.begin(), batch.triangles.end());
  }
  EXPECT_TRUE(reader->past_vertices());
  return mesh;
}

std::string bulk_bad_input_message(const std::filesystem::path& path, size_t max_bytes, uint32_t records_of = 0,
                                   bool in_place = false) {
  try {
    bulk_read(path, max_bytes, records_of, in_place);
  } catch (const Error& error) {
    EXPECT_EQ(error.kind(), ErrorKind::bad_input) << error.what();
    return error.what();
  }
  return "";
}

void expect_same_mesh(const IndexedMesh& a, const IndexedMesh& b) {
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  for (size_t i = 0; i < a.vertices.size(); ++i) EXPECT_EQ(a.vertices[i], b.vertices[i]) << "vertex " << i;
  for (size_t i = 0; i < a.triangles.size(); ++i) EXPECT_EQ(a.triangles[i], b.triangles[i]) << "triangle " << i;
}

struct Layout {
  std::string format = "binary_little_endian";
  std::string coordinate = "float";
  bool vertex_extra = false;   // a uchar and a double around x y z
  std::string count = "uchar";
  std::string index = "int";
  bool face_extra = false;     // a float before the list and an int after it
  bool polygons = false;       // quads and a pentagon among the triangles
};

// 40 vertices and 60 faces in `layout`.
std::string make_ply(const Layout& layout) {
  PlyBuilder ply(layout.format);
  ply.header_line("element vertex 40");
  if (layout.vertex_extra) ply.header_line("property uchar flag");
  for (const char* axis : {"x", "y", "z"}) ply.header_line("property " + layout.coordinate + " " + axis);
  if (layout.vertex_extra) ply.header_line("property double weight");
  ply.header_line("element face 60");
  if (layout.face_extra) ply.header_line("property float area");
  ply.header_line("property list " + layout.count + " " + layout.index + " vertex_indices");
  if (layout.face_extra) ply.header_line("property int tag");
  for (int v = 0; v < 40; ++v) {
    if (layout.vertex_extra) ply.value("uchar", v % 7);
    ply.value(layout.coordinate, v * 0.5);
    ply.value(layout.coordinate, 1.25 - v);
    ply.value(layout.coordinate, v % 3);
    if (layout.vertex_extra) ply.value("double", v * 3.0);
  }
  for (int f = 0; f < 60; ++f) {
    int corners = layout.polygons && f % 5 == 2 ? 4 + f % 2 : 3;
    if (layout.face_extra) ply.value("float", f * 0.1);
    ply.value(layout.count, corners);
    for (int k = 0; k < corners; ++k) ply.value(layout.index, (f * 7 + k * 3) % 40);
    if (layout.face_extra) ply.value("int", -f);
  }
  return ply.bytes();
}

std::vector<Layout> layouts() {
  std::vector<Layout> all;
  all.push_back({});
  Layout be;
  be.format = "binary_big_endian";
  all.push_back(be);
  Layout wide;
  wide.coordinate = "double";
  wide.index = "uint";
  wide.vertex_extra = true;
  all.push_back(wide);
  Layout polygons;
  polygons.polygons = true;
  all.push_back(polygons);
  Layout odd;
  odd.format = "binary_big_endian";
  odd.count = "ushort";
  odd.index = "short";
  odd.polygons = true;
  all.push_back(odd);
  Layout extra;
  extra.face_extra = true;
  extra.polygons = true;
  all.push_back(extra);
  return all;
}

TEST(PlyBulk, DecodesEveryLayoutLikeTheStreamingReaderWhereverRangesEnd) {
  TempDir dir;
  for (const Layout& layout : layouts()) {
    auto path = dir / "m.ply";
    testing::write_bytes(path, make_ply(layout));
    IndexedMesh expected = testing::read_in_batches(path, 1000);
    ASSERT_EQ(expected.vertices.size(), 40u);
    for (size_t max_bytes : {1, 2, 5, 12, 13, 14, 27, 100, 1 << 20}) {
      SCOPED_TRACE(layout.format + " " + layout.count + " " + layout.index + " range " + std::to_string(max_bytes));
      expect_same_mesh(bulk_read(path, max_bytes), expected);
      // The resident re-encode's decode straight into u32 triples or PLY face records
      // (polygons fanned) and float positions.
      expect_same_mesh(bulk_read(path, max_bytes, 12), expected);
      expect_same_mesh(bulk_read(path, max_bytes, ply_triangle_bytes), expected);
      expect_same_mesh(bulk_read(path, max_bytes, ply_triangle_bytes, true), expected);
      // The out-of-core re-encode's: (id, triple) records and each range's floats.
      expect_same_mesh(bulk_read(path, max_bytes, 16), expected);
    }
  }
}

// The re-encode keeps vertices as floats when the header declares x, y, z float.
TEST(PlyBulk, FloatCoordinatesOnlyWhenXYAndZAreDeclaredFloat) {
  TempDir dir;
  for (const Layout& layout : layouts()) {
    auto path = dir / "m.ply";
    testing::write_bytes(path, make_ply(layout));
    EXPECT_EQ(open_ply_bulk_reader(path)->float_coordinates(), layout.coordinate == "float") << layout.coordinate;
  }
}

TEST(PlyBulk, OnlyPlainBinaryPlyWithVerticesThenFaces) {
  TempDir dir;
  IndexedMesh mesh = testing::small_mesh();
  write_mesh(dir / "m.ply", mesh);
  EXPECT_TRUE(open_ply_bulk_reader(dir / "m.ply"));
  write_mesh(dir / "m.ply.zst", mesh);
  EXPECT_FALSE(open_ply_bulk_reader(dir / "m.ply.zst"));
  write_mesh(dir / "m.obj", mesh);
  EXPECT_FALSE(open_ply_bulk_reader(dir / "m.obj"));
  PlyBuilder ascii("ascii");
  ascii.header_line("element vertex 0");
  for (const char* axis : {"x", "y", "z"}) ascii.header_line(std::string("property float ") + axis);
  testing::write_bytes(dir / "a.ply", ascii.bytes());
  EXPECT_FALSE(open_ply_bulk_reader(dir / "a.ply"));
  // A third element (streaming reader only) and vertices alone (bulk).
  PlyBuilder other("binary_little_endian");
  other.header_line("element vertex 1");
  for (const char* axis : {"x", "y", "z"}) other.header_line(std::string("property float ") + axis);
  testing::write_bytes(dir / "v.ply", other.bytes() + std::string(12, '\0'));
  EXPECT_TRUE(open_ply_bulk_reader(dir / "v.ply"));
  EXPECT_EQ(bulk_read(dir / "v.ply", 5).vertices.size(), 1u);
  other.header_line("element edge 0");
  other.header_line("property int a");
  testing::write_bytes(dir / "e.ply", other.bytes() + std::string(12, '\0'));
  EXPECT_FALSE(open_ply_bulk_reader(dir / "e.ply"));
}

// Every truncation of every layout, at several range sizes: the same message as the
// streaming reader (file, byte offset, what was expected, what was found).
TEST(PlyBulk, TruncatedAnywhereFailsExactlyLikeTheStreamingReader) {
  TempDir dir;
  for (const Layout& layout : layouts()) {
    const std::string bytes = make_ply(layout);
    const size_t header = bytes.find("end_header\n") + 11;
    for (size_t length = header; length < bytes.size(); length += 1 + length % 11) {
      auto path = dir / "t.ply";
      testing::write_bytes(path, bytes.substr(0, length));
      const std::string expected = testing::bad_input_message(path);
      ASSERT_NE(expected.find("file ends inside"), std::string::npos) << expected;
      for (size_t max_bytes : {3, 13, 1 << 20}) {
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes), expected) << "length " << length << " range " << max_bytes;
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes, 12), expected) << "u32, length " << length << " range " << max_bytes;
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes, ply_triangle_bytes), expected)
            << "PLY records, length " << length << " range " << max_bytes;
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes, ply_triangle_bytes, true), expected)
            << "PLY records in place, length " << length << " range " << max_bytes;
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes, 16), expected)
            << "id records, length " << length << " range " << max_bytes;
      }
    }
  }
}

// Bad records (index out of range or negative, too few corners, implausible count,
// non-finite coordinate), each somewhere in the middle: the same message.
TEST(PlyBulk, BadRecordsFailExactlyLikeTheStreamingReader) {
  TempDir dir;
  struct Case {
    Layout layout;
    int face;
    int corners;      // written count
    int index;        // written as every index
    bool nan_vertex;  // vertex 17's y is NaN instead
  };
  std::vector<Case> cases;
  for (const Layout& layout : layouts()) {
    cases.push_back({layout, 33, 3, 40, false});
    // The first and the last record: the in-place check's vector loop leaves both out.
    cases.push_back({layout, 0, 3, 40, false});
    cases.push_back({layout, 59, 3, 41, false});
    cases.push_back({layout, 0, 2, 0, false});
    cases.push_back({layout, 59, 2, 0, false});
    cases.push_back({layout, 34, 3, -1, false});
    cases.push_back({layout, 35, 2, 0, false});
    cases.push_back({layout, 36, 0, 0, false});
    cases.push_back({layout, 0, 3, 0, true});
  }
  for (const Case& c : cases) {
    const Layout& layout = c.layout;
    if (c.index < 0 && (layout.index == "uint")) continue;  // no negative to write
    PlyBuilder ply(layout.format);
    ply.header_line("element vertex 40");
    for (const char* axis : {"x", "y", "z"}) ply.header_line("property " + layout.coordinate + " " + axis);
    ply.header_line("element face 60");
    ply.header_line("property list " + layout.count + " " + layout.index + " vertex_indices");
    for (int v = 0; v < 40; ++v) {
      ply.value(layout.coordinate, v);
      ply.value(layout.coordinate, c.nan_vertex && v == 17 ? std::nan("") : 1.0);
      ply.value(layout.coordinate, 2.0);
    }
    for (int f = 0; f < 60; ++f) {
      int corners = f == c.face ? c.corners : layout.polygons && f % 5 == 2 ? 4 : 3;
      ply.value(layout.count, corners);
      for (int k = 0; k < corners; ++k) ply.value(layout.index, f == c.face ? c.index : (f + k) % 40);
    }
    auto path = dir / "b.ply";
    testing::write_bytes(path, ply.bytes());
    const std::string expected = testing::bad_input_message(path);
    ASSERT_NE(expected.find(": byte "), std::string::npos) << expected;
    for (size_t max_bytes : {7, 13, 1 << 20}) {
      EXPECT_EQ(bulk_bad_input_message(path, max_bytes), expected) << "range " << max_bytes;
      EXPECT_EQ(bulk_bad_input_message(path, max_bytes, 12), expected) << "u32, range " << max_bytes;
      EXPECT_EQ(bulk_bad_input_message(path, max_bytes, ply_triangle_bytes), expected) << "PLY records, range " << max_bytes;
      EXPECT_EQ(bulk_bad_input_message(path, max_bytes, ply_triangle_bytes, true), expected)
          << "PLY records in place, range " << max_bytes;
      EXPECT_EQ(bulk_bad_input_message(path, max_bytes, 16), expected) << "id records, range " << max_bytes;
    }
  }
}

// Records past the header's counts (or any byte but whitespace after the last face):
// the same message as the streaming reader, wherever the ranges end.
TEST(PlyBulk, DataAfterTheLastFaceFailsExactlyLikeTheStreamingReader) {
  TempDir dir;
  for (const Layout& layout : layouts()) {
    const std::string bytes = make_ply(layout);
    const std::string face_line = std::string("element face ");
    const size_t at = bytes.find(face_line) + face_line.size();
    const size_t end = bytes.find('\n', at);
    const uint64_t faces = std::stoull(bytes.substr(at, end - at));
    // One face fewer in the header: the last face becomes data after the last element.
    const std::string fewer = bytes.substr(0, at) + std::to_string(faces - 1) + bytes.substr(end);
    for (const std::string& body : {fewer, bytes + "  \n#"}) {
      auto path = dir / "t.ply";
      testing::write_bytes(path, body);
      const std::string expected = testing::bad_input_message(path);
      ASSERT_NE(expected.find("data after the last element"), std::string::npos) << expected;
      for (size_t max_bytes : {3, 13, 1 << 20}) {
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes), expected) << "range " << max_bytes;
        EXPECT_EQ(bulk_bad_input_message(path, max_bytes, ply_triangle_bytes, true), expected)
            << "PLY records in place, range " << max_bytes;
      }
    }
    auto path = dir / "w.ply";
    testing::write_bytes(path, bytes + "\n");
    for (size_t max_bytes : {3, 13, 1 << 20}) EXPECT_EQ(bulk_bad_input_message(path, max_bytes), "");
  }
  // Without a face element, past the first 4 KiB of trailing spaces too.
  PlyBuilder points("binary_little_endian");
  points.header_line("element vertex 1");
  for (const char* axis : {"x", "y", "z"}) points.header_line(std::string("property float ") + axis);
  auto path = dir / "p.ply";
  testing::write_bytes(path, points.header() + std::string(12, '\0') + std::string(5000, ' ') + "garbage");
  const std::string expected = testing::bad_input_message(path);
  ASSERT_NE(expected.find("data after the last element"), std::string::npos) << expected;
  EXPECT_EQ(bulk_bad_input_message(path, 1 << 20), expected);
}

TEST(PlyBulk, EncodersMakeTheWritersBytes) {
  TempDir dir;
  IndexedMesh mesh = testing::small_mesh();
  mesh.vertices.push_back({1.0 / 3, 1e30, -0.0});
  for (bool double_precision : {false, true}) {
    WriteOptions options;
    options.double_precision = double_precision;
    auto plain = open_mesh_writer(dir / "plain.ply", mesh.vertices.size(), mesh.triangles.size(), options);
    plain->write_vertices(mesh.vertices.data(), mesh.vertices.size());
    plain->write_triangles(mesh.triangles.data(), mesh.triangles.size());
    plain->commit();

    auto bulk = open_mesh_writer(dir / "bulk.ply", mesh.vertices.size(), mesh.triangles.size(), options);
    ASSERT_EQ(bulk->ply_vertex_double(), double_precision);
    std::vector<char> bytes(mesh.vertices.size() * 24 + mesh.triangles.size() * ply_triangle_bytes);
    // In two parts each, as a caller encoding batches would.
    size_t n = encode_ply_vertices(mesh.vertices.data(), 3, double_precision, bytes.data());
    bulk->write_encoded_vertices(bytes.data(), 3);
    n = encode_ply_vertices(mesh.vertices.data() + 3, mesh.vertices.size() - 3, double_precision, bytes.data());
    EXPECT_EQ(n, (mesh.vertices.size() - 3) * (double_precision ? 24 : 12));
    bulk->write_encoded_vertices(bytes.data(), mesh.vertices.size() - 3);
    uint64_t max_index = 0;
    n = encode_ply_triangles(mesh.triangles.data(), 1, bytes.data(), max_index);
    EXPECT_EQ(n, ply_triangle_bytes);
    bulk->write_encoded_triangles(bytes.data(), 1, max_index);
    std::vector<uint32_t> narrow;
    for (size_t t = 1; t < mesh.triangles.size(); ++t)
      for (uint64_t v : mesh.triangles[t]) narrow.push_back(uint32_t(v));
    max_index = 0;
    encode_ply_triangles(narrow.data(), mesh.triangles.size() - 1, bytes.data(), max_index);
    EXPECT_EQ(max_index, 5u);
    bulk->write_encoded_triangles(bytes.data(), mesh.triangles.size() - 1, max_index);
    bulk->commit();
    EXPECT_EQ(testing::read_bytes(dir / "bulk.ply"), testing::read_bytes(dir / "plain.ply"));
    // Both use the encoders, so the body is also checked against bytes made by hand.
    std::string body;
    for (const Point& p : mesh.vertices) {
      for (double c : p) {
        if (double_precision) testing::put(body, c);
        else testing::put(body, float(c));
      }
    }
    for (const Triangle& t : mesh.triangles) {
      testing::put(body, uint8_t{3});
      for (uint64_t v : t) testing::put(body, int32_t(v));
    }
    const std::string file = testing::read_bytes(dir / "bulk.ply");
    ASSERT_GE(file.size(), body.size());
    EXPECT_EQ(file.substr(file.size() - body.size()), body);
  }
}

TEST(PlyBulk, EncodedWritesKeepTheWritersChecks) {
  TempDir dir;
  auto ply = open_mesh_writer(dir / "m.ply", 3, 1);
  char bytes[64] = {};
  EXPECT_THROW(ply->write_encoded_triangles(bytes, 1, 0), Error);  // before the vertices
  ply->write_encoded_vertices(bytes, 3);
  EXPECT_THROW(ply->write_encoded_vertices(bytes, 1), Error);      // more than declared
  EXPECT_THROW(ply->write_encoded_triangles(bytes, 1, 3), Error);  // index past the vertices
  EXPECT_THROW(ply->write_encoded_triangles(bytes, 2, 0), Error);  // more than declared
  auto obj = open_mesh_writer(dir / "m.obj", 3, 1);
  EXPECT_FALSE(obj->ply_vertex_double());
  EXPECT_THROW(obj->write_encoded_vertices(bytes, 3), Error);
}

}  // namespace
}  // namespace qemflow::io
