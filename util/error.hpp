#pragma once
// The one error type every qemflow layer throws. A library call never exits the
// process; the CLI maps ErrorKind to its documented exit code (DESIGN.md §6).
#include <stdexcept>
#include <string>

namespace qemflow {

enum class ErrorKind {
  internal = 1,   // a bug or an unexpected system failure
  usage = 2,      // bad flags or option values
  bad_input = 3,  // the input file is malformed (message names file, place, problem)
  resource = 4,   // memory budget, disk space, scratch directory, output not writable
  cancelled = 5,  // the host cancelled the job
};

inline int exit_code(ErrorKind kind) { return static_cast<int>(kind); }

class Error : public std::runtime_error {
 public:
  Error(ErrorKind kind, const std::string& message) : std::runtime_error(message), kind_(kind) {}
  ErrorKind kind() const noexcept { return kind_; }

 private:
  ErrorKind kind_;
};

// "FILE: PLACE: PROBLEM" — the one-line shape of every bad-input message.
[[noreturn]] inline void throw_bad_input(const std::string& file, const std::string& place,
                                         const std::string& problem) {
  throw Error(ErrorKind::bad_input, file + ": " + place + ": " + problem);
}

}  // namespace qemflow
