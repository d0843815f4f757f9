#include "engine/process_memory.hpp"

#include <malloc.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>

namespace qemflow::engine {

namespace {
uint64_t status_field_kib(const char* field) {
  std::ifstream status("/proc/self/status");
  std::string line;
  size_t n = std::strlen(field);
  while (std::getline(status, line)) {
    if (line.compare(0, n, field) == 0 && line.size() > n && line[n] == ':') {
      return std::stoull(line.substr(n + 1));
    }
  }
  return 0;
}
}  // namespace

uint64_t resident_bytes() { return status_field_kib("VmRSS") * 1024; }
uint64_t window_peak_resident_bytes() { return status_field_kib("VmHWM") * 1024; }

namespace {
std::atomic<uint64_t> peak_before_reset{0};
}

uint64_t peak_resident_bytes() { return std::max(peak_before_reset.load(), window_peak_resident_bytes()); }

bool reset_peak_resident() {
  peak_before_reset.store(peak_resident_bytes());
  FILE* file = std::fopen("/proc/self/clear_refs", "w");
  if (!file) return false;
  bool ok = std::fputs("5", file) >= 0;
  ok = (std::fclose(file) == 0) && ok;
  return ok;
}

void tune_allocator(int trim_threshold, int arenas) {
  mallopt(M_MMAP_THRESHOLD, 4 << 20);
  mallopt(M_TRIM_THRESHOLD, trim_threshold);
  mallopt(M_ARENA_MAX, arenas);
}

void trim_allocator() { malloc_trim(0); }

const void* release_pages(const void* begin, const void* end) {
  static const uintptr_t page = uintptr_t(sysconf(_SC_PAGESIZE));
  const uintptr_t from = (uintptr_t(begin) + page - 1) & ~(page - 1), to = uintptr_t(end) & ~(page - 1);
  if (to <= from) return begin;
  madvise(reinterpret_cast<void*>(from), to - from, MADV_DONTNEED);  // advice: a failure only keeps the pages
  return reinterpret_cast<const void*>(to);
}

void advise_huge_pages(const void* begin, const void* end) {
  constexpr uintptr_t huge = 2 << 20;
  const uintptr_t from = (uintptr_t(begin) + huge - 1) & ~(huge - 1), to = uintptr_t(end) & ~(huge - 1);
  if (to <= from) return;
  madvise(reinterpret_cast<void*>(from), to - from, MADV_HUGEPAGE);  // advice: a failure keeps small pages
}

uint64_t measure_baseline(uint64_t margin) { return resident_bytes() + margin; }

}  // namespace qemflow::engine
