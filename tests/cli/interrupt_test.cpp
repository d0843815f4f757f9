// Ctrl-C on the command line (engine/interrupt.hpp): an out-of-core run that gets
// SIGINT (or SIGTERM) cancels its job, removes its scratch and partial output, and ends
// with exit code 5 (DESIGN.md §6); before, the signal killed it and left the scratch.
#include <gtest/gtest.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "tests/test_support.hpp"

extern char** environ;

namespace qemflow::testing {
namespace {

// Starts `qemflow ARGS` with stdout/stderr to /dev/null; returns its pid.
pid_t spawn_cli(std::vector<std::string> args) {
  args.insert(args.begin(), cli_path().string());
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  return rc == 0 ? pid : -1;
}

void expect_interrupt_cancels(int signal_number) {
  TempDir dir;
  const auto mesh = dir / "blob.ply";
  std::string text;
  ASSERT_EQ(run_command(cli_path().string() + " gen " + mesh.string() + " --faces 1M --quiet", &text), 0) << text;
  const auto scratch = dir / "scratch";
  std::filesystem::create_directories(scratch);
  const auto out = dir / "out.ply";
  // About 25 s out of core: the signal comes in the middle of the epochs.
  const pid_t pid = spawn_cli({"simplify", mesh.string(), out.string(), "--ratio", "0.01", "--mem-budget", "96M",
                               "--quiet", "--scratch", scratch.string()});
  ASSERT_GT(pid, 0);
  std::this_thread::sleep_for(std::chrono::seconds(4));
  ASSERT_EQ(::kill(pid, signal_number), 0);
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "ended by signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  EXPECT_EQ(WEXITSTATUS(status), 5);
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_TRUE(std::filesystem::is_empty(scratch));
}

TEST(Interrupt, CtrlCCancelsAnOutOfCoreRunAndLeavesNothing) { expect_interrupt_cancels(SIGINT); }

TEST(Interrupt, SigtermDoesTheSame) { expect_interrupt_cancels(SIGTERM); }

}  // namespace
}  // namespace qemflow::testing
