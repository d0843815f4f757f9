#include "engine/retained_buffers.hpp"

#include <malloc.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <mutex>

#include "engine/process_memory.hpp"

namespace qemflow::engine {

namespace {

// Fixed tables, not containers: the hooks run inside operator new and delete, where a
// container's own allocation would call them again. While `kept` is full a freed buffer
// goes back to the OS as usual; while `lent` is full no kept buffer is handed out.
constexpr size_t kEntries = 512;
struct Kept {
  void* p;
  size_t usable;
  uint64_t resident;  // its pages in memory when it was freed
};
struct Lent {
  void* p;
  uint64_t resident;  // the pages it held when handed out again
};
struct State {
  std::mutex mutex;  // never held while a governor's lock is taken
  std::atomic<bool> open{false};
  const Governor* governor = nullptr;
  Kept kept[kEntries];
  size_t kept_count = 0;
  Lent lent[kEntries];
  size_t lent_count = 0;
  RetainedBuffers::Counts counts;
};
State& state() {
  static State s;
  return s;
}

bool considered(size_t size) {
  const size_t from = huge_page_advice_from();
  return from != 0 && size >= from;
}

// The bytes of [p, p + size) in memory (mincore, over whole pages), under the lock.
uint64_t resident_bytes_of(const void* p, size_t size) {
  static const uintptr_t page = uintptr_t(sysconf(_SC_PAGESIZE));
  static unsigned char in_memory[1 << 16];
  uintptr_t at = reinterpret_cast<uintptr_t>(p) & ~(page - 1);
  const uintptr_t end = reinterpret_cast<uintptr_t>(p) + size;
  uint64_t resident = 0;
  while (at < end) {
    const size_t pages = std::min<size_t>(sizeof in_memory, (end - at + page - 1) / page);
    if (mincore(reinterpret_cast<void*>(at), pages * page, in_memory) != 0) return (end - at) + resident;  // unknown: all
    for (size_t i = 0; i < pages; ++i) resident += (in_memory[i] & 1) ? page : 0;
    at += pages * page;
  }
  return resident;
}

void unmap_kept(State& s, size_t i) {
  std::free(s.kept[i].p);
  s.counts.kept_bytes -= s.kept[i].resident;
  ++s.counts.unmapped;
  s.kept[i] = s.kept[--s.kept_count];
}

}  // namespace

RetainedBuffers::RetainedBuffers(Governor& governor) : governor_(governor) {
  State& s = state();
  {
    const std::lock_guard lock(s.mutex);
    if (s.open.load(std::memory_order_relaxed)) return;  // another scope is open: this one keeps nothing
    s.governor = &governor;
    s.kept_count = s.lent_count = 0;
    s.counts = {};
    s.open.store(true, std::memory_order_release);
    open_ = true;
  }
  governor_.set_reclaimable(this);  // after the state's lock: grants take the governor's lock, then it
}

RetainedBuffers::~RetainedBuffers() {
  if (!open_) return;
  governor_.set_reclaimable(nullptr);
  State& s = state();
  const std::lock_guard lock(s.mutex);
  while (s.kept_count) unmap_kept(s, s.kept_count - 1);
  s.lent_count = 0;  // still in use: freed as usual later
  s.counts = {};
  s.governor = nullptr;
  s.open.store(false, std::memory_order_release);
}

uint64_t RetainedBuffers::held() const {
  State& s = state();
  const std::lock_guard lock(s.mutex);
  return s.counts.kept_bytes + s.counts.lent_bytes;
}

void RetainedBuffers::reclaim(uint64_t bytes) {
  State& s = state();
  const std::lock_guard lock(s.mutex);
  uint64_t freed = 0;
  while (freed < bytes && s.kept_count) {
    size_t largest = 0;
    for (size_t i = 1; i < s.kept_count; ++i)
      if (s.kept[i].resident > s.kept[largest].resident) largest = i;
    freed += s.kept[largest].resident;
    unmap_kept(s, largest);
  }
}

RetainedBuffers::Counts RetainedBuffers::counts() const {
  if (!open_) return {};
  State& s = state();
  const std::lock_guard lock(s.mutex);
  return s.counts;
}

void* take_retained_buffer(size_t size) noexcept {
  State& s = state();
  if (!s.open.load(std::memory_order_acquire) || !considered(size)) return nullptr;
  const std::lock_guard lock(s.mutex);
  if (!s.open.load(std::memory_order_relaxed) || s.lent_count == kEntries) return nullptr;
  // The smallest kept buffer that holds `size`, if at most about twice as large.
  size_t best = s.kept_count;
  for (size_t i = 0; i < s.kept_count; ++i) {
    const size_t usable = s.kept[i].usable;
    if (usable >= size && usable <= 2 * size + (size_t(2) << 20) &&
        (best == s.kept_count || usable < s.kept[best].usable))
      best = i;
  }
  if (best == s.kept_count) return nullptr;
  const Kept k = s.kept[best];
  s.kept[best] = s.kept[--s.kept_count];
  s.counts.kept_bytes -= k.resident;
  // Its pages past `size` go back to the OS, from the next 2 MiB boundary (a huge page
  // split in two would leave the rest on small pages); those before stay held until it
  // is freed.
  constexpr uintptr_t kHugePage = uintptr_t(2) << 20;
  const uintptr_t end = reinterpret_cast<uintptr_t>(k.p) + size;
  const uintptr_t keep_to = (end + kHugePage - 1) & ~(kHugePage - 1);
  const uintptr_t usable_end = reinterpret_cast<uintptr_t>(k.p) + k.usable;
  if (keep_to < usable_end) release_pages(reinterpret_cast<const void*>(keep_to), reinterpret_cast<const void*>(usable_end));
  const uint64_t lent = std::min<uint64_t>(k.resident, keep_to - reinterpret_cast<uintptr_t>(k.p));
  s.lent[s.lent_count++] = {k.p, lent};
  s.counts.lent_bytes += lent;
  ++s.counts.reused;
  s.counts.reused_bytes += size;
  return k.p;
}

bool retain_buffer(void* p) noexcept {
  State& s = state();
  if (!p || !s.open.load(std::memory_order_acquire)) return false;
  const size_t usable = malloc_usable_size(p);
  if (!considered(usable)) return false;
  const std::lock_guard lock(s.mutex);
  if (!s.open.load(std::memory_order_relaxed)) return false;
  for (size_t i = 0; i < s.lent_count; ++i)
    if (s.lent[i].p == p) {  // back from its second use: its pages are measured again below
      s.counts.lent_bytes -= s.lent[i].resident;
      s.lent[i] = s.lent[--s.lent_count];
      break;
    }
  if (s.kept_count == kEntries) return false;
  const uint64_t resident = resident_bytes_of(p, usable);
  // Kept only into room the governor's leases leave beside what is held already.
  const uint64_t capacity = s.governor->capacity();
  const uint64_t in_use = std::min(s.governor->in_use_now(), capacity);
  if (s.counts.kept_bytes + s.counts.lent_bytes + resident > capacity - in_use) return false;
  s.kept[s.kept_count++] = {p, usable, resident};
  s.counts.kept_bytes += resident;
  return true;
}

}  // namespace qemflow::engine
