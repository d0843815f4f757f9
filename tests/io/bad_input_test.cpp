// Every reader on malformed input: Error(bad_input), one line "FILE: PLACE: PROBLEM"
// naming the byte offset (binary) or line (text) where it went wrong.
#include <gtest/gtest.h>

#include "io/mesh_stream.hpp"
#include "io_test_support.hpp"
#include "ply_builder.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;
using testing::PlyBuilder;

// Checks that reading `bytes` stored as `name` fails with a message that starts
// with the file name and contains `expected`.
void expect_bad(const std::string& bytes, const std::string& name, const std::string& expected) {
  TempDir dir;
  auto path = dir / name;
  testing::write_bytes(path, bytes);
  std::string message = testing::bad_input_message(path);
  EXPECT_EQ(message.rfind(path.string() + ": ", 0), 0u) << message;
  EXPECT_NE(message.find(expected), std::string::npos) << "message: " << message << "\nexpected: " << expected;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
}

// 5 float vertices, 4 triangles, "list uchar int", binary little-endian.
struct BinaryPly {
  std::string header;
  std::string vertices;
  std::string faces;
  std::string bytes() const { return header + vertices + faces; }
  size_t vertex_offset(int v) const { return header.size() + 12 * v; }
  size_t face_offset(int f) const { return header.size() + vertices.size() + 13 * f; }
};

BinaryPly binary_ply(const std::string& index_type = "int") {
  PlyBuilder head("binary_little_endian");
  head.header_line("element vertex 5");
  for (const char* axis : {"x", "y", "z"}) head.header_line(std::string("property float ") + axis);
  head.header_line("element face 4");
  head.header_line("property list uchar " + index_type + " vertex_indices");
  BinaryPly ply;
  ply.header = head.header();
  for (int v = 0; v < 5; ++v) {
    for (float c : {float(v), 1.0f, 2.0f}) testing::put(ply.vertices, c);
  }
  for (int f = 0; f < 4; ++f) {
    testing::put(ply.faces, uint8_t{3});
    for (int k = 0; k < 3; ++k) testing::put(ply.faces, int32_t((f + k) % 5));
  }
  return ply;
}

std::string ascii_ply(const std::string& body) {
  // Header is 10 lines; the body starts on line 11.
  return "ply\nformat ascii 1.0\ncomment x\nelement vertex 3\nproperty float x\nproperty float y\n"
         "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" +
         body;
}

std::string header_with(const std::string& lines) { return "ply\nformat binary_little_endian 1.0\n" + lines; }

TEST(BadInput, MissingFileAndDirectory) {
  TempDir dir;
  std::string message = testing::bad_input_message(dir / "absent.ply");
  EXPECT_NE(message.find("absent.ply: cannot open"), std::string::npos) << message;
  std::filesystem::create_directory(dir / "folder.ply");
  message = testing::bad_input_message(dir / "folder.ply");
  EXPECT_NE(message.find("folder.ply: cannot open"), std::string::npos) << message;
}

TEST(BadInput, UnknownExtensionIsAUsageError) {
  TempDir dir;
  testing::write_bytes(dir / "mesh.stl", "solid");
  try {
    open_mesh_reader(dir / "mesh.stl");
    FAIL() << "no error";
  } catch (const Error& error) {
    EXPECT_EQ(error.kind(), ErrorKind::usage);
    EXPECT_NE(std::string(error.what()).find("mesh.stl"), std::string::npos);
  }
}

TEST(BadInput, PlyHeaderErrorsNameTheLine) {
  expect_bad("", "empty.ply", "line 1: not a PLY file");
  expect_bad("PLY\nformat ascii 1.0\nend_header\n", "m.ply", "line 1: not a PLY file");
  expect_bad(std::string(100000, 'x'), "m.ply", "line 1: ");
  expect_bad("ply\nformat binary_middle_endian 1.0\nend_header\n", "m.ply",
             "line 2: unknown PLY format 'binary_middle_endian'");
  expect_bad("ply\nformat ascii 2.0\nend_header\n", "m.ply", "line 2: unsupported PLY version");
  expect_bad("ply\nelement vertex 1\nproperty float x\nend_header\n", "m.ply", "no format line");
  expect_bad(header_with("element vertex 3\nproperty float x\n"), "m.ply", "line 4: header has no end_header");
  expect_bad(header_with("element vertex\nend_header\n"), "m.ply", "line 3: element line must be");
  expect_bad(header_with("element vertex -5\nend_header\n"), "m.ply", "line 3: element count '-5'");
  expect_bad(header_with("element vertex 1\nproperty float\nend_header\n"), "m.ply",
             "line 4: property line must be");
  expect_bad(header_with("property float x\nend_header\n"), "m.ply", "line 3: property before any element");
  expect_bad(header_with("element vertex 1\nproperty float3 x\nend_header\n"), "m.ply",
             "line 4: unknown property type 'float3'");
  expect_bad(header_with("element vertex 1\nproperty float x\nproperty float x\nend_header\n"), "m.ply",
             "line 5: property 'x' declared twice");
  expect_bad(header_with("element vertex 1\nproperty list float int x\nend_header\n"), "m.ply",
             "line 4: list count type 'float' is not an integer type");
  expect_bad(header_with("element vertex 1\nproperty list uchar int\nend_header\n"), "m.ply",
             "line 4: list property must be");
  expect_bad(header_with("bogus line\nend_header\n"), "m.ply", "line 3: unknown header keyword 'bogus'");
}

TEST(BadInput, PlyUnsupportedLayouts) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  expect_bad(header_with("element face 0\nproperty list uchar int vertex_indices\nend_header\n"), "m.ply",
             "no 'vertex' element");
  expect_bad(header_with("element vertex 1\nproperty float x\nproperty float y\nend_header\n"), "m.ply",
             "line 3: vertex element has no 'z' property");
  expect_bad(header_with("element vertex 1\nproperty list uchar float x\nproperty float y\nproperty float z\n"
                         "end_header\n"),
             "m.ply", "line 3: vertex property 'x' is a list");
  expect_bad(header_with("element vertex 1\n" + xyz + "element face 1\nproperty int vertex_indices\nend_header\n"),
             "m.ply", "line 7: face property 'vertex_indices' is not a list");
  expect_bad(header_with("element vertex 1\n" + xyz +
                         "element face 1\nproperty list uchar float vertex_indices\nend_header\n"),
             "m.ply", "line 7: face property 'vertex_indices' has non-integer type float");
  expect_bad(header_with("element vertex 1\n" + xyz + "element face 1\nproperty list uchar int corners\nend_header\n"),
             "m.ply", "line 7: face element has no 'vertex_indices'");
  expect_bad(header_with("element face 1\nproperty list uchar int vertex_indices\nelement vertex 1\n" + xyz +
                         "end_header\n"),
             "m.ply", "line 3: the face element comes before the vertex element");
}

TEST(BadInput, BinaryTruncationNamesOffsetAndWhatWasExpected) {
  BinaryPly ply = binary_ply();
  std::string bytes = ply.bytes();
  expect_bad(bytes.substr(0, ply.vertex_offset(3) + 5), "m.ply",
             "byte " + std::to_string(ply.vertex_offset(3)) +
                 ": file ends inside vertex 3 of 5 (needed 12 more bytes, found 5)");
  expect_bad(bytes.substr(0, ply.vertex_offset(5)), "m.ply",
             "byte " + std::to_string(ply.vertex_offset(5)) + ": file ends inside face 0 of 4");
  expect_bad(bytes.substr(0, ply.face_offset(2) + 7), "m.ply",
             "byte " + std::to_string(ply.face_offset(2)) + ": file ends inside face 2 of 4");
  // The .zst of a truncated PLY says the same (offsets are in the decompressed stream).
  expect_bad(testing::zstd_compress(bytes.substr(0, ply.face_offset(3) + 1)), "m.ply.zst",
             "byte " + std::to_string(ply.face_offset(3)) + ": file ends inside face 3 of 4");
}

// More records than the header declares: a face count cut short would otherwise lose
// the faces past it without a word. Whitespace after the last element is fine.
TEST(BadInput, DataAfterTheLastElementNamesItsOffset) {
  BinaryPly ply = binary_ply();
  const std::string extra_face = ply.faces.substr(0, 13);
  expect_bad(ply.bytes() + extra_face, "m.ply",
             "byte " + std::to_string(ply.face_offset(4)) +
                 ": data after the last element (the header declares 4 face; are its counts wrong?)");
  expect_bad(testing::zstd_compress(ply.bytes() + "\n" + extra_face), "m.ply.zst",
             "byte " + std::to_string(ply.face_offset(4) + 1) + ": data after the last element");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 2 1\n"), "a.ply",
             "line 15: data after the last element (the header declares 1 face");
  // A file without faces: every trailing byte is looked at, not just the first few KiB.
  PlyBuilder vertices_only("binary_little_endian");
  vertices_only.header_line("element vertex 1");
  for (const char* axis : {"x", "y", "z"}) vertices_only.header_line(std::string("property float ") + axis);
  const std::string point = vertices_only.header() + std::string(12, '\0') + std::string(5000, ' ') + "garbage";
  const size_t garbage_at = point.size() - 7;
  expect_bad(point, "p.ply", "byte " + std::to_string(garbage_at) + ": data after the last element");
  expect_bad(testing::zstd_compress(point), "p.ply.zst", "byte " + std::to_string(garbage_at) + ": data after");
  TempDir dir;
  for (const auto& [name, bytes] : std::vector<std::pair<std::string, std::string>>{
           {"m.ply", ply.bytes() + "\n"}, {"a.ply", ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n\n  \n")}}) {
    testing::write_bytes(dir / name, bytes);
    EXPECT_NO_THROW(testing::read_in_batches(dir / name, 3)) << name;
  }
}

TEST(BadInput, BinaryIndexOutOfRangeNamesFaceAndOffset) {
  for (std::string type : {"int", "uint", "short"}) {
    BinaryPly ply = binary_ply(type);
    if (type == "short") {  // rebuild faces with 2-byte indices
      ply.faces.clear();
      for (int f = 0; f < 4; ++f) {
        testing::put(ply.faces, uint8_t{3});
        for (int k = 0; k < 3; ++k) testing::put(ply.faces, int16_t(f == 1 && k == 2 ? 99 : k));
      }
      expect_bad(ply.bytes(), "m.ply",
                 "byte " + std::to_string(ply.header.size() + 60 + 7) +
                     ": face 1 has vertex index 99 but the file has 5 vertices");
      continue;
    }
    int32_t bad = 99;
    std::memcpy(ply.faces.data() + 13 + 1 + 4, &bad, 4);
    expect_bad(ply.bytes(), "m.ply",
               "byte " + std::to_string(ply.face_offset(1)) +
                   ": face 1 has vertex index 99 but the file has 5 vertices");
    bad = -1;
    std::memcpy(ply.faces.data() + 3 * 13 + 1, &bad, 4);
    std::memcpy(ply.faces.data() + 13 + 1 + 4, "\0\0\0\0", 4);
    expect_bad(ply.bytes(), "m.ply",
               "byte " + std::to_string(ply.face_offset(3)) + ": face 3 has vertex index " +
                   (type == "int" ? "-1" : "4294967295"));
  }
}

TEST(BadInput, BinaryNonFiniteCoordinate) {
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    BinaryPly ply = binary_ply();
    std::memcpy(ply.vertices.data() + 2 * 12 + 4, &bad, 4);
    expect_bad(ply.bytes(), "m.ply",
               "byte " + std::to_string(ply.vertex_offset(2)) + ": vertex 2 has a non-finite coordinate");
  }
}

TEST(BadInput, BinaryFacesWithFewerThanThreeVertices) {
  for (uint8_t count : {0, 1, 2}) {
    BinaryPly ply = binary_ply();
    ply.faces = ply.faces.substr(0, 26);
    testing::put(ply.faces, count);
    for (int k = 0; k < count; ++k) testing::put(ply.faces, int32_t(0));
    expect_bad(ply.bytes(), "m.ply",
               "byte " + std::to_string(ply.face_offset(2)) + ": face 2 has " + std::to_string(count) +
                   " vertices (a face needs at least 3)");
  }
}

TEST(BadInput, AsciiErrorsNameTheLine) {
  expect_bad(ascii_ply("0 0 0\n1 0 0\n"), "a.ply", "line 12: file ends inside vertex 2 of 3");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 1\n"), "a.ply", "line 14: file ends inside face 0 of 1");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"), "a.ply",
             "line 14: face 0 has vertex index 7 but the file has 3 vertices");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"), "a.ply", "line 14: face 0 has vertex index -1");
  expect_bad(ascii_ply("0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n"), "a.ply",
             "line 12: vertex 1 has a non-finite coordinate");
  expect_bad(ascii_ply("0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"), "a.ply", "line 12: vertex 1 has a non-finite");
  expect_bad(ascii_ply("0 0 0\n1 abc 0\n0 1 0\n3 0 1 2\n"), "a.ply", "line 12: coordinate 'abc' is not a number");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n2 0 1\n"), "a.ply", "line 14: face 0 has 2 vertices");
  expect_bad(ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"), "a.ply", "line 14: vertex index '1.5' is not an integer");
}

// Values are taken wherever they are, so a line short of values shifts every value
// after it and the error surfaces records later; the message also names the first
// record that did not fit its line.
TEST(BadInput, AsciiErrorsNameTheFirstRecordNotOnItsOwnLine) {
  expect_bad(ascii_ply("0 0 0\n1 0\n0 1 0\n3 0 1 2\n"), "a.ply",
             "line 14: face 0 has 0 vertices (a face needs at least 3) (vertex 1 of 3 starts on line 12 and ends on "
             "line 13: a line with too few or too many values?)");
  // Too many: the extra value starts the next record.
  expect_bad(ascii_ply("0 0 0 7\n1 0 0\n0 1 0\n3 0 1 2\n"), "a.ply", "(vertex 1 of 3 starts on line 11 and ends on line 12");
  // Errors on well-formed lines carry no such note.
  TempDir dir;
  testing::write_bytes(dir / "a.ply", ascii_ply("0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"));
  EXPECT_EQ(testing::bad_input_message(dir / "a.ply").find("starts on line"), std::string::npos);
  // A polygon cut by a batch's end resumes on its own line: no note either (8 corners make
  // 6 triangles, read here 3 elements at a time).
  testing::write_bytes(dir / "p.ply",
                       "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
                       "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                       "0 0 0\n1 0 0\n2 1 0\n2 2 0\n1 3 0\n0 3 0\n-1 2 0\n-1 1 0\n8 0 1 2 3 4 5 6 7\n3 0 1 9\n");
  const std::string polygon_message = testing::bad_input_message(dir / "p.ply");
  EXPECT_NE(polygon_message.find("line 19: face 1 has vertex index 9"), std::string::npos) << polygon_message;
  EXPECT_EQ(polygon_message.find("starts on line"), std::string::npos) << polygon_message;
  // A record across lines with the right values is read, as other readers read it.
  testing::write_bytes(dir / "w.ply", ascii_ply("0 0\n0\n1 0 0\n0 1 0\n3 0 1\n2\n"));
  EXPECT_EQ(testing::read_in_batches(dir / "w.ply", 3).triangles.size(), 1u);
}

TEST(BadInput, CorruptedZstd) {
  BinaryPly ply = binary_ply();
  std::string packed = testing::zstd_compress(ply.bytes());
  expect_bad(packed.substr(0, packed.size() - 3), "m.ply.zst", "zstd stream is truncated");
  expect_bad("this is not zstd at all", "m.ply.zst", "corrupted zstd data");
  // Flipping bits inside the frame is caught by zstd (the frame has no checksum
  // here, so any damage is enough to check that errors surface as bad_input).
  std::string damaged = packed;
  damaged[4] ^= 0x5A;
  expect_bad(damaged, "m.ply.zst", "zstd");
}

TEST(BadInput, ObjErrorsNameTheLine) {
  expect_bad("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "m.obj",
             "line 4: face 0 has vertex index 4 but only 3 vertices are defined before it");
  expect_bad("v 0 0 0\nf 1 2 3\nv 1 0 0\nv 0 1 0\n", "m.obj", "line 2: face 0 has vertex index 2");
  expect_bad("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 -2 -1\n", "m.obj", "line 4: face 0 has vertex index -4");
  expect_bad("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "m.obj", "line 4: face 0 has vertex reference '0'");
  expect_bad("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 2\n", "m.obj", "line 4: face 0 has vertex reference 'x'");
  expect_bad("v 0 0 0\nv 1 0 0\nf 1 2\n", "m.obj", "line 3: face 0 has 2 vertices (a face needs at least 3)");
  expect_bad("# c\nv 0 0\n", "m.obj", "line 2: vertex 0 has fewer than 3 coordinates");
  expect_bad("v 0 0 0\nv 1 nan 0\n", "m.obj", "line 2: vertex 1 has a non-finite coordinate");
  expect_bad("v 0 0 0\nv 1 1e999 0\n", "m.obj", "line 2: vertex 1 has a non-finite coordinate");
  expect_bad("v 0 0 0\nv 1 zero 0\n", "m.obj", "line 2: vertex 1 has coordinate 'zero' which is not a number");
  expect_bad(testing::zstd_compress("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"), "m.obj.zst",
             "line 4: face 0 has vertex index 9");
}

}  // namespace
}  // namespace qemflow::io
