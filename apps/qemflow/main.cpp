// The qemflow command line: a thin shell over the library. Exit codes (DESIGN.md §6):
// 0 ok, 1 internal, 2 usage, 3 bad input, 4 resources, 5 cancelled.
#include <cstdio>
#include <exception>

#include "apps/qemflow/commands.hpp"
#include "config/config_file.hpp"
#include "engine/interrupt.hpp"
#include "util/error.hpp"

int main(int argc, char** argv) {
  // First, before any thread starts: Ctrl-C cancels an out-of-core job cleanly.
  qemflow::engine::install_interrupt_cancel();
  CLI::App app{"qemflow: out-of-core QEM simplification of huge triangle meshes"};
  app.require_subcommand(0, 1);
  // A plain flag, not set_version_flag: --config's fallthrough would make that one a flag
  // of every command (`simplify IN OUT --version` printed the version and ran nothing).
  bool version = false;
  app.add_flag("--version", version, "print the version and exit");
  qemflow::cli::Run run;
  qemflow::cli::add_simplify_command(app, run);
  qemflow::cli::add_gen_command(app, run);
  qemflow::cli::add_compare_command(app, run);
  qemflow::cli::add_info_command(app, run);
  qemflow::config::add_config_option(app);
  // CLI11 reports a misspelt command as "A subcommand is required"; name it instead.
  if (argc > 1 && argv[1][0] != '-') {
    try {
      app.get_subcommand(argv[1]);
    } catch (const CLI::OptionNotFound&) {
      std::fprintf(stderr, "qemflow: unknown command '%s' (commands: simplify, gen, compare, info; see --help)\n",
                   argv[1]);
      return qemflow::exit_code(qemflow::ErrorKind::usage);
    }
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::FileError& e) {
    std::fprintf(stderr, "qemflow: %s\n", qemflow::config::file_error_message(app, e).c_str());
    return qemflow::exit_code(qemflow::ErrorKind::usage);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "qemflow: %s\n", e.what());
    return qemflow::exit_code(qemflow::ErrorKind::usage);
  }
  if (version) {
    for (const CLI::App* command : app.get_subcommands()) {
      std::fprintf(stderr, "qemflow: --version is not a flag of qemflow %s\n", command->get_name().c_str());
      return qemflow::exit_code(qemflow::ErrorKind::usage);
    }
    std::printf("qemflow 0.1.0\n");
    return 0;
  }
  if (app.get_subcommands().empty()) {
    std::fprintf(stderr, "qemflow: a command is required (simplify, gen, compare, info; see --help)\n");
    return qemflow::exit_code(qemflow::ErrorKind::usage);
  }
  try {
    if (run) run();
    return 0;
  } catch (const qemflow::Error& e) {
    std::fprintf(stderr, "qemflow: %s\n", e.what());
    return qemflow::exit_code(e.kind());
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "qemflow: out of memory\n");
    return qemflow::exit_code(qemflow::ErrorKind::resource);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "qemflow: internal error: %s\n", e.what());
    return qemflow::exit_code(qemflow::ErrorKind::internal);
  }
}
