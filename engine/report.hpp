#pragma once
// The run report (--report FILE.json, DESIGN §5) and the short end-of-run summary.
// job_report() fills what the engine knows (wall time, peak RSS against the budget,
// per-stage time and bytes, per-node memory from the governor, busy and overlap
// times); the pipeline adds its own fields (input/output faces, patches, rounds).
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"

namespace qemflow::engine {

nlohmann::json job_report(Job& job, const Governor& governor);
// One paragraph for stderr: wall time, peak RSS / budget, I/O and compute busy (with
// the compute threads' CPU as a rough share of threads x wall: see
// Activity::Totals::compute_thread_seconds), overlap; from a report made by job_report().
std::string format_summary(const nlohmann::json& report);
// Plain file write (the report is not pipeline data); Error(resource) on failure.
void write_json(const std::filesystem::path& path, const nlohmann::json& json);

// The scratch store's totals and codec: scratch_bytes_written, scratch_bytes_read,
// scratch_peak_bytes, scratch_codec ("raw", "zstd", or "mixed" when an automatic store
// chose both) and scratch_codec_choices (each choice's stage, codec, raw bound, free bytes).
void report_scratch(nlohmann::json& report, ScratchStore& scratch);

// Runs `body`, then writes the job's trace to `path` (if any) whether body returned or
// threw: a failed run's trace is the one most worth reading. A trace write error after
// a failure never masks the failure's own error.
template <class Body>
void run_then_write_trace(Job& job, const std::filesystem::path& path, Body&& body) {
  if (path.empty()) return body();
  Trace::check_writable(path);  // before the output exists (DESIGN §6)
  try {
    body();
  } catch (...) {
    try {
      job.trace().write(path);
    } catch (...) {
    }
    throw;
  }
  job.trace().write(path);
}

}  // namespace qemflow::engine
