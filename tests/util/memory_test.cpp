// whole_pages bounds every madvise the project makes (release_pages, advise_huge_pages,
// parallel_populate): a page that reaches past either end must not be in it, or the
// advice would drop or populate a neighbour's bytes.
#include <gtest/gtest.h>

#include <cstdint>

#include "util/memory.hpp"

namespace {

const void* at(uintptr_t address) { return reinterpret_cast<const void*>(address); }

TEST(WholePages, KeepOnlyThePagesInsideTheRange) {
  constexpr uintptr_t kPage = 4096;
  auto [from, to] = qemflow::whole_pages(at(10 * kPage + 1), at(13 * kPage + 7), kPage);
  EXPECT_EQ(from, 11 * kPage);
  EXPECT_EQ(to, 13 * kPage);
  std::tie(from, to) = qemflow::whole_pages(at(10 * kPage), at(12 * kPage), kPage);  // aligned ends are kept
  EXPECT_EQ(from, 10 * kPage);
  EXPECT_EQ(to, 12 * kPage);
  std::tie(from, to) = qemflow::whole_pages(at(10 * kPage + 1), at(11 * kPage + 9), kPage);  // no whole page
  EXPECT_GE(from, to);
  constexpr uintptr_t kHuge = uintptr_t(2) << 20;
  std::tie(from, to) = qemflow::whole_pages(at(kHuge - 1), at(3 * kHuge + 1), kHuge);
  EXPECT_EQ(from, kHuge);
  EXPECT_EQ(to, 3 * kHuge);
}

}  // namespace
