#include "engine/interrupt.hpp"

#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <thread>

namespace qemflow::engine {
namespace {

std::atomic<bool> armed{false};

std::shared_ptr<CancelToken>& token() {
  static auto shared = std::make_shared<CancelToken>();
  return shared;
}

sigset_t interrupt_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGHUP);
  return set;
}

[[noreturn]] void die_by(int signal_number) {
  // The default action, delivered to this thread, the only one with the signal unblocked.
  ::signal(signal_number, SIG_DFL);
  sigset_t one;
  sigemptyset(&one);
  sigaddset(&one, signal_number);
  pthread_sigmask(SIG_UNBLOCK, &one, nullptr);
  ::raise(signal_number);
  ::_exit(128 + signal_number);
}

}  // namespace

void install_interrupt_cancel() {
  const sigset_t set = interrupt_signals();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  (void)token();  // made before the waiting thread can read it
  std::thread([set] {
    int signal_number = 0;
    if (sigwait(&set, &signal_number) != 0) return;
    if (!armed.load()) die_by(signal_number);
    token()->cancel();
    if (sigwait(&set, &signal_number) == 0) die_by(signal_number);
  }).detach();
}

std::shared_ptr<CancelToken> interrupt_token() {
  armed.store(true);
  return token();
}

}  // namespace qemflow::engine
