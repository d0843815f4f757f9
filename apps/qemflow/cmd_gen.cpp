// `qemflow gen` — placeholder until its issue lands.
#include "apps/qemflow/commands.hpp"
#include "util/error.hpp"

namespace qemflow::cli {

void add_gen_command(CLI::App& root, Run& run) {
  auto* cmd = root.add_subcommand("gen", "(gen: not implemented yet)");
  cmd->allow_extras();
  cmd->callback([&run] {
    run = [] { throw Error(ErrorKind::internal, "'gen' is not implemented yet"); };
  });
}

}  // namespace qemflow::cli
