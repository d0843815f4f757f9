// End-to-end checks of `qemflow info` and `qemflow compare` on files.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>

#include "io/indexed_mesh.hpp"
#include "measure_test_meshes.hpp"
#include "test_support.hpp"

namespace qemflow::measure {
namespace {

using qemflow::testing::cli_path;
using qemflow::testing::run_command;
using qemflow::testing::TempDir;

void write(const std::filesystem::path& path, const testing::TestMesh& m) {
  io::WriteOptions options;
  options.double_precision = true;
  io::write_mesh(path, {m.points, m.triangles}, options);
}

nlohmann::json run_json(const std::string& args) {
  std::string out;
  const int status = run_command(cli_path().string() + " " + args, &out);
  EXPECT_EQ(status, 0) << out;
  // The JSON object is stdout; run_command merges stderr, which may carry log lines.
  const auto open = out.find("{\n"), close = out.rfind("\n}");
  if (open == std::string::npos || close == std::string::npos) return nlohmann::json::parse(out);
  return nlohmann::json::parse(out.substr(open, close + 2 - open));
}

TEST(CompareCli, CubeMovedAlongAnAxisAsJson) {
  TempDir dir;
  write(dir / "a.ply", testing::cube());
  write(dir / "b.obj", testing::cube({0.25, 0, 0}));
  const auto j = run_json("compare " + (dir / "a.ply").string() + " " + (dir / "b.obj").string() +
                          " --json --samples 20000");
  EXPECT_DOUBLE_EQ(j["distances"]["symmetric"]["absolute"]["hausdorff"].get<double>(), 0.25);
  EXPECT_DOUBLE_EQ(j["distances"]["a_to_b"]["relative"]["hausdorff"].get<double>(), 0.25 / std::sqrt(3.0));
  EXPECT_DOUBLE_EQ(j["bbox_diagonal"].get<double>(), std::sqrt(3.0));
  EXPECT_EQ(j["topology"]["original"]["faces"], 12);
  EXPECT_EQ(j["topology"]["simplified"]["boundary_edges"], 0);
  EXPECT_EQ(j["topology"]["simplified"]["connected_components"], 1);
  EXPECT_EQ(j["flipped_faces"], 0);
  EXPECT_EQ(j["samples"]["b_to_a"]["vertex"], 8);
}

TEST(CompareCli, ThreadCountDoesNotChangeTheNumbers) {
  TempDir dir;
  auto a = testing::icosphere(4);
  write(dir / "a.ply.zst", a);
  write(dir / "b.ply", testing::icosphere(2, 1.001));
  const std::string args = "compare " + (dir / "a.ply.zst").string() + " " + (dir / "b.ply").string() +
                           " --json --samples 50000 --chunk-faces 1024";
  auto one = run_json(args + " --threads 1"), two = run_json(args + " --threads 2");
  one.erase("seconds");
  two.erase("seconds");
  EXPECT_EQ(one.dump(), two.dump());
}

TEST(CompareCli, TableAndErrors) {
  TempDir dir;
  write(dir / "a.ply", testing::cube());
  std::string out;
  EXPECT_EQ(run_command(cli_path().string() + " compare " + (dir / "a.ply").string() + " " +
                            (dir / "a.ply").string() + " --samples 1000",
                        &out),
            0);
  EXPECT_NE(out.find("hausdorff"), std::string::npos) << out;
  EXPECT_NE(out.find("non-manifold vertices"), std::string::npos) << out;
  EXPECT_EQ(run_command(cli_path().string() + " compare " + (dir / "a.ply").string(), &out), 2) << out;
  EXPECT_EQ(run_command(cli_path().string() + " compare " + (dir / "a.ply").string() + " " +
                            (dir / "missing.ply").string(),
                        &out),
            3)
      << out;
  std::ofstream(dir / "bad.ply") << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                    "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
  EXPECT_EQ(run_command(cli_path().string() + " compare " + (dir / "a.ply").string() + " " +
                            (dir / "bad.ply").string(),
                        &out),
            3)
      << out;
  EXPECT_NE(out.find("bad.ply"), std::string::npos) << out;
}

TEST(InfoCli, CountsFormatAndPasses) {
  TempDir dir;
  auto m = testing::icosphere(5);
  m.triangles.resize(m.triangles.size() - 1);  // open a hole: 3 boundary edges
  write(dir / "s.ply.zst", m);
  const auto j = run_json("info " + (dir / "s.ply.zst").string() + " --json --mem-cap 1M");
  EXPECT_EQ(j["vertices"], m.points.size());
  EXPECT_EQ(j["faces"], m.triangles.size());
  EXPECT_EQ(j["boundary_edges"], 3);
  EXPECT_EQ(j["non_manifold_edges"], 0);
  EXPECT_EQ(j["zstd"], true);
  EXPECT_GT(j["passes"].get<int>(), 1);
  EXPECT_NEAR(j["bbox"]["diagonal"].get<double>(), 2 * std::sqrt(3.0), 0.05);
  EXPECT_FALSE(j.contains("connected_components"));
  const auto full = run_json("info " + (dir / "s.ply.zst").string() + " --json --full");
  EXPECT_EQ(full["connected_components"], 1);
  EXPECT_EQ(full["passes"], 1);

  std::string out;
  EXPECT_EQ(run_command(cli_path().string() + " info", &out), 2) << out;
  EXPECT_EQ(run_command(cli_path().string() + " info " + (dir / "none.ply").string(), &out), 3) << out;
}

TEST(InfoCli, BunnyMatchesTheManifest) {
  const auto bunny = qemflow::testing::shared_mesh("stanford-bunny");
  QEMFLOW_REQUIRE_SHARED_MESH(bunny);
  const auto j = run_json("info " + bunny.string() + " --json");
  EXPECT_EQ(j["vertices"], 35947);
  EXPECT_EQ(j["faces"], 69451);
  EXPECT_EQ(j["boundary_edges"], 223);
  EXPECT_EQ(j["non_manifold_edges"], 0);
  EXPECT_EQ(j["format"], "PLY binary little-endian + zstd");
}

}  // namespace
}  // namespace qemflow::measure
