// `qemflow info` — placeholder until its issue lands.
#include "apps/qemflow/commands.hpp"
#include "util/error.hpp"

namespace qemflow::cli {

void add_info_command(CLI::App& root, Run& run) {
  auto* cmd = root.add_subcommand("info", "(info: not implemented yet)");
  cmd->allow_extras();
  cmd->callback([&run] {
    run = [] { throw Error(ErrorKind::internal, "'info' is not implemented yet"); };
  });
}

}  // namespace qemflow::cli
