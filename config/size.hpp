#pragma once
// Byte sizes as users write them: "4G", "512M", "1.5G", "65536", "256MiB".
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace qemflow::config {

// Binary multiples (K = 1024). Throws Error(usage) naming the text on bad input.
uint64_t parse_size(std::string_view text);
// The inverse for messages: 268435456 -> "256 MiB", 1610612736 -> "1.5 GiB".
std::string format_size(uint64_t bytes);
// A budget to name in a refusal: `bytes` rounded up to a whole MiB, so that what the
// message prints (and a user types back) is never below what it stands for.
std::string format_budget(uint64_t bytes);

// A test or diagnosis variable (QEMFLOW_BASELINE, QEMFLOW_SCRATCH_FREE) holding a plain
// byte count: nullopt when unset; Error(usage) "NAME=TEXT: not a byte count" when it is
// not decimal digits (or is 0 where zero is not allowed).
std::optional<uint64_t> env_byte_count(const char* name, bool allow_zero);

}  // namespace qemflow::config
