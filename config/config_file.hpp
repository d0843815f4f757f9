#pragma once
// `--config FILE`: a TOML file of flag values for one command, so that a pipeline keeps
// its settings (budget, scratch, threads, tuning) in a file instead of a shell line:
//
//   # job.toml, for `qemflow simplify IN OUT --config job.toml`
//   ratio = 0.01
//   mem-budget = "4G"
//   scratch = "/mnt/fast/tmp"
//   in-core = false
//
// Keys are the command's long flag names without "--" (`mem_budget` is read as
// `mem-budget`); values are strings, numbers or booleans. A flag given on the command
// line wins over the file. The file is checked whole before the run: a TOML syntax
// error, an unknown key, a table or an array is a usage error naming the file, the
// line and column, and the problem.
#include <string>

#include <CLI/CLI.hpp>

namespace qemflow::config {

// Adds `--config FILE` to the root app `root`, accepted after any of its commands
// (fallthrough); the file's keys are the flags of the command being run.
void add_config_option(CLI::App& root);

// The one-line message for a FileError of `root`'s parse. CLI11 says "PATH was not
// readable (missing?)" of any --config path that is not a regular file; this says
// whether it is missing or a directory. Other FileErrors keep their own message.
std::string file_error_message(const CLI::App& root, const CLI::FileError& error);

}  // namespace qemflow::config
