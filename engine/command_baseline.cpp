// engine::command_baseline (process_memory.hpp). Apart from process_memory.cpp so that a
// host linking the engine's allocator and baseline helpers needs no other library
// (tests/engine/host_link: the config library is not on a host's link line).
#include <optional>

#include "config/size.hpp"
#include "engine/process_memory.hpp"

namespace qemflow::engine {

uint64_t command_baseline() {
  static const std::optional<uint64_t> fixed = config::env_byte_count("QEMFLOW_BASELINE", false);
  return fixed ? *fixed : measure_baseline();
}

}  // namespace qemflow::engine
