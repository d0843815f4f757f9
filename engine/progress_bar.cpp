#include "engine/progress_bar.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace qemflow::engine {

ProgressBar::ProgressBar(bool quiet) : active_(!quiet && ::isatty(2)) {}

ProgressCallback ProgressBar::callback() {
  if (!active_) return {};
  return [this](double fraction, const std::string& stage) { draw(fraction, stage); };
}

void ProgressBar::draw(double fraction, const std::string& stage) {
  std::lock_guard lock(mutex_);
  fraction = std::clamp(fraction, 0.0, 1.0);
  double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  char eta[32] = "--:--";
  if (fraction > 0.01) {
    int left = int(elapsed * (1 - fraction) / fraction);
    std::snprintf(eta, sizeof eta, "%d:%02d", left / 60, left % 60);
  }
  constexpr int width = 30;
  int filled = int(fraction * width);
  std::string bar(size_t(filled), '#');
  bar.resize(width, '.');
  std::fprintf(stderr, "\r[%s] %3.0f%% %-10s ETA %s ", bar.c_str(), fraction * 100, stage.c_str(), eta);
  std::fflush(stderr);
  drawn_ = true;
}

void ProgressBar::finish() {
  std::lock_guard lock(mutex_);
  if (drawn_) std::fprintf(stderr, "\r\033[K");
  drawn_ = false;
}

}  // namespace qemflow::engine
