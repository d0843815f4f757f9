#pragma once
// A Job is one run of a pipeline inside a host process: it owns the I/O thread, the
// compute arena, the trace and the per-stage accounting, and shares the process's
// Governor with every other job. No global state, no exit(), nothing on stdout.
//
// Contract
// - Errors: the first failure anywhere (a node body, an I/O task) is kept and stops
//   the job; every other node sees stopped() and drains without doing work. The
//   pipeline rethrows it at the end of the pass (qemflow::Error keeps its kind).
// - Cancel: the host calls CancelToken::cancel() from any thread; the job stops as
//   soon as every node has finished its current item, and ends with
//   Error(cancelled); scratch and partial output are removed as on any failure.
// - Progress: `progress(fraction, stage)` is called from pipeline threads; the hook
//   gets at most ~20 reports a second (a report within 50 ms of the last is dropped,
//   unless it completes, fraction 1, or names a new stage); it must be cheap and
//   thread-safe. A stage reports the
//   fraction of its own work; the job maps it into the span its driver set
//   (`progress_span`, default the whole run) and never reports less than before, so
//   the host sees one rising fraction for the whole job.
#include <oneapi/tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "engine/governor.hpp"
#include "engine/io_thread.hpp"
#include "engine/trace.hpp"

namespace qemflow::engine {

class CancelToken {
 public:
  void cancel();
  bool cancelled() const { return cancelled_.load(std::memory_order_relaxed); }
  // Called once on cancel (immediately if already cancelled); for wake-ups. Returns an
  // id for forget (0 when it ran at once).
  uint64_t on_cancel(std::function<void()> callback);
  // Drops a callback that has not run: what registers one forgets it when it ends, so a
  // token shared by many jobs in turn (a daemon's shutdown token) keeps none of theirs.
  void forget(uint64_t id);
  size_t pending() const;  // callbacks registered and not run or forgotten (tests)

 private:
  std::atomic<bool> cancelled_{false};
  mutable std::mutex mutex_;
  uint64_t next_id_ = 0;
  std::vector<std::pair<uint64_t, std::function<void()>>> callbacks_;
};

using ProgressCallback = std::function<void(double fraction, const std::string& stage)>;

struct JobHooks {
  ProgressCallback progress;                  // may be empty
  std::shared_ptr<CancelToken> cancel;        // may be empty
};

struct JobSettings {
  int threads = 0;                // compute threads; 0 = all cores
  size_t trace_events = 0;        // 0 = no trace
  std::string owner_prefix;       // prepended to governor owner names (jobs sharing a governor)
};

// Per-stage accounting for the report: wall time of the stage, bytes read and
// written by its I/O, items processed, and what the job's Activity counted while the
// stage ran: the process's CPU seconds (so cpu_seconds / seconds is the cores it
// kept busy), the I/O thread's busy seconds, the compute threads' and both at once.
// Stages must not nest (a StageTimer's scope holds no other): their sums are the run's.
struct StageStats {
  std::string name;
  double seconds = 0;
  double cpu_seconds = 0;
  double io_busy_seconds = 0;
  double compute_busy_seconds = 0;
  double overlap_seconds = 0;
  std::atomic<uint64_t> bytes_read{0};
  std::atomic<uint64_t> bytes_written{0};
  std::atomic<uint64_t> items{0};
};

class Job;

// A job's own governor reserved from the shared one (Governor's reserving
// constructor): `bytes` of its capacity (0: all of it, so the job waits until nothing
// else holds memory there and then runs alone), owned by `owner_prefix + "job"` ("a/job"
// for the prefix "a/"). The wait ends with Error(cancelled) when hooks.cancel fires.
std::unique_ptr<Governor> reserve_for_job(Governor& shared, const std::string& owner_prefix, uint64_t bytes,
                                          const JobHooks& hooks);

// A window over the process's resident high-water mark for one phase of a job. VmHWM is
// one per process and reset_peak_resident resets it for every reader, so the window
// opens (resets it) only when the job is the only one alive on its governor's root
// (Governor::jobs_alive); peak() is the window's high-water mark when no other job was
// alive at either end or started in between, else 0 (not measured: another job's
// memory would be in it). The process's own peak (peak_resident_bytes) is kept either way.
class SoleJobPeakWindow {
 public:
  explicit SoleJobPeakWindow(const Governor& governor);
  uint64_t peak() const;

 private:
  const Governor& governor_;
  bool open_ = false;
  uint64_t started_ = 0;
};

// Adds a scope's wall time and activity to a stage (the pipeline's top-level phases,
// one after another): made and ended on the thread that drives the job, never inside
// another StageTimer of the same job (Error(internal): the stages' sums would count the
// inner one twice).
class StageTimer {
 public:
  StageTimer(Job& job, const std::string& stage);
  ~StageTimer();
  StageTimer(const StageTimer&) = delete;
  StageTimer& operator=(const StageTimer&) = delete;

 private:
  Job& job_;
  StageStats& stage_;
  Activity::Totals start_;
};

class Job {
 public:
  Job(Governor& governor, JobHooks hooks, JobSettings settings);
  ~Job();
  Job(const Job&) = delete;
  Job& operator=(const Job&) = delete;

  Governor& governor() { return governor_; }
  // What the job holds for its whole run (the trace buffer), and so what its stages may
  // lease at most: the governor's capacity less that. A stage sizing a lease from the
  // bare capacity would, with --trace, ask for more than can ever be free and wait
  // forever; require_fits checks against capacity() (the minimum budget it names
  // includes the trace).
  uint64_t held_for_run() const { return trace_lease_.bytes(); }
  uint64_t capacity() const { return governor_.capacity() - std::min(governor_.capacity(), held_for_run()); }
  void require_fits(const std::string& owner, uint64_t bytes) const { governor_.require_fits(owner, bytes + held_for_run()); }
  IoThread& io() { return *io_; }
  Trace& trace() { return trace_; }
  Activity& activity() { return activity_; }
  tbb::task_arena& arena() { return arena_; }
  int threads() const { return arena_.max_concurrency(); }
  std::string owner(const std::string& node) const { return settings_.owner_prefix + node; }

  bool stopped() const { return stopped_.load(std::memory_order_relaxed); }
  bool cancelled() const { return hooks_.cancel && hooks_.cancel->cancelled(); }
  void fail(std::exception_ptr error);
  IoThread::ErrorHandler error_handler() {
    return [this](std::exception_ptr e) { fail(e); };
  }
  // Throws the job's error (or Error(cancelled)) if it stopped.
  void check();

  void progress(double fraction, const std::string& stage);
  // The part [from, to] of the whole job that the following progress() calls cover;
  // set by the thread that drives the pipeline, between its stages.
  void progress_span(double from, double to);
  StageStats& stage(const std::string& name);  // created on first use, kept in order
  std::vector<const StageStats*> stages() const;

 private:
  Governor& governor_;
  JobHooks hooks_;
  JobSettings settings_;
  Trace trace_;
  Activity activity_;
  Lease trace_lease_;
  uint64_t observer_ = 0;  // its trace counter on the governor (0: untraced)
  tbb::task_arena arena_;
  std::unique_ptr<IoThread> io_;
  std::atomic<bool> stopped_{false};
  std::mutex mutex_;
  std::exception_ptr error_;
  std::vector<std::unique_ptr<StageStats>> stages_;
  friend class StageTimer;
  const StageStats* timed_stage_ = nullptr;  // the StageTimer open now (driving thread only)
  std::atomic<int64_t> last_progress_ns_{0};
  std::mutex progress_mutex_;  // hook calls in order, each at least the one before
  double progress_from_ = 0, progress_to_ = 1, progress_reported_ = 0;
  std::string progress_stage_;  // of the last report that went through
  std::shared_ptr<std::atomic<Job*>> alive_;  // lets a cancel after the job's end do nothing
  uint64_t cancel_callback_ = 0;              // on hooks_.cancel, forgotten at the end
};

}  // namespace qemflow::engine
