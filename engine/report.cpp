#include "engine/report.hpp"

#include <sys/resource.h>

#include <cstdio>
#include <fstream>

#include "config/size.hpp"
#include "engine/process_memory.hpp"
#include "util/error.hpp"

namespace qemflow::engine {

nlohmann::json job_report(Job& job, const Governor& governor) {
  auto activity = job.activity().totals();
  nlohmann::json report;
  report["wall_seconds"] = activity.wall_seconds;
  report["peak_rss_bytes"] = peak_resident_bytes();
  report["budget_bytes"] = governor.budget();
  report["baseline_bytes"] = governor.baseline();
  report["governor_peak_bytes"] = governor.peak_in_use();
  report["threads"] = job.threads();
  report["io_busy_seconds"] = activity.io_busy_seconds;
  report["compute_busy_seconds"] = activity.compute_busy_seconds;
  report["compute_thread_seconds"] = activity.compute_thread_seconds;
  report["overlap_seconds"] = activity.overlap_seconds;
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  report["cpu_seconds"] = double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
                          1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
  nlohmann::json stages = nlohmann::json::array();
  for (const StageStats* s : job.stages()) {
    stages.push_back({{"name", s->name},
                      {"seconds", s->seconds},
                      {"cpu_seconds", s->cpu_seconds},
                      {"io_busy_seconds", s->io_busy_seconds},
                      {"compute_busy_seconds", s->compute_busy_seconds},
                      {"overlap_seconds", s->overlap_seconds},
                      {"bytes_read", s->bytes_read.load()},
                      {"bytes_written", s->bytes_written.load()},
                      {"items", s->items.load()}});
  }
  report["stages"] = stages;
  nlohmann::json nodes = nlohmann::json::array();
  for (const OwnerStats& o : governor.owners()) {
    nodes.push_back({{"name", o.owner},
                     {"peak_bytes", o.peak},
                     {"granted_bytes", o.granted_total},
                     {"grants", o.grants},
                     {"partial_grants", o.partial_grants},
                     {"denials", o.denials}});
  }
  report["nodes"] = nodes;
  report["trace_dropped_events"] = job.trace().dropped();
  return report;
}

std::string format_summary(const nlohmann::json& r) {
  double wall = r.value("wall_seconds", 0.0);
  auto pct = [&](double seconds) { return wall > 0 ? 100.0 * seconds / wall : 0.0; };
  double io = r.value("io_busy_seconds", 0.0);
  double overlap = r.value("overlap_seconds", 0.0);
  char line[512];
  std::snprintf(line, sizeof line,
                "wall %.2f s | peak RSS %s of %s budget | I/O busy %.0f%% | compute busy %.0f%% "
                "(CPU ~%.0f%% of %d threads) | overlap %.0f%% of I/O time",
                wall, config::format_size(r.value("peak_rss_bytes", uint64_t(0))).c_str(),
                config::format_size(r.value("budget_bytes", uint64_t(0))).c_str(), pct(io),
                pct(r.value("compute_busy_seconds", 0.0)),
                pct(r.value("compute_thread_seconds", 0.0)) / std::max(1, r.value("threads", 1)),
                r.value("threads", 1), io > 0 ? 100.0 * overlap / io : 0.0);
  return line;
}

void report_scratch(nlohmann::json& report, ScratchStore& scratch) {
  report["scratch_bytes_written"] = scratch.bytes_written();
  report["scratch_bytes_read"] = scratch.bytes_read();
  report["scratch_peak_bytes"] = scratch.peak_bytes_on_disk();
  // "mixed": an automatic store went raw for some stages and zstd for others.
  bool any_raw = false, any_zstd = false;
  nlohmann::json choices = nlohmann::json::array();
  for (const auto& c : scratch.codec_choices()) {
    (c.raw ? any_raw : any_zstd) = true;
    choices.push_back({{"stage", c.stage}, {"codec", c.raw ? "raw" : "zstd"}, {"raw_bound_bytes", c.raw_bytes},
                       {"free_bytes", c.free_bytes}});
    // A raw stage sized by an estimate (ScratchStore::choose_codec): its raw bytes'
    // cap, and whether its frames went zstd past it (then the stage is mixed itself).
    if (c.raw_estimate) choices.back()["raw_estimate_bytes"] = c.raw_estimate;
    if (c.raw_cap) {
      choices.back()["raw_cap_bytes"] = c.raw_cap;
      choices.back()["past_cap"] = c.past_cap;
      any_zstd = any_zstd || c.past_cap;
    }
  }
  report["scratch_codec"] = any_raw && any_zstd ? "mixed" : any_raw ? "raw" : "zstd";
  report["scratch_codec_choices"] = choices;
}

void write_json(const std::filesystem::path& path, const nlohmann::json& json) {
  std::ofstream out(path);
  out << json.dump(2) << "\n";
  if (!out) throw Error(ErrorKind::resource, path.string() + ": cannot write the report");
}

}  // namespace qemflow::engine
