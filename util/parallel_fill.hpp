#pragma once
// Fresh arrays first touched in parallel. A big array is a new mapping every time it is
// made (engine::tune_allocator), so its first write faults in every page and the kernel
// zeroes each one; std::vector's value-initialisation (resize, assign, the sized
// constructor) makes that first write, page faults and zeroing included, on one core.
// An UninitializedVector sized without a write and filled by parallel_fill puts them
// on every thread instead. A std::vector that must stay one (a public struct's field)
// is sized by parallel_resize: its pages are faulted in on every thread first, and
// only the zeroing of resident pages is left serial. Measured in the out-of-core
// simplify's patch setup and extract (PatchDecimator), whose arrays are new in every
// patch of every pass.
#include <sys/mman.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "util/memory.hpp"

namespace qemflow {

// Elements each task of a parallel fill writes at least: whole pages (and for a huge
// page, a few tasks each), so that tasks do not share the pages they fault in.
template <class T>
constexpr size_t kFillGrain = std::max<size_t>(1, (size_t(64) << 10) / sizeof(T));

// Writes `value` to v[0, n), in parallel.
template <class T>
void parallel_fill(T* v, size_t n, const T& value) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, kFillGrain<T>),
                    [&](const tbb::blocked_range<size_t>& r) { std::fill(v + r.begin(), v + r.end(), value); });
}

// v = n copies of `value` (what std::vector::assign leaves), its pages first touched in
// parallel. Storage too small is freed first (assign would not copy it either).
template <class T>
void parallel_assign(UninitializedVector<T>& v, size_t n, const T& value) {
  if (v.capacity() < n) release_memory(v);
  v.resize(n);
  parallel_fill(v.data(), n, value);
}

// Faults in the pages of [begin, end) for writing, in parallel slices of whole huge
// pages (madvise MADV_POPULATE_WRITE, Linux 5.14; advice: where refused, the first
// writes fault them in as before). The range must be memory the caller owns.
inline void parallel_populate(void* begin, void* end) {
#ifdef MADV_POPULATE_WRITE
  constexpr uintptr_t kSlice = uintptr_t(4) << 20;  // two 2 MiB pages
  const auto [lo, hi] = whole_pages(begin, end, 4096);
  if (hi <= lo || hi - lo < kSlice) return;  // small: not worth the tasks
  const uintptr_t first = (lo + kSlice - 1) & ~(kSlice - 1);  // slice boundaries aligned
  const size_t slices = (hi - first + kSlice - 1) / kSlice + 1;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, slices, 1), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) {
      const uintptr_t a = i == 0 ? lo : first + (i - 1) * kSlice;
      const uintptr_t b = i == 0 ? std::min(first, hi) : std::min(first + i * kSlice, hi);
      if (b > a) madvise(reinterpret_cast<void*>(a), b - a, MADV_POPULATE_WRITE);
    }
  });
#else
  (void)begin;
  (void)end;
#endif
}

// v.resize(n) of an empty std::vector whose storage faults in on every thread: the
// fresh pages are populated in parallel before the value-initialisation writes them.
template <class T, class A>
void parallel_resize(std::vector<T, A>& v, size_t n) {
  if (v.empty() && n > v.capacity()) {
    v.reserve(n);
    parallel_populate(v.data(), v.data() + n);
  }
  v.resize(n);
}

}  // namespace qemflow
