#pragma once
// The dedicated I/O thread. Every read and write of input, scratch and output is a
// task on this one thread, in submission order, so the disk sees one sequential
// stream while compute threads keep (de)compressing and never wait on it.
//
// Contract
// - submit() queues a task and returns at once; call() queues it and waits for its
//   result (rethrowing its exception). Tasks run one at a time, FIFO.
// - A submitted task that throws hands its exception to the `on_error` it was
//   submitted with (never lost, never kills the thread).
// - Tasks must not block on compute work (they may block on the disk only); this is
//   what makes "compute waits for I/O" deadlock-free.
// - drain() waits until every task queued so far has finished. While call() and drain()
//   wait, the calling thread's compute span does not count it busy (Waiting).
// - bytes_in_flight: bytes queued for writing; shown as a trace counter.
// - The destructor drains and joins.
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <future>
#include <mutex>
#include <thread>

#include "engine/trace.hpp"

namespace qemflow::engine {

class IoThread {
 public:
  IoThread(Trace* trace, Activity* activity);
  ~IoThread();
  IoThread(const IoThread&) = delete;
  IoThread& operator=(const IoThread&) = delete;

  using ErrorHandler = std::function<void(std::exception_ptr)>;
  // `name` must be a string literal (it names the trace span). `write_bytes` counts
  // towards bytes in flight until the task ends.
  void submit(const char* name, std::function<void()> task, ErrorHandler on_error,
              uint64_t write_bytes = 0);

  template <class F>
  auto call(const char* name, F&& f) -> decltype(f()) {
    using R = decltype(f());
    std::packaged_task<R()> task(std::forward<F>(f));
    auto future = task.get_future();
    auto shared = std::make_shared<std::packaged_task<R()>>(std::move(task));
    submit(name, [shared] { (*shared)(); }, {});
    Waiting waiting;
    return future.get();
  }

  void drain();
  bool on_io_thread() const { return std::this_thread::get_id() == thread_.get_id(); }
  uint64_t bytes_in_flight() const;

 private:
  struct Task {
    const char* name;
    std::function<void()> run;
    ErrorHandler on_error;
    uint64_t write_bytes;
  };
  void loop();

  Trace* trace_;
  Activity* activity_;
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<Task> queue_;
  bool running_task_ = false;
  bool stop_ = false;
  uint64_t in_flight_ = 0;
  std::thread thread_;
};

}  // namespace qemflow::engine
