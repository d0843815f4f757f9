#include <unistd.h>

#include <cstdio>

#include "engine/process_memory.hpp"
#include "engine/progress_bar.hpp"
#include "engine/reencode.hpp"

namespace qemflow::engine {

ReencodeResult run_reencode_command(const ReencodeCommand& command) {
  tune_allocator(8 << 20, 2);  // see process_memory.hpp (measured with two arenas)
  uint64_t budget = command.mem_budget;
  if (budget == 0) budget = uint64_t(::sysconf(_SC_PHYS_PAGES)) * uint64_t(::sysconf(_SC_PAGE_SIZE)) / 2;
  const uint64_t baseline = command_baseline();
  require_budget_for_load(budget, baseline);
  Governor governor(budget, baseline);
  ProgressBar bar(command.quiet);
  ReencodeOptions options;
  options.input = command.input;
  options.output = command.output;
  options.scratch_dir = command.scratch_dir;
  options.trace_path = command.trace_path;
  options.report_path = command.report_path;
  options.threads = command.threads;
  options.scratch_codec = command.scratch_codec;
  ReencodeResult result = run_reencode(governor, options, {.progress = bar.callback(), .cancel = command.cancel});
  bar.finish();
  if (!command.quiet) std::fprintf(stderr, "qemflow: %s\n", result.summary.c_str());
  return result;
}

}  // namespace qemflow::engine
