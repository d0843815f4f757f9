// radix_sort_by_key stands in for std::sort in the patch build and the decimator's
// renumbering, whose orders the output bytes depend on: it must give std::sort's order.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

#include <tbb/task_arena.h>

#include "util/parallel_select.hpp"
#include "util/radix_sort.hpp"

namespace {

using Pair = std::pair<uint64_t, uint32_t>;
uint64_t first_of(const Pair& x) { return x.first; }

// Pairs (key, index) in index order with keys drawn from `bits` bits shifted up by `low`.
std::vector<Pair> pairs(size_t n, int bits, int low, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<Pair> v(n);
  const uint64_t mask = bits >= 64 ? ~uint64_t(0) : (uint64_t(1) << bits) - 1;
  for (size_t i = 0; i < n; ++i) v[i] = {(rng() & mask) << low, uint32_t(i)};
  return v;
}

TEST(RadixSort, GivesStdSortsOrderForKeyThenIndexPairs) {
  // Few key bits (many ties, broken by index order), ~20 bits as a patch's fids, 63-bit
  // Morton codes, a digit all keys share, and the sizes around one element.
  for (const auto& [n, bits, low] : std::vector<std::tuple<size_t, int, int>>{
           {0, 8, 0}, {1, 8, 0}, {2, 8, 0}, {1000, 3, 0}, {50000, 20, 0}, {50000, 63, 0}, {20000, 64, 0},
           {30000, 12, 30}, {30000, 1, 63}}) {
    std::vector<Pair> v = pairs(n, bits, low, n * 131 + bits);
    std::vector<Pair> expected = v;
    std::sort(expected.begin(), expected.end());
    std::vector<Pair> stable = v;
    std::reverse(stable.begin(), stable.end());  // ties now against the index order
    std::vector<Pair> expected_stable = stable;
    std::stable_sort(expected_stable.begin(), expected_stable.end(),
                     [](const Pair& a, const Pair& b) { return a.first < b.first; });
    qemflow::radix_sort_by_key(v, first_of);
    qemflow::radix_sort_by_key(stable, first_of);
    EXPECT_EQ(v, expected) << n << " keys of " << bits << " bits";
    EXPECT_EQ(stable, expected_stable) << n << " keys of " << bits << " bits, reversed";
  }
}

TEST(RadixSort, SortsPlainKeys) {
  std::vector<uint64_t> v(40000);
  std::mt19937_64 rng(7);
  for (auto& x : v) x = rng() >> 1 | uint64_t(1) << 40;  // bit 40 always set: a shared digit
  std::vector<uint64_t> expected = v;
  std::sort(expected.begin(), expected.end());
  qemflow::radix_sort_by_key(v, [](uint64_t x) { return x; });
  EXPECT_EQ(v, expected);
}

}  // namespace

// The blocked parallel path (arrays over one block, an arena of more than one thread)
// and the serial one (an arena of one) give std::sort's order alike.
TEST(RadixSort, ParallelBlocksGiveTheSerialOrder) {
  for (const auto& [n, bits] : std::vector<std::pair<size_t, int>>{{200000, 20}, {300001, 63}, {100000, 4}}) {
    const std::vector<Pair> input = pairs(n, bits, 0, n + bits);
    std::vector<Pair> expected = input;
    std::sort(expected.begin(), expected.end());
    for (int threads : {1, 2, 3}) {
      std::vector<Pair> v = input;
      tbb::task_arena(threads).execute([&] { qemflow::radix_sort_by_key(v, first_of); });
      EXPECT_EQ(v, expected) << n << " keys of " << bits << " bits, " << threads << " threads";
    }
  }
}

TEST(ParallelSelect, GivesTheSerialSelectionInOrder) {
  const size_t n = 100000;
  std::vector<uint64_t> expected;
  auto keep = [](size_t i) { return (i * 2654435761u) % 7 < 3; };
  for (size_t i = 0; i < n; ++i)
    if (keep(i)) expected.push_back(i);
  for (int threads : {1, 2, 3}) {
    std::vector<uint64_t> got;
    tbb::task_arena(threads).execute([&] {
      qemflow::parallel_select(n, keep, [&](size_t total) { got.resize(total); },
                               [&](size_t i, size_t rank) { got[rank] = i; });
    });
    EXPECT_EQ(got, expected) << threads << " threads";
  }
}
