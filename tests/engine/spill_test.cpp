#include "engine/spill.hpp"

#include <gtest/gtest.h>

#include <cstring>

#include "engine/blocks.hpp"
#include "test_support.hpp"

namespace qemflow::engine {
namespace {

using qemflow::testing::TempDir;

struct Record {
  uint64_t bucket, index;
};

// Spills `count` records over `buckets` buckets under a lease of `lease_bytes`; returns
// the records read back per bucket, in order, and the frame count.
std::pair<std::vector<std::vector<uint64_t>>, size_t> round_trip(uint64_t lease_bytes, uint32_t buckets,
                                                                 uint64_t count,
                                                                 ScratchCodec codec = ScratchCodec::zstd) {
  TempDir dir;
  Governor governor(1ull << 30, 0);
  Job job(governor, {}, {.threads = 2});
  ScratchStore scratch(dir.path(), 0, 0, codec);
  BucketSpill spill(job, scratch, "test", sizeof(Record), governor.try_acquire("spill", lease_bytes), buckets, "test");
  job.arena().execute([&] {
    for (uint64_t i = 0; i < count; ++i) {
      Record r{(i * 7919) % buckets, i};
      spill.add(uint32_t(r.bucket), &r);
    }
    spill.finish();
  });
  EXPECT_EQ(governor.in_use(), 0u);  // the spill's lease is returned at finish
  std::vector<std::vector<uint64_t>> back(buckets);
  size_t frames = 0;
  for (uint32_t b = 0; b < buckets; ++b) {
    frames += spill.frames(b).size();
    for_each_frame(job, scratch, "read", "reader", spill.frames(b), sizeof(Record), {},
                   [&](const FrameHeader& header, Bytes& records, Lease&) {
                     for (uint64_t i = 0; i < header.count; ++i) {
                       Record r;
                       std::memcpy(&r, records.data() + i * sizeof r, sizeof r);
                       EXPECT_EQ(r.bucket, b);
                       back[b].push_back(r.index);
                     }
                   },
                   0, /*ordered=*/true);
    EXPECT_EQ(back[b].size(), spill.records(b));
  }
  return {back, frames};
}

TEST(BucketSpill, ASmallerLeaseGivesTheSameRecordsInMoreFrames) {
  auto [big, big_frames] = round_trip(64ull << 20, 37, 200'000);
  auto [small, small_frames] = round_trip(BucketSpill::min_lease_bytes(sizeof(Record)), 37, 200'000);
  EXPECT_EQ(big, small);
  for (const auto& bucket : small) EXPECT_TRUE(std::is_sorted(bucket.begin(), bucket.end()));  // order kept
  EXPECT_EQ(big_frames, 37u);         // everything fit: one frame per bucket at finish
  EXPECT_GT(small_frames, 4 * big_frames);  // spilled early and often
}

// Records spread over more buckets than the pages a small lease holds: each record
// for a bucket without a page flushed others of a few records each (a shuffled 3M
// faces at 48M wrote 3.1M corner frames, 2.9 records apiece, and their FrameRefs took
// the process to 211 MiB against its budget). The minimum for the buckets holds two
// pages per bucket, so a flush writes pages, not scraps.
TEST(BucketSpill, TheMinimumLeaseForManyBucketsWritesFramesOfWholePages) {
  constexpr uint32_t buckets = 300;
  constexpr uint64_t count = 300'000;
  auto [enough, enough_frames] = round_trip(BucketSpill::min_lease_bytes(sizeof(Record), buckets), buckets, count,
                                            ScratchCodec::raw);
  auto [scraps, scrap_frames] = round_trip(BucketSpill::min_lease_bytes(sizeof(Record)), buckets, count,
                                           ScratchCodec::raw);
  EXPECT_EQ(enough, scraps);
  const uint64_t page_records = 2048 / sizeof(Record);
  EXPECT_LE(enough_frames, 2 * count / page_records) << "frames of " << count / enough_frames << " records";
  EXPECT_GT(scrap_frames, 8 * enough_frames) << "the one-bucket minimum no longer shows the scraps";
}

TEST(BucketSpill, RawFramesGiveTheSameRecords) {
  auto [zstd, zstd_frames] = round_trip(BucketSpill::min_lease_bytes(sizeof(Record)), 37, 200'000);
  auto [raw, raw_frames] = round_trip(BucketSpill::min_lease_bytes(sizeof(Record)), 37, 200'000, ScratchCodec::raw);
  EXPECT_EQ(zstd, raw);
  EXPECT_GT(raw_frames, 37u);
}

}  // namespace
}  // namespace qemflow::engine
