// `qemflow compare` — placeholder until its issue lands.
#include "apps/qemflow/commands.hpp"
#include "util/error.hpp"

namespace qemflow::cli {

void add_compare_command(CLI::App& root, Run& run) {
  auto* cmd = root.add_subcommand("compare", "(compare: not implemented yet)");
  cmd->allow_extras();
  cmd->callback([&run] {
    run = [] { throw Error(ErrorKind::internal, "'compare' is not implemented yet"); };
  });
}

}  // namespace qemflow::cli
