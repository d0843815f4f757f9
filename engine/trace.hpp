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
  void compute_begin() { change(0, +1); }
  void compute_end() { change(0, -1); }

  struct Totals {
    double wall_seconds = 0;
    double io_busy_seconds = 0;       // the I/O thread was working
    double compute_busy_seconds = 0;  // at least one compute thread was working
    double compute_thread_seconds = 0;  // summed over compute threads
    double overlap_seconds = 0;       // both at once
  };
  Totals totals() const;

 private:
  void change(int io_delta, int compute_delta);
  void advance(Clock::time_point now);  // under lock
  mutable std::mutex mutex_;
  Clock::time_point start_, last_;
  int io_active_ = 0, compute_active_ = 0;
  double io_ = 0, compute_ = 0, compute_threads_ = 0, both_ = 0;
};

class Trace {
 public:
  // max_events == 0: disabled (every call is a cheap no-op).
  explicit Trace(size_t max_events = 0);
  bool enabled() const { return max_events_ > 0; }
  static constexpr size_t bytes_per_event = 48;

  // Names the calling thread's track (e.g. "io").
  void name_thread(const std::string& name);
  double now_us() const;
  void span(const char* name, double start_us, double end_us, uint64_t bytes = 0);
  // Rate-limited to one sample per counter per 200 µs (the last value always wins at
  // the next sample).
  void counter(const char* name, double value);
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
  };
  uint32_t thread_id();  // under lock
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
// I/O busy time.
class Span {
 public:
  enum class Kind { compute, io };
  Span(Trace* trace, Activity* activity, const char* name, Kind kind = Kind::compute,
       uint64_t bytes = 0);
  ~Span();
  Span(const Span&) = delete;
  Span& operator=(const Span&) = delete;
  void set_bytes(uint64_t bytes) { bytes_ = bytes; }

 private:
  Trace* trace_;
  Activity* activity_;
  const char* name_;
  Kind kind_;
  uint64_t bytes_;
  double start_us_ = 0;
};

}  // namespace qemflow::engine
