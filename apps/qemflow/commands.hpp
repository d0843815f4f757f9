#pragma once
// Each subcommand lives in its own file: it declares its flags on `root` and, when
// chosen, sets `run` to the work it does. main() owns parsing, errors and exit codes.
#include <CLI/CLI.hpp>
#include <functional>

namespace qemflow::cli {

using Run = std::function<void()>;

void add_gen_command(CLI::App& root, Run& run);
void add_info_command(CLI::App& root, Run& run);
void add_compare_command(CLI::App& root, Run& run);
void add_simplify_command(CLI::App& root, Run& run);

}  // namespace qemflow::cli
