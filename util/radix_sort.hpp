#pragma once
// A stable LSD radix sort by a 64-bit key. The patch build and the decimator's
// locality renumbering sort arrays of (unique key, index) pairs for every patch of
// every epoch: std::sort spent ~1 CPU-s of the 1M-face demo there. Radix passes only
// over the key bits that differ between elements (a patch's fids and gids span ~20
// bits), and skips a digit that all keys share.
//
// In an arena of more than one thread a large array is sorted in blocks: each pass
// counts every block's digits, then scatters the blocks in parallel, each to its
// slice of every bucket (the block's offset in a bucket is the count of the blocks
// before it). A stable sort has one result, so this is the serial sort's order
// whatever the thread count or the blocks. Why: these sorts ran on one core while the
// other idled, in every patch's build, setup, extract and export.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "util/parallel_fill.hpp"
#include "util/parallel_select.hpp"

namespace qemflow {

namespace radix_detail {
constexpr int kDigitBits = 11;
constexpr size_t kBuckets = size_t(1) << kDigitBits;
// Elements per block of the parallel sort: its counts (8 KiB a block) stay small
// beside the block's data, and a patch's arrays (~10^5-10^6) give a few blocks per thread.
constexpr size_t kBlock = size_t(1) << 15;
}  // namespace radix_detail

// Sorts `v` by key_of(element) (a uint64_t), keeping the given order among equal keys:
// so for unique keys, or for keys tied only where the elements are already in order,
// the result is std::sort's. Holds a second array of v's size while it runs (of v's
// type: an UninitializedVector's is not zeroed; its fresh pages fault in on every
// thread, parallel_fill.hpp).
template <class T, class A, class KeyOf>
void radix_sort_by_key(std::vector<T, A>& v, KeyOf key_of) {
  using radix_detail::kBlock;
  using radix_detail::kBuckets;
  using radix_detail::kDigitBits;
  constexpr int kMaxDigits = (64 + kDigitBits - 1) / kDigitBits;
  static_assert(kMaxDigits <= 6);
  const size_t n = v.size();
  if (n < 2) return;
  const uint64_t first = key_of(v[0]);
  // One thread (an arena of one, or --threads 1's global limit): the serial sort, which
  // reads the keys once less per digit.
  const bool parallel = parallel_threads() > 1;
  const size_t blocks = parallel ? (n + kBlock - 1) / kBlock : 1;
  uint64_t differ = 0;
  if (blocks > 1) {
    differ = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, n, kBlock), uint64_t{0},
        [&](const tbb::blocked_range<size_t>& r, uint64_t acc) {
          for (size_t i = r.begin(); i < r.end(); ++i) acc |= key_of(v[i]) ^ first;
          return acc;
        },
        std::bit_or<uint64_t>());
  } else {
    for (const T& x : v) differ |= key_of(x) ^ first;
  }
  if (differ == 0) return;
  const int low = std::countr_zero(differ);
  const int digits = (64 - std::countl_zero(differ) - low + kDigitBits - 1) / kDigitBits;
  std::vector<T, A> other;
  parallel_resize(other, n);
  if (blocks <= 1) {
    // One block: every digit's counts in one read (they do not change as elements move).
    std::vector<std::array<uint32_t, kBuckets>> counts(static_cast<size_t>(digits));
    for (auto& c : counts) c.fill(0);
    for (const T& x : v) {
      const uint64_t key = key_of(x) >> low;
      for (int d = 0; d < digits; ++d) ++counts[size_t(d)][(key >> (d * kDigitBits)) & (kBuckets - 1)];
    }
    for (int d = 0; d < digits; ++d) {
      auto& count = counts[size_t(d)];
      const int shift = low + d * kDigitBits;
      if (count[(key_of(v[0]) >> shift) & (kBuckets - 1)] == n) continue;  // one bucket: nothing moves
      uint32_t sum = 0;
      for (uint32_t& c : count) {
        const uint32_t here = c;
        c = sum;
        sum += here;
      }
      for (const T& x : v) other[count[(key_of(x) >> shift) & (kBuckets - 1)]++] = x;
      v.swap(other);
    }
    return;
  }
  // Per block and bucket: the count, then the block's first slot in the bucket. A
  // block's counts change as elements move, so each pass counts its own digit.
  std::vector<uint32_t> at(blocks * kBuckets);
  auto each_block = [&](auto&& body) { for_each_block(n, kBlock, body); };
  for (int d = 0; d < digits; ++d) {
    const int shift = low + d * kDigitBits;
    each_block([&](size_t b, size_t begin, size_t end) {
      uint32_t* count = at.data() + b * kBuckets;
      std::fill(count, count + kBuckets, 0u);
      for (size_t i = begin; i < end; ++i) ++count[(key_of(v[i]) >> shift) & (kBuckets - 1)];
    });
    const size_t first_bucket = (key_of(v[0]) >> shift) & (kBuckets - 1);
    uint64_t in_first = 0;
    for (size_t b = 0; b < blocks; ++b) in_first += at[b * kBuckets + first_bucket];
    if (in_first == n) continue;  // one bucket: nothing moves
    uint32_t sum = 0;
    for (size_t bucket = 0; bucket < kBuckets; ++bucket)
      for (size_t b = 0; b < blocks; ++b) {
        uint32_t& c = at[b * kBuckets + bucket];
        const uint32_t here = c;
        c = sum;
        sum += here;
      }
    each_block([&](size_t b, size_t begin, size_t end) {
      uint32_t* slot = at.data() + b * kBuckets;
      for (size_t i = begin; i < end; ++i) other[slot[(key_of(v[i]) >> shift) & (kBuckets - 1)]++] = v[i];
    });
    v.swap(other);
  }
}

}  // namespace qemflow
