// Activity's busy times (engine/trace.hpp): a thread counts once however many spans
// it nests, not while it waits (Waiting), and compute_thread_seconds is the compute
// threads' CPU, parallel work inside one span included.
#include "engine/trace.hpp"

#include <gtest/gtest.h>

#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>

#include <unistd.h>

namespace qemflow::engine {
namespace {

using namespace std::chrono_literals;

// Burns about `seconds` of the calling thread's CPU.
void burn(double seconds) {
  const double until = thread_cpu_seconds() + seconds;
  volatile double x = 1;
  while (thread_cpu_seconds() < until)
    for (int i = 0; i < 10000; ++i) x = std::sqrt(x + 1.0);
}

// The I/O thread works the whole time; the compute thread computes, then waits for
// it, then computes again. The wait is neither compute busy time nor overlap.
TEST(Activity, AWaitInsideASpanIsNotComputeBusyNorOverlap) {
  Activity activity;
  std::atomic<bool> stop{false}, reading{false};
  std::thread io([&] {
    Span span(nullptr, &activity, "read", Span::Kind::io);
    reading = true;
    while (!stop) std::this_thread::sleep_for(1ms);
  });
  // The compute side starts once the I/O span has: otherwise the thread's start-up
  // falls inside the measured time but outside the I/O span (seen in CI: I/O busy
  // 0.210526 s against 0.210528 s measured).
  while (!reading) std::this_thread::yield();
  const auto start = Clock::now();
  Clock::duration waited{};
  {
    Span outer(nullptr, &activity, "phase");
    {
      Span inner(nullptr, &activity, "nested");  // the same thread: counted once
      std::this_thread::sleep_for(30ms);
    }
    const auto wait_start = Clock::now();
    {
      Waiting waiting;
      std::this_thread::sleep_for(150ms);
    }
    waited = Clock::now() - wait_start;
    std::this_thread::sleep_for(30ms);
  }
  const double span_seconds = std::chrono::duration<double>(Clock::now() - start).count();
  stop = true;
  io.join();
  const auto t = activity.totals();
  const double wait_seconds = std::chrono::duration<double>(waited).count();
  EXPECT_LE(t.compute_busy_seconds, span_seconds - wait_seconds + 1e-3);
  EXPECT_GE(t.compute_busy_seconds, 0.055);
  EXPECT_NEAR(t.overlap_seconds, t.compute_busy_seconds, 1e-3);
  EXPECT_GE(t.io_busy_seconds, span_seconds);
}

// A span inside a wait counts again (a thread that runs a stream pass's node while it
// waits for the pass).
TEST(Activity, ASpanInsideAWaitCounts) {
  Activity activity;
  {
    Span outer(nullptr, &activity, "phase");
    Waiting waiting;
    Span node(nullptr, &activity, "decode");
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_GE(activity.totals().compute_busy_seconds, 0.045);
}

// Two threads' CPU inside one thread's span: compute_thread_seconds has it all (it
// counted the span's one thread before).
TEST(Activity, ComputeThreadSecondsCountTheParallelWorkInsideOneSpan) {
  Activity activity;
  tbb::task_arena arena(2);
  {
    Span span(nullptr, &activity, "rounds");
    arena.execute([] {
      tbb::parallel_for(0, 2, [](int) { burn(0.2); }, tbb::static_partitioner());
    });
  }
  const auto t = activity.totals();
  EXPECT_GE(t.compute_thread_seconds, 0.38);
  // The I/O thread's CPU is not the compute threads'.
  Activity with_io;
  std::thread io([&] {
    const double start = thread_cpu_seconds();
    burn(0.2);
    with_io.set_io_cpu_seconds(thread_cpu_seconds() - start);
  });
  io.join();
  EXPECT_LT(with_io.totals().compute_thread_seconds, 0.05);
}

// A phase's span carries its patch as an arg; spans beyond the cap are counted, not kept.
TEST(Trace, PatchArgAndTheEventCap) {
  Trace trace(2);
  {
    Span a(&trace, nullptr, "gather");
    a.set_patch(7);
  }
  { Span b(&trace, nullptr, "decode"); }
  { Span c(&trace, nullptr, "rounds"); }
  EXPECT_EQ(trace.size(), 2u);
  EXPECT_EQ(trace.dropped(), 1u);
  const auto path = std::filesystem::temp_directory_path() / ("qemflow_trace_test_" + std::to_string(::getpid()) + ".json");
  trace.write(path);
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::filesystem::remove(path);
  EXPECT_NE(text.find("\"name\":\"gather\",\"ts\""), std::string::npos) << text;
  EXPECT_NE(text.find("\"args\":{\"bytes\":0,\"patch\":7}"), std::string::npos) << text;
  EXPECT_EQ(text.find("\"patch\":4294967295"), std::string::npos) << text;
}

// A run longer than the buffer keeps its whole-run spans (a patch's phases, long
// spans) and a thinned sample of the fine ones from its start to its end, rather than
// its first events only.
TEST(Trace, AFullBufferThinsTheFineEventsAndKeepsThePhases) {
  Trace trace(64);
  constexpr int kFine = 10'000;
  for (int i = 0; i < kFine; ++i) {
    const double t = 100.0 * i;
    trace.span("decode", t, t + 5);
    if (i % 1000 == 0) trace.span("rounds", t, t + 50, 0, uint32_t(i / 1000));  // a phase
    if (i % 2500 == 0) trace.span("load", t, t + Trace::kWholeSpanUs);           // a long span
  }
  EXPECT_LE(trace.size(), 64u);
  EXPECT_EQ(trace.size() + trace.dropped(), size_t(kFine + 10 + 4));
  const auto path = std::filesystem::temp_directory_path() / ("qemflow_trace_thin_" + std::to_string(::getpid()) + ".json");
  trace.write(path);
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::filesystem::remove(path);
  size_t phases = 0, longs = 0, fine = 0;
  double last_fine = -1;
  for (size_t at = text.find("\"name\":"); at != std::string::npos; at = text.find("\"name\":", at + 1)) {
    const size_t ts = text.find("\"ts\":", at);
    const std::string_view name = std::string_view(text).substr(at);
    if (name.starts_with("\"name\":\"rounds\"")) ++phases;
    if (name.starts_with("\"name\":\"load\"")) ++longs;
    if (name.starts_with("\"name\":\"decode\"")) {
      ++fine;
      last_fine = std::stod(text.substr(ts + 5));
    }
  }
  EXPECT_EQ(phases, 10u);
  EXPECT_EQ(longs, 4u);
  EXPECT_GT(fine, 16u);
  // The fine sample reaches the run's last tenth.
  EXPECT_GT(last_fine, 0.9 * 100.0 * kFine);
  EXPECT_NE(text.find("\"fine_events_kept_one_in\":"), std::string::npos);
}

}  // namespace
}  // namespace qemflow::engine
