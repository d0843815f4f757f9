// generate_to_file and the `qemflow gen` command: what reaches the disk is the
// generated mesh, in the format the name asks for, and nothing on failure.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <iterator>

#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"
#include "test_support.hpp"

namespace qemflow::gen {
namespace {

using testing::cli_path;
using testing::run_command;
using testing::TempDir;

using testing::file_bytes;

TEST(GenerateToFile, WritesTheGeneratedMeshInEveryFormat) {
  TempDir dir;
  const GenOptions options{"figure", 3000, 9};
  const io::IndexedMesh expected = generate_in_memory(options);
  for (const char* name : {"m.ply", "m.obj", "m.ply.zst"}) {
    const GenStats stats = generate_to_file(options, dir / name);
    EXPECT_EQ(stats.face_count, 3000u);
    EXPECT_EQ(stats.vertex_count, expected.vertices.size());
    EXPECT_GT(stats.bytes_written, 0u);
    const io::IndexedMesh read = io::read_mesh(dir / name);
    EXPECT_EQ(read.triangles, expected.triangles) << name;
    ASSERT_EQ(read.vertices.size(), expected.vertices.size()) << name;
    for (size_t v = 0; v < read.vertices.size(); ++v)
      for (int c = 0; c < 3; ++c)  // written as float by default (OBJ: shortest text of that float)
        ASSERT_EQ(static_cast<float>(read.vertices[v][c]), static_cast<float>(expected.vertices[v][c]))
            << name << " vertex " << v;
  }
}

TEST(GenCommand, WritesIdenticalFilesAndPrintsASummary) {
  TempDir dir;
  std::string output;
  const std::string gen = cli_path().string() + " gen ";
  ASSERT_EQ(run_command(gen + (dir / "a.ply").string() + " --faces 20k --shape terrain --seed 4", &output), 0)
      << output;
  EXPECT_NE(output.find("terrain, "), std::string::npos) << output;
  EXPECT_NE(output.find("20000 faces"), std::string::npos) << output;
  ASSERT_EQ(run_command(gen + (dir / "b.ply").string() + " --faces 20000 --shape terrain --seed 4 --quiet", &output),
            0)
      << output;
  EXPECT_EQ(output, "");
  EXPECT_EQ(file_bytes(dir / "a.ply"), file_bytes(dir / "b.ply"));
  ASSERT_EQ(run_command(gen + (dir / "c.ply").string() + " --faces 20000 --shape terrain --seed 5 --quiet"), 0);
  EXPECT_NE(file_bytes(dir / "a.ply"), file_bytes(dir / "c.ply"));
}

// --shuffle: the same surface (every face's corner positions, in the same rotation),
// the vertices and the faces each in a new order, a pure function of the seed.
TEST(GenCommand, ShuffleKeepsTheSurfaceInANewOrder) {
  TempDir dir;
  const std::string gen = cli_path().string() + " gen ";
  for (const char* name : {"s1.ply", "s1b.ply"})
    ASSERT_EQ(run_command(gen + (dir / name).string() + " --faces 20000 --shuffle 1 --quiet"), 0);
  ASSERT_EQ(run_command(gen + (dir / "s2.ply").string() + " --faces 20000 --shuffle 2 --quiet"), 0);
  EXPECT_EQ(file_bytes(dir / "s1.ply"), file_bytes(dir / "s1b.ply"));
  EXPECT_NE(file_bytes(dir / "s1.ply"), file_bytes(dir / "s2.ply"));
  const io::IndexedMesh plain = generate_in_memory({"blob", 20000, 1});
  const io::IndexedMesh shuffled = io::read_mesh(dir / "s1.ply");
  ASSERT_EQ(shuffled.vertices.size(), plain.vertices.size());
  ASSERT_EQ(shuffled.triangles.size(), plain.triangles.size());
  using Corners = std::array<std::array<float, 3>, 3>;
  auto corners = [](const io::IndexedMesh& m) {
    std::vector<Corners> out;
    for (const Triangle& t : m.triangles) {
      Corners c;
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a) c[k][a] = static_cast<float>(m.vertices[t[k]][a]);
      out.push_back(c);
    }
    return out;
  };
  const std::vector<Corners> in_order = corners(shuffled);
  std::vector<Corners> a = corners(plain), b = in_order;
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());
  EXPECT_TRUE(a == b) << "not the same surface";
  // Really reordered: few faces and vertices keep their place.
  size_t same_faces = 0, same_vertices = 0;
  for (size_t f = 0; f < plain.triangles.size(); ++f) same_faces += plain.triangles[f] == shuffled.triangles[f];
  for (size_t v = 0; v < plain.vertices.size(); ++v)
    same_vertices += static_cast<float>(plain.vertices[v][0]) == static_cast<float>(shuffled.vertices[v][0]);
  EXPECT_LT(same_faces, plain.triangles.size() / 100);
  EXPECT_LT(same_vertices, plain.vertices.size() / 100);
}

TEST(GenCommand, RejectsBadArgumentsAsUsageErrorsWithoutOutput) {
  TempDir dir;
  const std::string out = (dir / "x.ply").string();
  const std::string gen = cli_path().string() + " gen " + out;
  std::string output;
  EXPECT_EQ(run_command(gen + " --faces 10000 --shape teapot", &output), 2);
  EXPECT_NE(output.find("blob, terrain, figure"), std::string::npos) << output;
  EXPECT_EQ(run_command(gen + " --faces 99", &output), 2);
  EXPECT_NE(output.find("at least 200"), std::string::npos) << output;
  EXPECT_EQ(run_command(gen + " --faces 3Q", &output), 2);
  EXPECT_EQ(run_command(gen, &output), 2);  // --faces is required
  EXPECT_FALSE(std::filesystem::exists(out));
}

}  // namespace
}  // namespace qemflow::gen
