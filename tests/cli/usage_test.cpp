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
  expect_simplify_refused(dir, "--target-faces 0", 2, "--target-faces: must be a face count of at least 1");
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

// A --config path that is a directory was "not readable (missing?)", CLI11's words for
// any path that is not a file.
TEST(CliConfig, ADirectoryOrAMissingFileIsNamedAsSuch) {
  TempDir dir;
  std::filesystem::create_directories(dir / "job.toml");
  expect_simplify_refused(dir, "--config " + (dir / "job.toml").string(), 2, "job.toml: is a directory, not a TOML file");
  expect_simplify_refused(dir, "--config " + (dir / "none.toml").string(), 2, "none.toml: no such file");
}

// review17 (MEDIUM): "flags on the command line win" over the file, the target too:
// a job file's ratio with --target-faces on the command line was refused ("--target-faces
// excludes --ratio", exit 2), so a shared job file could not be given another target.
TEST(CliConfig, TheCommandLinesTargetWinsOverTheFilesRatio) {
  TempDir dir;
  const auto mesh = small_mesh(dir);
  const auto config = dir / "job.toml";
  std::ofstream(config) << "ratio = 0.1\nquiet = true\n";
  std::string out;
  ASSERT_EQ(run_command(q() + " simplify " + mesh.string() + " " + (dir / "out.ply").string() + " --config " +
                            config.string() + " --target-faces 500 --report " + (dir / "r.json").string(),
                        &out),
            0)
      << out;
  EXPECT_EQ(nlohmann::json::parse(file_bytes(dir / "r.json"))["output_faces"], 500);
}

// review17 (LOW): --config's fallthrough made every root flag a flag of each command:
// `simplify IN OUT --ratio 0.5 --version` printed the version and exited 0 without
// simplifying (before --config: exit 2, "--version not expected").
TEST(CliConfig, TheRootsVersionFlagIsNotACommandFlag) {
  TempDir dir;
  expect_simplify_refused(dir, "--ratio 0.5 --version", 2, "--version");
}

// review17 (LOW): --help answers whatever --config names; the file was read first, so a
// bad file (or --config with no command) turned a call for help into a usage error.
TEST(CliConfig, HelpWinsOverTheConfigFile) {
  TempDir dir;
  const auto config = dir / "job.toml";
  std::ofstream(config) << "frob = 3\n";
  for (const std::string args : {" simplify --help --config ", " --config "}) {
    std::string out;
    EXPECT_EQ(run_command(q() + args + config.string() + (args == " --config " ? " --help" : ""), &out), 0)
        << args << "\n" << out;
    EXPECT_NE(out.find("Usage:"), std::string::npos) << args << "\n" << out;
  }
}


// review17 (LOW): a negative target, on the command line (`--target-faces -5`, which
// CLI11 2.1 takes as a value) or from a TOML integer (`target-faces = -5`), went through
// strtoull as 2^64-5: the input came back unsimplified, exit 0 (what e4871d1 fixed for
// --clusters '-3').
TEST(CliUsage, ANegativeTargetIsRefused) {
  TempDir dir;
  expect_simplify_refused(dir, "--target-faces -5", 2, "--target-faces");
  std::filesystem::remove(dir / "out.ply");  // each case on its own
  expect_simplify_refused(dir, "--target-faces=-5 --in-core", 2, "--target-faces");
  std::filesystem::remove(dir / "out.ply");
  const auto config = dir / "job.toml";
  std::ofstream(config) << "target-faces = -5\n";
  expect_simplify_refused(dir, "--config " + config.string(), 2, "target-faces");
}

// review17 (LOW): DESIGN §6, a failed run leaves no output file. A --trace that cannot be
// written failed the run (exit 4) after the output was renamed into place: new in core
// with e4871d1 (it exited 0 before), and so out of core too.
TEST(CliUsage, ATraceThatCannotBeWrittenLeavesNoOutput) {
  TempDir dir;
  const std::string trace = " --trace " + (dir / "missing" / "t.json").string();
  expect_simplify_refused(dir, "--ratio 0.5 --quiet --in-core" + trace, 4, "cannot write the trace");
  std::filesystem::remove(dir / "out.ply");  // each case on its own
  expect_simplify_refused(dir, "--ratio 0.5 --quiet" + trace, 4, "cannot write the trace");
}


// review17: CLI::Range lets NaN through, so `--round-fraction nan` and
// `--min-normal-cos nan` ran with a rule that no comparison could meet.
TEST(CliUsage, TuningValuesMustBeFiniteAndInRange) {
  TempDir dir;
  for (const std::string bad : {"--round-fraction nan", "--candidate-fraction 2", "--min-normal-cos nan",
                                "--min-face-quality inf", "--fold-cos -3", "--boundary-weight nan",
                                "--deviation-weight nan", "--new-fold-cos 2", "--charge-from -1"}) {
    expect_simplify_refused(dir, "--ratio 0.5 " + bad, 2, "must be a number from");
    std::filesystem::remove(dir / "out.ply");
  }
}

}  // namespace
}  // namespace qemflow::testing
