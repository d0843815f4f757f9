// The command line's own checks (DESIGN.md §6): a bad flag value or command is a usage
// error (exit 2) with a message naming it, a scratch path that is a file is a resource
// error naming that, and --trace gives a trace file in every mode.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tests/test_support.hpp"

namespace qemflow::testing {
namespace {

std::string q() { return cli_path().string(); }

std::filesystem::path small_mesh(const TempDir& dir) {
  const auto mesh = dir / "blob.ply";
  std::string out;
  EXPECT_EQ(run_command(q() + " gen " + mesh.string() + " --faces 2000 --quiet", &out), 0) << out;
  return mesh;
}

// Runs `qemflow simplify MESH DIR/out.ply ARGS`; expects `code`, `message` in its output
// and no output file.
void expect_simplify_refused(const TempDir& dir, const std::string& args, int code, const std::string& message) {
  const auto mesh = small_mesh(dir);
  std::string out;
  EXPECT_EQ(run_command(q() + " simplify " + mesh.string() + " " + (dir / "out.ply").string() + " " + args, &out), code)
      << args << "\n" << out;
  EXPECT_NE(out.find(message), std::string::npos) << args << "\n" << out;
  EXPECT_FALSE(std::filesystem::exists(dir / "out.ply")) << args;
}

TEST(CliUsage, ClustersMustBeAutoOrAPositiveCount) {
  TempDir dir;
  for (const std::string bad : {"x", "-3", "0", "99999999999"})
    expect_simplify_refused(dir, "--ratio 0.5 --clusters " + bad, 2, "--clusters must be auto or a patch count");
}

TEST(CliUsage, TargetOfZeroFacesIsRefused) {
  TempDir dir;
  expect_simplify_refused(dir, "--target-faces 0", 2, "--target-faces must be at least 1");
}

TEST(CliUsage, AScratchPathThatIsAFileIsNamedAsSuch) {
  TempDir dir;
  const auto file = dir / "not_a_dir";
  std::ofstream(file) << "x";
  expect_simplify_refused(dir, "--ratio 0.5 --scratch " + file.string(), 4, "scratch path is not a directory");
}

TEST(CliUsage, AnUnknownCommandIsNamed) {
  std::string out;
  EXPECT_EQ(run_command(q() + " frobnicate x", &out), 2) << out;
  EXPECT_NE(out.find("unknown command 'frobnicate'"), std::string::npos) << out;
}

TEST(CliUsage, InCoreRunWritesATraceOfItsStages) {
  TempDir dir;
  const auto mesh = small_mesh(dir);
  const auto trace = dir / "t.json";
  std::string out;
  ASSERT_EQ(run_command(q() + " simplify " + mesh.string() + " " + (dir / "out.ply").string() +
                            " --ratio 0.5 --in-core --quiet --trace " + trace.string(),
                        &out),
            0)
      << out;
  const auto json = nlohmann::json::parse(file_bytes(trace));
  std::string names;
  for (const auto& e : json["traceEvents"])
    if (e["ph"] == "X") names += e["name"].get<std::string>() + " ";
  EXPECT_EQ(names, "read simplify write ");
}

}  // namespace
}  // namespace qemflow::testing

namespace qemflow::testing {
namespace {

// --config FILE (DESIGN §5): a TOML file of the command's flag values.
TEST(CliConfig, FlagValuesComeFromTheFileAndTheCommandLineWins) {
  TempDir dir;
  const auto mesh = small_mesh(dir);
  const auto config = dir / "job.toml";
  std::ofstream(config) << "ratio = 0.1\nmem_budget = \"64M\"\nquiet = true\nthreads = 1\n";
  const auto run = [&](const std::string& extra) {
    std::string out;
    EXPECT_EQ(run_command(q() + " simplify " + mesh.string() + " " + (dir / "out.ply").string() + " --config " +
                              config.string() + " --report " + (dir / "r.json").string() + extra,
                          &out),
              0)
        << out;
    EXPECT_EQ(out, "") << "quiet = true";
    return nlohmann::json::parse(file_bytes(dir / "r.json"));
  };
  auto r = run("");
  EXPECT_EQ(r["output_faces"], 200);
  EXPECT_EQ(r["budget_bytes"], 64ull << 20);
  EXPECT_EQ(r["threads"], 1);
  r = run(" --ratio 0.2 --mem-budget 80M");
  EXPECT_EQ(r["output_faces"], 400);
  EXPECT_EQ(r["budget_bytes"], 80ull << 20);
}

TEST(CliConfig, AFileThatIsNotFlagsIsAUsageErrorNamingItsLine) {
  TempDir dir;
  const auto config = dir / "job.toml";
  const std::pair<std::string, std::string> cases[] = {
      {"ratio = 0.1\nfrob = 3\n", "job.toml: line 2, column 1: 'frob' is not a flag of qemflow simplify"},
      {"ratio = 0.1\nmem-budget = [1, 2]\n", "job.toml: line 2, column 1: 'mem-budget' must be a string"},
      {"ratio = 0.1\n[simplify]\n", "job.toml: line 2, column 2: [simplify] is a table"},
      {"ratio = 0.1\nmem-budget = \"4G\n", "job.toml: line 2, column"},
  };
  for (const auto& [text, message] : cases) {
    std::ofstream(config) << text;
    expect_simplify_refused(dir, "--config " + config.string(), 2, message);
  }
}

}  // namespace
}  // namespace qemflow::testing
