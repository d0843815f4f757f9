#pragma once
// Ctrl-C (SIGINT), SIGTERM and SIGHUP as a job's cancel, for the command line.
//
// Contract
// - install_interrupt_cancel() blocks those signals in the calling thread and starts a
//   thread that waits for them; call it first in main(), before any other thread
//   starts, so that every thread inherits the mask (a handler could not cancel: a
//   CancelToken takes a mutex).
// - interrupt_token() arms the waiting thread and returns the token it cancels: the
//   first signal then cancels the job holding it, which stops, removes its scratch and
//   partial output and ends with exit code 5 (DESIGN.md §6).
// - Unarmed (commands without a job: gen, compare, in-core simplify), and on a second
//   signal, the signal's default action ends the process, as if it were never caught.
#include <memory>

#include "engine/job.hpp"

namespace qemflow::engine {

void install_interrupt_cancel();
std::shared_ptr<CancelToken> interrupt_token();

}  // namespace qemflow::engine
