#pragma once
// Observability: Chrome trace-event JSON (opens in Perfetto / chrome://tracing) and
// the busy-time accounting behind the end-of-run summary.
//
// - Trace records "X" spans (one per node per item: name, thread, start, duration,
//   bytes), "C" counters (governor bytes in use, I/O bytes in flight) and "M"
//   thread_name metadata: the I/O thread is "io", TBB threads "compute-N", the rest
//   "thread-N". Events are kept in memory up to a fixed cap (the cap's memory is the
//   trace's lease); beyond it they are counted as dropped, never grown.
// - Activity measures, with or without a trace file, how long the I/O thread and the
//   compute threads were busy, and how long both were busy at once (the overlap).
//   Busy time comes from spans: a thread is computing while it is inside a compute
//   Span (nested spans on one thread count it once) and not inside a Waiting scope
//   (waiting for the I/O thread, or for a stream pass whose own spans count its work).
//   The compute threads' CPU is not: a span around a parallel_for is one thread's span
//   while every worker computes, so compute_thread_seconds comes from CPU clocks.
// Thread safety: every member may be called from any thread.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace qemflow::engine {

using Clock = std::chrono::steady_clock;

class Activity {
 public:
  Activity();
  void io_begin() { change(+1, 0); }
  void io_end() { change(-1, 0); }
  // A thread starts / stops computing (Span and Waiting call these once per thread).
  void compute_begin() { change(0, +1); }
  void compute_end() { change(0, -1); }
  // The I/O thread's CPU seconds so far (its own thread CPU clock), set by the I/O
  // thread after each task.
  void set_io_cpu_seconds(double seconds) { io_cpu_.store(seconds, std::memory_order_relaxed); }

  struct Totals {
    double wall_seconds = 0;
    double io_busy_seconds = 0;       // the I/O thread was working
    double compute_busy_seconds = 0;  // at least one compute thread was working
    // CPU seconds the process used since the job began, less the I/O thread's: what the
    // compute threads (the job's own thread and TBB's) ran, including the parallel_for
    // work inside a span and the work outside any span (planning between phases). Also
    // counted: TBB workers spinning before they sleep, and, in a process running
    // several jobs at once, the other jobs' threads (only their sum is known). So the
    // summary line prints it as a whole percentage of threads x wall, no finer.
    double compute_thread_seconds = 0;
    double overlap_seconds = 0;       // both at once
    double process_cpu_seconds = 0;   // the process's CPU since the job began, every thread's
  };
  Totals totals() const;

 private:
  void change(int io_delta, int compute_delta);
  void advance(Clock::time_point now);  // under lock
  mutable std::mutex mutex_;
  Clock::time_point start_, last_;
  double cpu_start_;  // process CPU seconds at the job's start
  std::atomic<double> io_cpu_{0};
  int io_active_ = 0, compute_active_ = 0;
  double io_ = 0, compute_ = 0, both_ = 0;
};

// CPU seconds of the process / of the calling thread (CLOCK_*_CPUTIME_ID).
double process_cpu_seconds();
double thread_cpu_seconds();

class Trace {
 public:
  // max_events == 0: disabled (every call is a cheap no-op).
  explicit Trace(size_t max_events = 0);
  bool enabled() const { return max_events_ > 0; }
  static constexpr size_t bytes_per_event = 48;

  // Names the calling thread's track (e.g. "io").
  void name_thread(const std::string& name);
  // Gives the calling thread its track now, named as its first span would name it
  // ("compute-N" inside the job's arena): a thread whose first span would come from
  // outside the arena (the job's own thread, between phases) gets its arena name.
  void register_thread();
  double now_us() const { return us_at(Clock::now()); }
  double us_at(Clock::time_point time) const;  // µs since the trace began
  static constexpr uint32_t kNoPatch = UINT32_MAX;
  // `patch`: the patch (owner) the span worked on, an arg of the event unless kNoPatch.
  void span(const char* name, double start_us, double end_us, uint64_t bytes = 0, uint32_t patch = kNoPatch);
  // Rate-limited to one sample per counter per 200 µs (the last value always wins at
  // the next sample). A fine event, thinned like short spans when the buffer fills.
  void counter(const char* name, double value);
  // Spans of a patch's phase or of at least kWholeSpanUs are whole-run events, kept
  // while the buffer has room; the rest (a frame's decode, a write, counters) are fine
  // events, thinned when it is full (make_room).
  static constexpr double kWholeSpanUs = 10'000;
  uint64_t dropped() const { return dropped_; }
  size_t size() const;

  // Writes the JSON (plain file I/O: the trace is not part of the pipeline's data).
  void write(const std::filesystem::path& path) const;
  // Error(resource) now, as write() would throw at the end, if `path` cannot be
  // written; leaves no file behind. Runs check before their output exists.
  static void check_writable(const std::filesystem::path& path);

 private:
  struct Event {
    const char* name;  // string literals / interned names only
    double ts, dur;    // µs; dur < 0 marks a counter
    uint64_t value;
    uint32_t tid;
    uint32_t patch;  // kNoPatch: none
  };
  uint32_t thread_id();  // under lock
  static bool is_fine(const Event& e);
  // Under lock: whether an event may be added now. A full buffer drops every other fine
  // event it holds and keeps one fine event in twice as many from then on
  // (fine_stride_), so a long run's trace covers it all, thinned, instead of stopping.
  bool make_room(bool fine);
  uint64_t fine_seen_ = 0;    // fine events offered, kept or not
  uint64_t fine_stride_ = 1;  // one fine event in fine_stride_ is kept
  const size_t max_events_;
  Clock::time_point start_;
  mutable std::mutex mutex_;
  std::vector<Event> events_;
  std::map<std::thread::id, uint32_t> tids_;
  std::map<uint32_t, std::string> thread_names_;
  std::map<std::string, double> last_counter_us_;
  std::atomic<uint64_t> dropped_{0};
};

// A span on the calling thread: traced if the trace is on, and counted as compute or
// I/O busy time. A compute span inside another of the same Activity on the same thread
// is traced but not counted again (the thread is one compute thread either way).
class Span {
 public:
  enum class Kind { compute, io };
  Span(Trace* trace, Activity* activity, const char* name, Kind kind = Kind::compute,
       uint64_t bytes = 0);
  ~Span();
  Span(const Span&) = delete;
  Span& operator=(const Span&) = delete;
  void set_bytes(uint64_t bytes) { bytes_ = bytes; }
  void set_patch(uint32_t patch) { patch_ = patch; }

  struct ThreadState {
    Activity* activity = nullptr;
    int depth = 0;  // compute spans of `activity` open on this thread (counted once)
  };

 private:
  Trace* trace_;
  Activity* activity_;
  const char* name_;
  Kind kind_;
  uint64_t bytes_;
  uint32_t patch_ = Trace::kNoPatch;
  double start_us_ = 0;
  bool counted_ = false;  // this span counted its thread as computing
  ThreadState saved_;
};

// The calling thread waits (for the I/O thread, or for a stream pass whose own spans
// count its work): its enclosing compute span, if any, does not count it as computing
// until the scope ends. Spans begun inside the scope count afresh.
class Waiting {
 public:
  Waiting();
  ~Waiting();
  Waiting(const Waiting&) = delete;
  Waiting& operator=(const Waiting&) = delete;

 private:
  Span::ThreadState saved_;
};

}  // namespace qemflow::engine
