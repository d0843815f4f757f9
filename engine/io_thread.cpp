#include "engine/io_thread.hpp"

namespace qemflow::engine {

IoThread::IoThread(Trace* trace, Activity* activity)
    : trace_(trace), activity_(activity), thread_([this] { loop(); }) {}

IoThread::~IoThread() {
  drain();
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void IoThread::submit(const char* name, std::function<void()> task, ErrorHandler on_error,
                      uint64_t write_bytes) {
  uint64_t now;
  {
    std::lock_guard lock(mutex_);
    queue_.push_back({name, std::move(task), std::move(on_error), write_bytes});
    in_flight_ += write_bytes;
    now = in_flight_;
  }
  wake_.notify_one();
  if (write_bytes && trace_) trace_->counter("io bytes in flight", double(now));
}

void IoThread::drain() {
  Waiting waiting;
  std::unique_lock lock(mutex_);
  idle_.wait(lock, [this] { return queue_.empty() && !running_task_; });
}

uint64_t IoThread::bytes_in_flight() const {
  std::lock_guard lock(mutex_);
  return in_flight_;
}

void IoThread::loop() {
  if (trace_) trace_->name_thread("io");
  // The thread's CPU is what Activity takes out of the process's to leave the compute
  // threads' (it is ~0 between tasks: the thread sleeps).
  const double cpu_start = thread_cpu_seconds();
  std::unique_lock lock(mutex_);
  for (;;) {
    wake_.wait(lock, [this] { return stop_ || !queue_.empty(); });
    if (queue_.empty()) return;  // stop_ with nothing left
    Task task = std::move(queue_.front());
    queue_.pop_front();
    running_task_ = true;
    lock.unlock();
    {
      Span span(trace_, activity_, task.name, Span::Kind::io, task.write_bytes);
      try {
        task.run();
      } catch (...) {
        if (task.on_error) task.on_error(std::current_exception());
      }
    }
    uint64_t written = task.write_bytes;
    task = {};  // frees captured buffers before the next task
    if (activity_) activity_->set_io_cpu_seconds(thread_cpu_seconds() - cpu_start);
    lock.lock();
    in_flight_ -= written;
    running_task_ = false;
    uint64_t now = in_flight_;
    if (queue_.empty()) idle_.notify_all();
    if (trace_ && trace_->enabled()) {
      lock.unlock();
      trace_->counter("io bytes in flight", double(now));
      lock.lock();
    }
  }
}

}  // namespace qemflow::engine
