#include "engine/process_memory.hpp"

#include <malloc.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

#include "util/memory.hpp"

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

namespace {
// Allocations through operator new of at least this many bytes get huge-page advice
// (0: none). At or above the mmap threshold, so each is its own mapping.
std::atomic<size_t> huge_pages_from{0};
}  // namespace

void tune_allocator(int trim_threshold, int arenas, int mmap_threshold, bool huge_pages) {
  mallopt(M_MMAP_THRESHOLD, mmap_threshold);
  mallopt(M_TRIM_THRESHOLD, trim_threshold);
  mallopt(M_ARENA_MAX, arenas);
  huge_pages_from.store(huge_pages ? size_t(mmap_threshold) : 0, std::memory_order_relaxed);
}

bool huge_pages_on_big_allocations() { return huge_page_advice_from() != 0; }

size_t huge_page_advice_from() { return huge_pages_from.load(std::memory_order_relaxed); }

void trim_allocator() { malloc_trim(0); }

const void* release_pages(const void* begin, const void* end) {
  static const uintptr_t page = uintptr_t(sysconf(_SC_PAGESIZE));
  const auto [from, to] = whole_pages(begin, end, page);
  if (to <= from) return begin;
  madvise(reinterpret_cast<void*>(from), to - from, MADV_DONTNEED);  // advice: a failure only keeps the pages
  return reinterpret_cast<const void*>(to);
}

void populate_pages(void* begin, void* end) {
#ifdef MADV_POPULATE_WRITE
  static const uintptr_t page = uintptr_t(sysconf(_SC_PAGESIZE));
  const auto [from, to] = whole_pages(begin, end, page);
  if (to > from) madvise(reinterpret_cast<void*>(from), to - from, MADV_POPULATE_WRITE);
#else
  (void)begin, (void)end;
#endif
}

void advise_huge_pages(const void* begin, const void* end) {
  const auto [from, to] = whole_pages(begin, end, 2 << 20);
  if (to <= from) return;
  madvise(reinterpret_cast<void*>(from), to - from, MADV_HUGEPAGE);  // advice: a failure keeps small pages
}

uint64_t measure_baseline(uint64_t margin) { return resident_bytes() + margin; }

}  // namespace qemflow::engine
