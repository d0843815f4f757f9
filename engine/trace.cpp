#include "engine/trace.hpp"

#include <oneapi/tbb/task_arena.h>

#include <time.h>

#include <algorithm>
#include <cstdio>
#include <memory>

#include "util/error.hpp"

namespace qemflow::engine {

namespace {
double cpu_seconds(clockid_t clock) {
  timespec t{};
  clock_gettime(clock, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

thread_local Span::ThreadState t_compute;
}  // namespace

double process_cpu_seconds() { return cpu_seconds(CLOCK_PROCESS_CPUTIME_ID); }
double thread_cpu_seconds() { return cpu_seconds(CLOCK_THREAD_CPUTIME_ID); }

Activity::Activity() : start_(Clock::now()), last_(start_), cpu_start_(process_cpu_seconds()) {}

void Activity::advance(Clock::time_point now) {
  double dt = std::chrono::duration<double>(now - last_).count();
  if (io_active_ > 0) io_ += dt;
  if (compute_active_ > 0) compute_ += dt;
  if (io_active_ > 0 && compute_active_ > 0) both_ += dt;
  last_ = now;
}

void Activity::change(int io_delta, int compute_delta) {
  std::lock_guard lock(mutex_);
  advance(Clock::now());
  io_active_ += io_delta;
  compute_active_ += compute_delta;
}

Activity::Totals Activity::totals() const {
  std::lock_guard lock(mutex_);
  auto* self = const_cast<Activity*>(this);
  self->advance(Clock::now());
  Totals t;
  t.wall_seconds = std::chrono::duration<double>(last_ - start_).count();
  t.io_busy_seconds = io_;
  t.compute_busy_seconds = compute_;
  t.process_cpu_seconds = process_cpu_seconds() - cpu_start_;
  t.compute_thread_seconds = std::max(0.0, t.process_cpu_seconds - io_cpu_.load(std::memory_order_relaxed));
  t.overlap_seconds = both_;
  return t;
}

Trace::Trace(size_t max_events) : max_events_(max_events), start_(Clock::now()) {
  if (max_events_) events_.reserve(max_events_);
}

double Trace::us_at(Clock::time_point time) const {
  return std::chrono::duration<double, std::micro>(time - start_).count();
}

uint32_t Trace::thread_id() {
  auto [it, inserted] = tids_.try_emplace(std::this_thread::get_id(), uint32_t(tids_.size() + 1));
  if (inserted && !thread_names_.count(it->second)) {
    int slot = tbb::this_task_arena::current_thread_index();
    thread_names_[it->second] = slot >= 0 ? "compute-" + std::to_string(slot)
                                          : "thread-" + std::to_string(it->second);
  }
  return it->second;
}

void Trace::name_thread(const std::string& name) {
  if (!enabled()) return;
  std::lock_guard lock(mutex_);
  thread_names_[thread_id()] = name;
}

void Trace::register_thread() {
  if (!enabled()) return;
  std::lock_guard lock(mutex_);
  thread_id();
}

bool Trace::is_fine(const Event& e) { return e.patch == kNoPatch && e.dur < kWholeSpanUs; }

bool Trace::make_room(bool fine) {
  if (fine && fine_seen_++ % fine_stride_ != 0) return false;
  if (events_.size() < max_events_) return true;
  // Full: every other fine event kept so far goes, and from now on one fine event in
  // twice as many is kept, so the buffer covers the whole run at a coarser grain.
  size_t kept = 0, fine_rank = 0;
  for (const Event& e : events_)
    if (!is_fine(e) || fine_rank++ % 2 == 0) events_[kept++] = e;
  const size_t thinned = events_.size() - kept;
  events_.resize(kept);
  dropped_ += thinned;
  if (thinned > 0) fine_stride_ *= 2;
  // Room now, and a fine event still on the coarser grid.
  return events_.size() < max_events_ && (!fine || (fine_seen_ - 1) % fine_stride_ == 0);
}

void Trace::span(const char* name, double start_us, double end_us, uint64_t bytes, uint32_t patch) {
  if (!enabled()) return;
  const Event event{name, start_us, end_us - start_us, bytes, 0, patch};
  std::lock_guard lock(mutex_);
  if (!make_room(is_fine(event))) {
    ++dropped_;
    return;
  }
  events_.push_back(event);
  events_.back().tid = thread_id();
}

void Trace::counter(const char* name, double value) {
  if (!enabled()) return;
  double now = now_us();
  std::lock_guard lock(mutex_);
  auto& last = last_counter_us_[name];
  if (last != 0 && now - last < 200) return;
  last = now;
  if (!make_room(true)) {
    ++dropped_;
    return;
  }
  events_.push_back({name, now, -1, uint64_t(value), 0, kNoPatch});
}

size_t Trace::size() const {
  std::lock_guard lock(mutex_);
  return events_.size();
}

namespace {
std::string json_string(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) continue;
    out += c;
  }
  return out + "\"";
}
}  // namespace

void Trace::check_writable(const std::filesystem::path& path) {
  std::error_code ec;
  const bool existed = std::filesystem::exists(path, ec);
  FILE* file = std::fopen(path.c_str(), "a");  // "a": an existing file keeps its bytes
  if (!file) throw Error(ErrorKind::resource, path.string() + ": cannot write the trace");
  std::fclose(file);
  if (!existed) std::filesystem::remove(path, ec);
}

void Trace::write(const std::filesystem::path& path) const {
  std::lock_guard lock(mutex_);
  std::unique_ptr<FILE, int (*)(FILE*)> file(std::fopen(path.c_str(), "w"), &std::fclose);
  if (!file) throw Error(ErrorKind::resource, path.string() + ": cannot write the trace");
  FILE* f = file.get();
  std::fprintf(f, "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[\n");
  std::fprintf(f, "{\"ph\":\"M\",\"pid\":1,\"tid\":0,\"name\":\"process_name\",\"args\":{\"name\":\"qemflow\"}}");
  for (const auto& [tid, name] : thread_names_) {
    std::fprintf(f, ",\n{\"ph\":\"M\",\"pid\":1,\"tid\":%u,\"name\":\"thread_name\",\"args\":{\"name\":%s}}",
                 tid, json_string(name).c_str());
    // "io" first, then compute threads, in Perfetto's track order.
    int order = name == "io" ? 0 : int(tid) + 1;
    std::fprintf(f, ",\n{\"ph\":\"M\",\"pid\":1,\"tid\":%u,\"name\":\"thread_sort_index\",\"args\":{\"sort_index\":%d}}",
                 tid, order);
  }
  for (const auto& e : events_) {
    if (e.dur < 0) {
      std::fprintf(f, ",\n{\"ph\":\"C\",\"pid\":1,\"name\":%s,\"ts\":%.3f,\"args\":{\"bytes\":%llu}}",
                   json_string(e.name).c_str(), e.ts, static_cast<unsigned long long>(e.value));
    } else {
      char patch[32] = "";
      if (e.patch != kNoPatch) std::snprintf(patch, sizeof patch, ",\"patch\":%u", e.patch);
      std::fprintf(f, ",\n{\"ph\":\"X\",\"pid\":1,\"tid\":%u,\"name\":%s,\"ts\":%.3f,\"dur\":%.3f,\"args\":{\"bytes\":%llu%s}}",
                   e.tid, json_string(e.name).c_str(), e.ts, e.dur,
                   static_cast<unsigned long long>(e.value), patch);
    }
  }
  std::fprintf(f, "\n],\"otherData\":{\"dropped_events\":%llu,\"fine_events_kept_one_in\":%llu}}\n",
               static_cast<unsigned long long>(dropped_.load()), static_cast<unsigned long long>(fine_stride_));
  if (std::ferror(f)) throw Error(ErrorKind::resource, path.string() + ": cannot write the trace");
}

Span::Span(Trace* trace, Activity* activity, const char* name, Kind kind, uint64_t bytes)
    : trace_(trace), activity_(activity), name_(name), kind_(kind), bytes_(bytes) {
  if (trace_ && trace_->enabled()) start_us_ = trace_->now_us();
  if (!activity_) return;
  if (kind_ == Kind::io) {
    activity_->io_begin();
    return;
  }
  if (t_compute.depth > 0 && t_compute.activity == activity_) {
    ++t_compute.depth;
    return;
  }
  // The first of this thread's spans (or one of another job's inside it: counted apart).
  saved_ = t_compute;
  t_compute = {activity_, 1};
  counted_ = true;
  activity_->compute_begin();
}

Span::~Span() {
  if (activity_) {
    if (kind_ == Kind::io) {
      activity_->io_end();
    } else if (counted_) {
      activity_->compute_end();
      t_compute = saved_;
    } else {
      --t_compute.depth;
    }
  }
  if (trace_ && trace_->enabled()) trace_->span(name_, start_us_, trace_->now_us(), bytes_, patch_);
}

Waiting::Waiting() : saved_(t_compute) {
  if (saved_.depth > 0) saved_.activity->compute_end();
  t_compute = {};
}

Waiting::~Waiting() {
  if (saved_.depth > 0) saved_.activity->compute_begin();
  t_compute = saved_;
}

}  // namespace qemflow::engine
