#pragma once
// A stable LSD radix sort by a 64-bit key. The patch build and the decimator's
// locality renumbering sort arrays of (unique key, index) pairs for every patch of
// every epoch: std::sort spent ~1 CPU-s of the 1M-face demo there. Radix passes only
// over the key bits that differ between elements (a patch's fids and gids span ~20
// bits), and skips a digit that all keys share.
#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace qemflow {

// Sorts `v` by key_of(element) (a uint64_t), keeping the given order among equal keys:
// so for unique keys, or for keys tied only where the elements are already in order,
// the result is std::sort's. Holds a second array of v's size while it runs.
template <class T, class KeyOf>
void radix_sort_by_key(std::vector<T>& v, KeyOf key_of) {
  constexpr int kDigitBits = 11;
  constexpr size_t kBuckets = size_t(1) << kDigitBits;
  constexpr int kMaxDigits = (64 + kDigitBits - 1) / kDigitBits;
  const size_t n = v.size();
  if (n < 2) return;
  const uint64_t first = key_of(v[0]);
  uint64_t differ = 0;
  for (const T& x : v) differ |= key_of(x) ^ first;
  if (differ == 0) return;
  const int low = std::countr_zero(differ);
  const int digits = (64 - std::countl_zero(differ) - low + kDigitBits - 1) / kDigitBits;
  std::vector<std::array<uint32_t, kBuckets>> counts(static_cast<size_t>(digits));
  for (auto& c : counts) c.fill(0);
  for (const T& x : v) {
    const uint64_t key = key_of(x) >> low;
    for (int d = 0; d < digits; ++d) ++counts[size_t(d)][(key >> (d * kDigitBits)) & (kBuckets - 1)];
  }
  static_assert(kMaxDigits <= 6);
  std::vector<T> other(n);
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
}

}  // namespace qemflow
