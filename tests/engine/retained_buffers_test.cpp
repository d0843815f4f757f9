// RetainedBuffers: big buffers freed inside the scope are kept (through the CLI's
// operator new, apps/qemflow/huge_page_new.cpp, linked into this test) and serve the
// next allocation that fits; they are kept only into room the governor's leases leave,
// and a grant that needs that room has them unmapped first.
#include <gtest/gtest.h>

#include <cstring>
#include <memory>

#include "engine/governor.hpp"
#include "engine/process_memory.hpp"
#include "engine/retained_buffers.hpp"

namespace qemflow::engine {
namespace {

constexpr uint64_t kMiB = 1u << 20;

// The out-of-core command's allocator settings (big allocations are their own
// mappings, considered from 2 MiB), undone at the end of each test.
class RetainedBuffersTest : public ::testing::Test {
 protected:
  void SetUp() override { tune_allocator(8 << 20, 1, 2 << 20, true); }
  void TearDown() override { tune_allocator(); }
};

// A buffer of `bytes`, every page written (resident).
std::unique_ptr<char[]> touched(uint64_t bytes) {
  std::unique_ptr<char[]> p(new char[bytes]);
  std::memset(p.get(), 1, bytes);
  return p;
}

TEST_F(RetainedBuffersTest, AFreedBufferServesTheNextAllocationThatFitsIt) {
  Governor governor(1024 * kMiB, 0);
  RetainedBuffers retained(governor);
  auto first = touched(16 * kMiB);
  const char* at = first.get();
  first.reset();
  EXPECT_GE(retained.counts().kept_bytes, 16 * kMiB);
  EXPECT_EQ(retained.held(), retained.counts().kept_bytes);
  auto second = std::unique_ptr<char[]>(new char[12 * kMiB]);  // fits in it, less than twice as small
  EXPECT_EQ(second.get(), at);
  RetainedBuffers::Counts counts = retained.counts();
  EXPECT_EQ(counts.reused, 1u);
  EXPECT_EQ(counts.kept_bytes, 0u);
  // Its pages up to the size asked, and on to the next huge-page boundary, stay counted.
  EXPECT_GE(counts.lent_bytes, 12 * kMiB);
  EXPECT_LE(counts.lent_bytes, 14 * kMiB);
  auto third = std::unique_ptr<char[]>(new char[4 * kMiB]);  // nothing kept: afresh
  EXPECT_NE(third.get(), at);
  second.reset();
  counts = retained.counts();
  EXPECT_EQ(counts.lent_bytes, 0u);
  EXPECT_GE(counts.kept_bytes, 12 * kMiB);
  // A buffer more than about twice the size asked for is not handed out.
  auto small = std::unique_ptr<char[]>(new char[3 * kMiB]);
  EXPECT_NE(small.get(), at);
  EXPECT_EQ(retained.counts().reused, 1u);
}

TEST_F(RetainedBuffersTest, AGrantUnmapsKeptBuffersToMakeRoom) {
  Governor governor(64 * kMiB, 0);
  RetainedBuffers retained(governor);
  touched(32 * kMiB).reset();
  EXPECT_GE(retained.held(), 32 * kMiB);
  // Within what the kept buffer leaves: it stays.
  Lease small = governor.acquire("small", 16 * kMiB, 16 * kMiB);
  EXPECT_GE(retained.held(), 32 * kMiB);
  EXPECT_EQ(retained.counts().unmapped, 0u);
  // Needing its room: it goes first, and leases plus held memory fit the capacity.
  Lease big = governor.acquire("big", 32 * kMiB, 32 * kMiB);
  EXPECT_EQ(big.bytes(), 32 * kMiB);
  EXPECT_EQ(retained.held(), 0u);
  EXPECT_EQ(retained.counts().unmapped, 1u);
  EXPECT_LE(governor.in_use() + retained.held(), governor.capacity());
}

TEST_F(RetainedBuffersTest, KeepsOnlyIntoRoomTheLeasesLeave) {
  Governor governor(64 * kMiB, 0);
  RetainedBuffers retained(governor);
  Lease lease = governor.acquire("stage", 40 * kMiB, 40 * kMiB);
  touched(32 * kMiB).reset();  // 32 MiB beside 40 leased would pass 64
  EXPECT_EQ(retained.held(), 0u);
  touched(16 * kMiB).reset();
  EXPECT_GE(retained.held(), 16 * kMiB);
  EXPECT_LE(governor.in_use() + retained.held(), governor.capacity());
}

TEST_F(RetainedBuffersTest, NothingIsKeptOutsideTheScopeOrInASecondOne) {
  Governor governor(1024 * kMiB, 0);
  {
    RetainedBuffers retained(governor);
    RetainedBuffers second(governor);  // another is open: keeps nothing, counts nothing
    touched(16 * kMiB).reset();
    EXPECT_GE(retained.held(), 16 * kMiB);
    EXPECT_EQ(second.counts().kept_bytes, 0u);
  }
  // The scope unmapped what it kept; freed buffers now go back as usual.
  RetainedBuffers later(governor);
  EXPECT_EQ(later.held(), 0u);
  tune_allocator();  // no huge-page advice: big buffers are not considered
  touched(16 * kMiB).reset();
  EXPECT_EQ(later.held(), 0u);
}

}  // namespace
}  // namespace qemflow::engine
