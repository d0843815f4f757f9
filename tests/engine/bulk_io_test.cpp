// The re-encode with binary PLY on both ends: the I/O thread only moves bytes (the
// bulk reader's ranges in, encoded PLY bytes out). Its output must be the PLY
// writer's bytes for the same mesh, in every mode (resident, blocks in memory or in
// scratch, out-of-core dereference), and bad binary input must fail with the
// streaming reader's exact message, leaving nothing behind.
#include <gtest/gtest.h>

#include <fstream>

#include "engine/reencode.hpp"
#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"
#include "reencode_refusal.hpp"
#include "test_support.hpp"
#include "util/error.hpp"

namespace qemflow::engine {
namespace {

using qemflow::testing::TempDir;

using qemflow::testing::file_bytes;

struct Mode {
  const char* name;
  uint64_t budget;
  LoadOptions load;
};

TEST(BulkIo, PlyOutputIsTheWritersBytesInEveryMode) {
  TempDir dir;
  gen::GenOptions gen_options;
  gen_options.faces = 30'000;
  gen_options.shape = "blob";
  gen::generate_to_file(gen_options, dir / "in.ply");
  const io::IndexedMesh input = io::read_mesh(dir / "in.ply");
  const Mode modes[] = {
      {"resident, blocks in memory", 256ull << 20, {.faces_per_block = 1'000}},
      {"out of core, tiny windows", 64ull << 20,
       {.faces_per_block = 2'000, .window_vertices = 997, .range_faces = 1'231, .force_out_of_core = true}},
  };
  for (const Mode& mode : modes) {
    SCOPED_TRACE(mode.name);
    Governor governor(mode.budget, 0);
    ReencodeOptions options{.input = dir / "in.ply", .output = dir / "out.ply", .scratch_dir = dir.path()};
    options.load = mode.load;
    auto result = run_reencode(governor, options, {});
    const io::IndexedMesh output = io::read_mesh(dir / "out.ply");
    EXPECT_TRUE(output.vertices == input.vertices);
    EXPECT_EQ(output.triangles.size(), input.triangles.size());
    // The same vertices and triangles through the PLY writer itself: the same bytes.
    io::write_mesh(dir / "again.ply", output);
    EXPECT_EQ(file_bytes(dir / "out.ply"), file_bytes(dir / "again.ply"));
    EXPECT_EQ(result.report["output_bytes"].get<uint64_t>(), std::filesystem::file_size(dir / "out.ply"));
    std::filesystem::remove(dir / "out.ply");
  }
}

// A binary PLY of 6 vertices and 5 triangles; `cut` bytes dropped from the end, or
// face 3's third index set to `bad_index`.
std::string small_binary_ply(size_t cut, int32_t bad_index = -2) {
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
      "property float z\nelement face 5\nproperty list uchar int vertex_indices\nend_header\n";
  for (int v = 0; v < 6; ++v) {
    float xyz[3] = {float(v), float(v * v), 1.0f};
    bytes.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
  }
  for (int f = 0; f < 5; ++f) {
    bytes.push_back(3);
    int32_t abc[3] = {f, f + 1, f == 3 && bad_index != -2 ? bad_index : (f + 2) % 6};
    bytes.append(reinterpret_cast<const char*>(abc), sizeof abc);
  }
  return bytes.substr(0, bytes.size() - cut);
}

TEST(BulkIo, BadBinaryInputFailsWithTheReadersMessageAndLeavesNothing) {
  TempDir dir, scratch_dir;
  struct Case {
    std::string bytes;
    const char* problem;
  };
  const Case cases[] = {
      {small_binary_ply(7), "file ends inside face 4 of 5"},
      {small_binary_ply(65 + 30), "file ends inside vertex 3 of 6"},
      {small_binary_ply(0, 6), "face 3 has vertex index 6 but the file has 6 vertices"},
      {small_binary_ply(0, -1), "face 3 has vertex index -1"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.problem);
    {
      std::ofstream out(dir / "bad.ply", std::ios::binary);
      out << c.bytes;
    }
    std::string expected;
    try {
      io::read_mesh(dir / "bad.ply");
    } catch (const Error& e) {
      expected = e.what();
    }
    ASSERT_NE(expected.find(c.problem), std::string::npos) << expected;
    testing::expect_reencode_refused(dir / "bad.ply", dir / "out.ply", scratch_dir.path(),
                                     [&](const Error& e) { EXPECT_EQ(std::string(e.what()), expected); });
  }
}

}  // namespace
}  // namespace qemflow::engine
