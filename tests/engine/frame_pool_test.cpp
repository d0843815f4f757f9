// FramePool: for_each_frame reads later frames into the buffers earlier items left,
// every kept buffer covered by a lease, and a pump parked for memory is not starved
// by buffers the pool keeps.
#include <gtest/gtest.h>

#include <atomic>
#include <numeric>

#include "engine/blocks.hpp"
#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "test_support.hpp"

namespace qemflow::engine {
namespace {

using qemflow::testing::TempDir;

// `counts[i]` u64 records per frame, record j of frame i holding i * 1'000'000 + j.
std::vector<FrameRef> write_frames(Job& job, ScratchStore& scratch, const std::vector<uint64_t>& counts) {
  const uint32_t file = scratch.create_file("frames");
  std::vector<FrameRef> refs;
  job.io().call("write", [&] {
    for (uint64_t i = 0; i < counts.size(); ++i) {
      std::vector<uint64_t> values(counts[i]);
      std::iota(values.begin(), values.end(), i * 1'000'000);
      Bytes frame = encode_frame(i, sizeof(uint64_t), values.data(), values.size(), FrameCodec::uncompressed());
      const uint64_t offset = scratch.append(file, frame.data(), frame.size());
      refs.push_back({file, offset, frame.size(), counts[i], i, sizeof(uint64_t)});
    }
    scratch.finalize(file);
  });
  return refs;
}

uint64_t sum_of_records(Job& job, ScratchStore& scratch, const std::vector<FrameRef>& frames, FramePool* pool) {
  std::atomic<uint64_t> sum = 0;
  for_each_frame(
      job, scratch, "test", "test frames", frames, sizeof(uint64_t),
      [&](const FrameHeader& header, Bytes& records, Lease&) {
        const auto* values = reinterpret_cast<const uint64_t*>(records.data());
        uint64_t s = 0;
        for (uint64_t i = 0; i < header.count; ++i) s += values[i];
        sum += s;
      },
      {}, 8, false, false, pool);
  return sum;
}

uint64_t expected_sum(const std::vector<uint64_t>& counts) {
  uint64_t sum = 0;
  for (uint64_t i = 0; i < counts.size(); ++i) sum += counts[i] * i * 1'000'000 + counts[i] * (counts[i] - 1) / 2;
  return sum;
}

TEST(FramePool, KeepsBuffersCoveredByLeasesAcrossPasses) {
  TempDir dir;
  Governor governor(64ull << 20, 0);
  Job job(governor, {}, {.threads = 2});
  ScratchStore scratch(dir.path(), 0);
  const std::vector<uint64_t> counts(40, 5000);
  const auto frames = write_frames(job, scratch, counts);
  FramePool pool;
  EXPECT_EQ(sum_of_records(job, scratch, frames, &pool), expected_sum(counts));
  EXPECT_EQ(sum_of_records(job, scratch, frames, &pool), expected_sum(counts));  // reads into kept buffers
  std::vector<FramePool::Kept> kept = pool.take_all();
  ASSERT_FALSE(kept.empty());  // the items' buffers stayed for the next pass
  uint64_t covered = 0;
  for (const FramePool::Kept& one : kept) {
    EXPECT_GE(one.buffer.capacity(), 5000 * sizeof(uint64_t));
    EXPECT_EQ(one.lease.bytes(), one.buffer.capacity());
    covered += one.lease.bytes();
  }
  EXPECT_EQ(governor.in_use(), covered);  // what the pool holds, and nothing else
  kept.clear();
  EXPECT_EQ(governor.in_use(), 0u);
}

// A budget for about one frame at a time, frames growing so that a kept buffer is too
// small for the next one: the pump parks for memory while the pool holds bytes, and
// must free them rather than wait for them.
TEST(FramePool, AParkedReadIsNotStarvedByKeptBuffers) {
  TempDir dir;
  std::vector<uint64_t> counts;
  for (uint64_t i = 0, n = 4'000; i < 12; ++i, n += n / 2) counts.push_back(n);  // past a kept buffer's slack
  const uint64_t largest_item = 48 + 8 + counts.back() * (8 + 8) + counts.back() * 8;
  Governor governor(largest_item + largest_item / 8, 0);
  Job job(governor, {}, {.threads = 2});
  ScratchStore scratch(dir.path(), 0);
  const auto frames = write_frames(job, scratch, counts);
  FramePool pool;
  EXPECT_EQ(sum_of_records(job, scratch, frames, &pool), expected_sum(counts));
  EXPECT_EQ(sum_of_records(job, scratch, frames, &pool), expected_sum(counts));
  pool.clear();
  EXPECT_EQ(governor.in_use(), 0u);
}

}  // namespace
}  // namespace qemflow::engine
