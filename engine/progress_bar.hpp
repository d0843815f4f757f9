#pragma once
// A progress bar with ETA on stderr, drawn only when stderr is a terminal and the
// user did not ask for --quiet. Hand callback() to the job as its progress hook.
#include <chrono>
#include <mutex>
#include <string>

#include "engine/job.hpp"

namespace qemflow::engine {

class ProgressBar {
 public:
  explicit ProgressBar(bool quiet);
  ~ProgressBar() { finish(); }
  bool active() const { return active_; }
  ProgressCallback callback();  // empty when inactive
  void finish();                // ends the line

 private:
  void draw(double fraction, const std::string& stage);
  bool active_ = false;
  bool drawn_ = false;
  std::mutex mutex_;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

}  // namespace qemflow::engine
