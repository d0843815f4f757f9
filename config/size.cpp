#include "config/size.hpp"

#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "util/error.hpp"

namespace qemflow::config {

uint64_t parse_size(std::string_view text) {
  auto fail = [&](const char* why) -> uint64_t {
    throw Error(ErrorKind::usage, "invalid size '" + std::string(text) + "': " + why +
                                      " (examples: 4G, 512M, 1.5G, 65536)");
  };
  size_t pos = 0;
  while (pos < text.size() && (std::isdigit(static_cast<unsigned char>(text[pos])) || text[pos] == '.')) ++pos;
  if (pos == 0) return fail("expected a number");
  double value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + pos, value);
  if (ec != std::errc() || end != text.data() + pos) return fail("expected a number");
  std::string unit;
  for (char c : text.substr(pos)) unit.push_back(static_cast<char>(std::toupper(static_cast<unsigned char>(c))));
  double scale = 1;
  if (unit.empty() || unit == "B") scale = 1;
  else if (unit == "K" || unit == "KB" || unit == "KIB") scale = 1024.0;
  else if (unit == "M" || unit == "MB" || unit == "MIB") scale = 1024.0 * 1024;
  else if (unit == "G" || unit == "GB" || unit == "GIB") scale = 1024.0 * 1024 * 1024;
  else if (unit == "T" || unit == "TB" || unit == "TIB") scale = 1024.0 * 1024 * 1024 * 1024;
  else return fail("unknown unit");
  double bytes = std::floor(value * scale);
  if (!(bytes >= 1) || bytes > 9.0e18) return fail("out of range");
  return static_cast<uint64_t>(bytes);
}

std::string format_size(uint64_t bytes) {
  static const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  double value = static_cast<double>(bytes);
  int unit = 0;
  while (value >= 1024 && unit < 4) { value /= 1024; ++unit; }
  char buffer[32];
  if (unit == 0) std::snprintf(buffer, sizeof buffer, "%llu B", static_cast<unsigned long long>(bytes));
  else std::snprintf(buffer, sizeof buffer, "%.4g %s", value, units[unit]);
  return buffer;
}

std::string format_budget(uint64_t bytes) {
  const uint64_t mib = (bytes + (1u << 20) - 1) >> 20;
  return std::to_string(mib) + " MiB";
}

std::optional<uint64_t> env_byte_count(const char* name, bool allow_zero) {
  const char* text = std::getenv(name);
  if (!text) return std::nullopt;
  uint64_t bytes = 0;
  const char* end = text + std::strlen(text);
  const auto [at, error] = std::from_chars(text, end, bytes);
  if (error != std::errc() || at != end || (bytes == 0 && !allow_zero)) {
    throw Error(ErrorKind::usage, std::string(name) + "=" + text + ": not a byte count");
  }
  return bytes;
}

}  // namespace qemflow::config
