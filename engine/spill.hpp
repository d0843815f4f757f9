#pragma once
// BucketSpill: records sorted into buckets (grid blocks, vertex ranges, face ranges)
// and spilled to scratch as frames, under one lease.
//
// Contract
// - add() is called by one thread at a time (a serial node). Records are copied into
//   fixed-size pages; no page is ever reallocated, so the memory held is exactly
//   pages × page size, which stays within a third of the lease.
// - When the pages would exceed that third, the largest buckets are flushed: their
//   pages are encoded with the store's codec (in parallel, on the calling compute arena) into frames and
//   handed to the I/O thread (raw codec: the pages themselves go, between a header
//   and a checksum, with no copy; they count as in flight from then on). Frames waiting for the disk stay within the
//   other two thirds; if they would not, add() waits for the I/O thread (which never
//   waits for compute, so this cannot deadlock).
// - A smaller lease means smaller pages and earlier, more frequent flushes; nothing
//   else changes (the minimum lease is min_lease_bytes(), which grows with the
//   buckets: each needs room for two pages, or records landing in buckets without a
//   page force flushes of a few records each, a frame and a FrameRef apiece).
// - A frame holds at most 2 MiB of records (a bucket flushes as several frames), so
//   frame buffers, written and read, come from the heap rather than fresh mappings.
// - finish() flushes everything, waits for the writes and finalizes the files, and
//   hands the lease back; then frames(bucket) lists where each bucket's records are.
//   Each bucket is one file.
// - Within a bucket, frames keep the order in which records were added.
#include <condition_variable>
#include <cstring>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"

namespace qemflow::engine {

class BucketSpill {
 public:
  // `expected_buckets` sizes the pages (more buckets, smaller pages).
  BucketSpill(Job& job, ScratchStore& scratch, std::string name, uint32_t record_size,
              Lease lease, uint32_t expected_buckets, const char* stage);
  ~BucketSpill();
  static uint64_t min_lease_bytes(uint32_t record_size, uint32_t buckets = 1);

  // Inline, with the copy's size known for the common record sizes: a libc memcpy
  // call a record (12 bytes) was most of a re-encode's cost of filing records.
  void add(uint32_t bucket, const void* record) {
    if (bucket >= buckets_.size()) buckets_.resize(bucket + 1);
    Bucket& b = buckets_[bucket];
    if (b.pages.empty() || b.used_in_last + record_size_ > page_bytes_) start_page(b);
    std::byte* at = b.pages.back().get() + b.used_in_last;
    switch (record_size_) {
      case 12: std::memcpy(at, record, 12); break;
      case 16: std::memcpy(at, record, 16); break;
      case 24: std::memcpy(at, record, 24); break;
      case 32: std::memcpy(at, record, 32); break;
      default: std::memcpy(at, record, record_size_);
    }
    b.used_in_last += record_size_;
    ++b.buffered;
    ++b.records;
    ++total_records_;
  }
  // `count` records laid end to end, all for `bucket`: the same pages and frames as
  // that many add() calls, copied a page's worth at a time.
  void add_run(uint32_t bucket, const void* records, uint64_t count);
  // Returns the spill's lease (for its owner to reuse or release).
  Lease finish();

  uint32_t bucket_count() const { return uint32_t(buckets_.size()); }
  const std::vector<FrameRef>& frames(uint32_t bucket) const;
  uint64_t records(uint32_t bucket) const;
  uint64_t records() const { return total_records_; }
  uint64_t bytes_written() const { return encoded_bytes_; }
  // Largest bucket in records (to size the lease that will read it back).
  uint64_t max_bucket_records() const;
  uint64_t max_frame_records() const { return max_frame_records_; }
  uint64_t max_frame_bytes() const { return max_frame_bytes_; }
  // Whether frames can hold as little as one record: fewer than two pages per
  // expected bucket (a lease sized for fewer buckets than it files, records in random
  // bucket order). Otherwise a flush at the page limit takes the fullest buckets, which
  // hold two pages each on average, so its frames average at least half a page (2 KiB
  // pages at the least: the 56-byte frame envelope is under 6% of what they hold).
  bool small_frames() const { return page_limit_ < 2 * uint64_t(expected_buckets_); }

 private:
  struct Bucket {
    std::vector<std::unique_ptr<std::byte[]>> pages;
    size_t used_in_last = 0;  // bytes used in pages.back()
    uint64_t buffered = 0;    // records in pages
    uint64_t records = 0;     // records in total
    uint32_t file = UINT32_MAX;
    uint64_t file_bytes = 0;  // frames submitted so far: the next frame's offset
    std::vector<FrameRef> frames;
  };
  void start_page(Bucket& b);  // a new page for b (flushing first when pages are at their limit)
  void flush_largest();
  void flush(const std::vector<uint32_t>& which);
  void flush_raw(const std::vector<uint32_t>& which);
  void submit_write(uint32_t file, std::vector<Piece> pieces, uint64_t bytes, std::shared_ptr<void> owner,
                    uint64_t memory);
  void wait_for_room(uint64_t bytes);

  Job& job_;
  ScratchStore& scratch_;
  std::string name_;
  const char* stage_;  // the report's stage these writes belong to
  uint32_t record_size_;
  uint32_t expected_buckets_;
  Lease lease_;
  size_t page_bytes_;
  uint64_t page_limit_;  // pages allowed in memory
  uint64_t pages_held_ = 0;
  uint64_t in_flight_limit_;
  std::vector<Bucket> buckets_;
  uint64_t total_records_ = 0;
  uint64_t encoded_bytes_ = 0;
  uint64_t max_frame_records_ = 0, max_frame_bytes_ = 0;
  bool finished_ = false;

  // Shared with I/O tasks, which may outlive a failed spill's stack frame.
  struct Shared {
    std::mutex mutex;
    std::condition_variable written;
    uint64_t in_flight = 0;
  };
  std::shared_ptr<Shared> shared_ = std::make_shared<Shared>();
};

}  // namespace qemflow::engine
