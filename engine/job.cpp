#include "engine/job.hpp"

#include "engine/process_memory.hpp"
#include "util/error.hpp"

namespace qemflow::engine {

void CancelToken::cancel() {
  std::vector<std::pair<uint64_t, std::function<void()>>> callbacks;
  {
    std::lock_guard lock(mutex_);
    if (cancelled_.exchange(true)) return;
    callbacks.swap(callbacks_);
  }
  for (auto& [id, callback] : callbacks) callback();
}

uint64_t CancelToken::on_cancel(std::function<void()> callback) {
  {
    std::lock_guard lock(mutex_);
    if (!cancelled_) {
      callbacks_.emplace_back(++next_id_, std::move(callback));
      return next_id_;
    }
  }
  callback();
  return 0;
}

void CancelToken::forget(uint64_t id) {
  std::lock_guard lock(mutex_);
  std::erase_if(callbacks_, [id](const auto& entry) { return entry.first == id; });
}

size_t CancelToken::pending() const {
  std::lock_guard lock(mutex_);
  return callbacks_.size();
}

Job::Job(Governor& governor, JobHooks hooks, JobSettings settings)
    : governor_(governor),
      hooks_(std::move(hooks)),
      settings_(std::move(settings)),
      trace_(settings_.trace_events),
      arena_(settings_.threads > 0 ? settings_.threads : tbb::task_arena::automatic) {
  if (trace_.enabled()) {
    trace_lease_ = governor_.acquire(owner("trace"), settings_.trace_events * Trace::bytes_per_event,
                                     settings_.trace_events * Trace::bytes_per_event);
    observer_ = governor_.add_observer(
        [this](uint64_t in_use) { trace_.counter("governor bytes in use", double(in_use)); });
  }
  io_ = std::make_unique<IoThread>(&trace_, &activity_);
  governor_.job_started();
  alive_ = std::make_shared<std::atomic<Job*>>(this);
  if (hooks_.cancel) {
    cancel_callback_ = hooks_.cancel->on_cancel([alive = alive_] {
      if (Job* job = alive->load()) {
        job->fail(std::make_exception_ptr(Error(ErrorKind::cancelled, "cancelled")));
      }
    });
  }
}

Job::~Job() {
  alive_->store(nullptr);
  io_.reset();  // drains: no I/O task may outlive the job
  governor_.job_ended();
  if (observer_) governor_.remove_observer(observer_);
  if (hooks_.cancel && cancel_callback_) hooks_.cancel->forget(cancel_callback_);
}

std::unique_ptr<Governor> reserve_for_job(Governor& shared, const std::string& owner_prefix, uint64_t bytes,
                                          const JobHooks& hooks) {
  if (bytes == 0) bytes = shared.capacity();
  // A cancel wakes the wait; the callback may fire after the wait (or the shared
  // governor) is gone, so it finds the governor through a pointer cleared under a lock.
  struct Waiting {
    std::mutex mutex;
    Governor* governor;
  };
  auto waiting = std::make_shared<Waiting>();
  waiting->governor = &shared;
  const uint64_t wake = hooks.cancel ? hooks.cancel->on_cancel([waiting] {
    std::lock_guard lock(waiting->mutex);
    if (waiting->governor) waiting->governor->wake_all();
  })
                                     : 0;
  struct Clear {
    Waiting& waiting;
    const JobHooks& hooks;
    uint64_t wake;
    ~Clear() {
      if (hooks.cancel && wake) hooks.cancel->forget(wake);
      std::lock_guard lock(waiting.mutex);
      waiting.governor = nullptr;
    }
  } clear{*waiting, hooks, wake};
  return std::make_unique<Governor>(shared, owner_prefix + "job", bytes,
                                    [&] { return hooks.cancel && hooks.cancel->cancelled(); });
}

SoleJobPeakWindow::SoleJobPeakWindow(const Governor& governor)
    : governor_(governor), started_(governor.jobs_started()) {
  open_ = governor.jobs_alive() == 1;  // after started_ (Governor::job_started)
  if (open_) reset_peak_resident();
}

uint64_t SoleJobPeakWindow::peak() const {
  const bool alone = open_ && governor_.jobs_alive() == 1 && governor_.jobs_started() == started_;
  return alone ? window_peak_resident_bytes() : 0;
}

void Job::fail(std::exception_ptr error) {
  {
    std::lock_guard lock(mutex_);
    if (!error_) error_ = error;
  }
  stopped_ = true;
  governor_.wake_all();
}

void Job::check() {
  if (!stopped()) return;
  std::exception_ptr error;
  {
    std::lock_guard lock(mutex_);
    error = error_;
  }
  if (error) std::rethrow_exception(error);
  throw Error(ErrorKind::cancelled, "cancelled");
}

void Job::progress(double fraction, const std::string& stage) {
  if (!hooks_.progress) return;
  const int64_t now = Clock::now().time_since_epoch().count();
  const bool due = fraction >= 1.0 || now - last_progress_ns_.load(std::memory_order_relaxed) >= 50'000'000;
  std::lock_guard lock(progress_mutex_);
  // A new stage's first report always goes through (a stage shorter than the limit
  // would otherwise never show, nor would its start).
  if (!due && stage == progress_stage_) return;
  last_progress_ns_.store(now, std::memory_order_relaxed);
  if (stage != progress_stage_) progress_stage_ = stage;
  const double mapped = progress_from_ + (progress_to_ - progress_from_) * std::clamp(fraction, 0.0, 1.0);
  progress_reported_ = std::max(progress_reported_, mapped);
  hooks_.progress(progress_reported_, stage);
}

void Job::progress_span(double from, double to) {
  std::lock_guard lock(progress_mutex_);
  progress_from_ = from;
  progress_to_ = to;
}

StageTimer::StageTimer(Job& job, const std::string& stage)
    : job_(job), stage_(job.stage(stage)), start_(job.activity().totals()) {
  if (job.timed_stage_) {
    throw Error(ErrorKind::internal, "stage \"" + stage + "\" timed inside stage \"" + job.timed_stage_->name + "\"");
  }
  job.timed_stage_ = &stage_;
}

StageTimer::~StageTimer() {
  job_.timed_stage_ = nullptr;
  const Activity::Totals end = job_.activity().totals();
  stage_.seconds += end.wall_seconds - start_.wall_seconds;
  stage_.cpu_seconds += end.process_cpu_seconds - start_.process_cpu_seconds;
  stage_.io_busy_seconds += end.io_busy_seconds - start_.io_busy_seconds;
  stage_.compute_busy_seconds += end.compute_busy_seconds - start_.compute_busy_seconds;
  stage_.overlap_seconds += end.overlap_seconds - start_.overlap_seconds;
}

StageStats& Job::stage(const std::string& name) {
  std::lock_guard lock(mutex_);
  for (auto& s : stages_) {
    if (s->name == name) return *s;
  }
  stages_.push_back(std::make_unique<StageStats>());
  stages_.back()->name = name;
  return *stages_.back();
}

std::vector<const StageStats*> Job::stages() const {
  std::lock_guard lock(const_cast<std::mutex&>(mutex_));
  std::vector<const StageStats*> result;
  for (const auto& s : stages_) result.push_back(s.get());
  return result;
}

}  // namespace qemflow::engine
