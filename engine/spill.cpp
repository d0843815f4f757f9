#include "engine/spill.hpp"

#include <oneapi/tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <numeric>
#include <optional>

#include "util/error.hpp"

namespace qemflow::engine {

namespace {
// Pages shrink with the lease down to this; the minimum lease still holds 8 pages of
// kMinLeasePageBytes. Pages far larger than the lease's share per bucket leave most
// buckets a partial page at each flush: frames of a few records, each with its own
// header and FrameRef (1M faces in random order at 48M: 409k corner frames).
constexpr size_t min_page_bytes = 2 << 10;
constexpr size_t min_lease_page_bytes = 16 << 10;
constexpr size_t max_page_bytes = 1 << 20;
constexpr size_t frame_limit_bytes = 1 << 20;  // below the allocator's mmap threshold
}  // namespace

// Pages get a third of the lease. With fewer pages than buckets, a record for a
// bucket without a page flushes others holding a page of a few records: a shuffled 3M
// faces at 48M (79 vertex chunks, 64 pages) wrote 3.1M corner frames of 2.9 records
// each, and their FrameRefs, which no lease counts, took the process to 211 MiB.
uint64_t BucketSpill::min_lease_bytes(uint32_t record_size, uint32_t buckets) {
  return 3 * std::max<uint64_t>(8 * (min_lease_page_bytes + record_size), 2 * uint64_t(buckets) * (min_page_bytes + record_size));
}

BucketSpill::BucketSpill(Job& job, ScratchStore& scratch, std::string name, uint32_t record_size,
                         Lease lease, uint32_t expected_buckets, const char* stage)
    : job_(job),
      scratch_(scratch),
      name_(std::move(name)),
      stage_(stage),
      record_size_(record_size),
      expected_buckets_(std::max<uint32_t>(expected_buckets, 1)),
      lease_(std::move(lease)) {
  if (lease_.bytes() < min_lease_bytes(record_size)) {
    throw Error(ErrorKind::internal, name_ + ": spill lease below its minimum");
  }
  uint64_t third = lease_.bytes() / 3;
  size_t page = size_t(third / (4 * std::max<uint32_t>(expected_buckets, 1)));
  page = std::clamp(page, min_page_bytes, max_page_bytes);
  page_bytes_ = std::max<size_t>(page / record_size * record_size, record_size);
  page_limit_ = std::max<uint64_t>(third / page_bytes_, 4);
  in_flight_limit_ = lease_.bytes() - page_limit_ * page_bytes_;
}

BucketSpill::~BucketSpill() {
  // On failure, writes may still be queued: they hold only shared state, and the
  // scratch store outlives the I/O thread's queue (the job drains it).
}

const std::vector<FrameRef>& BucketSpill::frames(uint32_t bucket) const {
  static const std::vector<FrameRef> none;
  return bucket < buckets_.size() ? buckets_[bucket].frames : none;
}

uint64_t BucketSpill::records(uint32_t bucket) const {
  return bucket < buckets_.size() ? buckets_[bucket].records : 0;
}

uint64_t BucketSpill::max_bucket_records() const {
  uint64_t m = 0;
  for (const auto& b : buckets_) m = std::max(m, b.records);
  return m;
}

void BucketSpill::start_page(Bucket& b) {
  if (pages_held_ >= page_limit_) flush_largest();
  b.pages.push_back(std::make_unique_for_overwrite<std::byte[]>(page_bytes_));
  b.used_in_last = 0;
  ++pages_held_;
}

void BucketSpill::add_run(uint32_t bucket, const void* records, uint64_t count) {
  if (bucket >= buckets_.size()) buckets_.resize(bucket + 1);
  const auto* from = static_cast<const std::byte*>(records);
  while (count > 0) {
    Bucket& b = buckets_[bucket];
    if (b.pages.empty() || b.used_in_last + record_size_ > page_bytes_) start_page(b);
    const uint64_t n = std::min<uint64_t>(count, (page_bytes_ - b.used_in_last) / record_size_);
    std::memcpy(b.pages.back().get() + b.used_in_last, from, n * record_size_);
    b.used_in_last += n * record_size_;
    b.buffered += n;
    b.records += n;
    total_records_ += n;
    from += n * record_size_;
    count -= n;
  }
}

void BucketSpill::flush_largest() {
  std::vector<uint32_t> order;
  for (uint32_t i = 0; i < buckets_.size(); ++i) {
    if (buckets_[i].buffered) order.push_back(i);
  }
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
    return buckets_[a].buffered > buckets_[b].buffered;
  });
  std::vector<uint32_t> chosen;
  uint64_t pages = 0;
  for (uint32_t i : order) {
    chosen.push_back(i);
    pages += buckets_[i].pages.size();
    if (pages * 2 >= pages_held_) break;
  }
  flush(chosen);
}

void BucketSpill::wait_for_room(uint64_t bytes) {
  std::unique_lock lock(shared_->mutex);
  std::optional<Waiting> waiting;  // on the I/O thread's writes: not compute busy
  while (shared_->in_flight > 0 && shared_->in_flight + bytes > in_flight_limit_) {
    if (job_.stopped()) break;
    if (!waiting) waiting.emplace();
    shared_->written.wait_for(lock, std::chrono::milliseconds(20));
  }
  shared_->in_flight += bytes;
}

// Queues the write of one frame (`pieces`, `bytes` in all) on the I/O thread; `owner`
// keeps its memory (`memory` bytes in flight) until written, failed or dropped.
void BucketSpill::submit_write(uint32_t file, std::vector<Piece> pieces, uint64_t bytes,
                               std::shared_ptr<void> owner, uint64_t memory) {
  ScratchStore* scratch = &scratch_;
  StageStats* stage = &job_.stage(stage_);
  struct Done {  // the in-flight bytes go back whatever happens to the task
    std::shared_ptr<Shared> shared;
    uint64_t size;
    Done(std::shared_ptr<Shared> s, uint64_t n) : shared(std::move(s)), size(n) {}
    Done(const Done&) = delete;
    ~Done() {
      {
        std::lock_guard lock(shared->mutex);
        shared->in_flight -= size;
      }
      shared->written.notify_all();
    }
  };
  auto done = std::make_shared<Done>(shared_, memory);
  job_.io().submit(
      "scratch write",
      [pieces = std::move(pieces), owner = std::move(owner), done = std::move(done), file, bytes, scratch,
       stage]() mutable {
        scratch->append_pieces(file, pieces);
        stage->bytes_written += bytes;
        owner.reset();
        done.reset();
      },
      job_.error_handler(), memory);
}

// Raw codec: no encoding, so no copy. Each frame is its pages between a header and a
// checksum trailer (the checksums are the only compute, done in parallel); the pages
// move to the I/O task and are freed when written.
void BucketSpill::flush_raw(const std::vector<uint32_t>& which) {
  job_.check();
  struct Frame {
    uint32_t bucket;
    std::vector<std::unique_ptr<std::byte[]>> pages;
    std::vector<Piece> pieces;  // header, the pages' used bytes, trailer
    uint64_t first_record, records;
    RawFrameEnvelope envelope;
  };
  const size_t pages_per_frame = std::max<size_t>(frame_limit_bytes / page_bytes_, 1);
  const uint64_t records_per_page = page_bytes_ / record_size_;
  std::vector<Frame> frames;
  uint64_t held = 0;
  for (uint32_t i : which) {
    Bucket& b = buckets_[i];
    held += b.pages.size() * page_bytes_;
    uint64_t first_record = b.records - b.buffered;
    for (size_t p = 0; p < b.pages.size(); p += pages_per_frame) {
      size_t n = std::min(pages_per_frame, b.pages.size() - p);
      bool last = p + n == b.pages.size();
      Frame frame{i, {}, {}, first_record, last ? (n - 1) * records_per_page + b.used_in_last / record_size_ : n * records_per_page, {}};
      for (size_t k = p; k < p + n; ++k) {
        frame.pieces.push_back({b.pages[k].get(), k + 1 == b.pages.size() ? b.used_in_last : page_bytes_});
        frame.pages.push_back(std::move(b.pages[k]));
      }
      first_record += frame.records;
      frames.push_back(std::move(frame));
    }
    pages_held_ -= b.pages.size();
    b.pages.clear();
    b.pages.shrink_to_fit();
    b.used_in_last = 0;
    b.buffered = 0;
  }
  // The pages are now in flight, not held: wait until the I/O thread has room for them.
  wait_for_room(held);
  job_.check();
  tbb::parallel_for(size_t(0), frames.size(), [&](size_t k) {
    Span span(&job_.trace(), &job_.activity(), "checksum", Span::Kind::compute);
    frames[k].envelope = raw_frame_envelope(frames[k].first_record, record_size_, frames[k].pieces, frames[k].records);
    span.set_bytes(frames[k].envelope.bytes);
  });
  for (Frame& frame : frames) {
    Bucket& b = buckets_[frame.bucket];
    if (b.file == UINT32_MAX) b.file = scratch_.create_file(name_ + "-" + std::to_string(frame.bucket));
    uint64_t size = frame.envelope.bytes;
    b.frames.push_back({b.file, b.file_bytes, size, frame.records, frame.first_record});
    max_frame_records_ = std::max<uint64_t>(max_frame_records_, frame.records);
    max_frame_bytes_ = std::max<uint64_t>(max_frame_bytes_, size);
    b.file_bytes += size;
    encoded_bytes_ += size;
    uint64_t memory = frame.pages.size() * page_bytes_;
    auto owned = std::make_shared<Frame>(std::move(frame));
    owned->pieces.insert(owned->pieces.begin(), {owned->envelope.header.data(), owned->envelope.header.size()});
    owned->pieces.push_back({owned->envelope.trailer.data(), owned->envelope.trailer.size()});
    submit_write(b.file, owned->pieces, owned->envelope.bytes, owned, memory);
  }
}

void BucketSpill::flush(const std::vector<uint32_t>& which) {
  if (which.empty()) return;
  if (scratch_.codec().raw) return flush_raw(which);
  job_.check();
  uint64_t bound = 0;
  for (uint32_t i : which) bound += frame_bound(buckets_[i].buffered * record_size_);
  wait_for_room(bound);
  job_.check();

  // Each bucket's pages are cut into frames of at most max_frame_bytes (so frames stay
  // small enough to come from the heap on both sides), all compressed in parallel.
  struct Piece_ {
    uint32_t bucket;
    size_t first_page, pages;
    uint64_t first_record, records;
  };
  std::vector<Piece_> jobs;
  const size_t pages_per_frame = std::max<size_t>(frame_limit_bytes / page_bytes_, 1);
  const uint64_t records_per_page = page_bytes_ / record_size_;
  for (uint32_t i : which) {
    Bucket& b = buckets_[i];
    uint64_t first_record = b.records - b.buffered;
    for (size_t p = 0; p < b.pages.size(); p += pages_per_frame) {
      size_t n = std::min(pages_per_frame, b.pages.size() - p);
      bool last = p + n == b.pages.size();
      uint64_t records = last ? (n - 1) * records_per_page + b.used_in_last / record_size_ : n * records_per_page;
      jobs.push_back({i, p, n, first_record, records});
      first_record += records;
    }
  }
  std::vector<Bytes> encoded(jobs.size());
  tbb::parallel_for(size_t(0), jobs.size(), [&](size_t k) {
    const Piece_& job = jobs[k];
    const Bucket& b = buckets_[job.bucket];
    Span span(&job_.trace(), &job_.activity(), "compress", Span::Kind::compute);
    std::vector<Piece> pieces;
    for (size_t p = job.first_page; p < job.first_page + job.pages; ++p) {
      pieces.push_back({b.pages[p].get(), p + 1 == b.pages.size() ? b.used_in_last : page_bytes_});
    }
    encoded[k] = encode_frame(job.first_record, record_size_, pieces, job.records, scratch_.codec());
    span.set_bytes(encoded[k].size());
  });

  uint64_t actual = 0;
  for (size_t k = 0; k < jobs.size(); ++k) {
    Bucket& b = buckets_[jobs[k].bucket];
    if (b.file == UINT32_MAX) b.file = scratch_.create_file(name_ + "-" + std::to_string(jobs[k].bucket));
    uint64_t size = encoded[k].size();
    actual += encoded[k].capacity();  // what the frame holds until written
    b.frames.push_back({b.file, b.file_bytes, size, jobs[k].records, jobs[k].first_record});
    max_frame_records_ = std::max<uint64_t>(max_frame_records_, jobs[k].records);
    max_frame_bytes_ = std::max<uint64_t>(max_frame_bytes_, size);
    b.file_bytes += size;
    encoded_bytes_ += size;
  }
  for (uint32_t i : which) {
    Bucket& b = buckets_[i];
    pages_held_ -= b.pages.size();
    b.pages.clear();
    b.pages.shrink_to_fit();
    b.used_in_last = 0;
    b.buffered = 0;
  }
  {
    std::lock_guard lock(shared_->mutex);
    shared_->in_flight -= bound - actual;
  }
  for (size_t k = 0; k < jobs.size(); ++k) {
    auto frame = std::make_shared<Bytes>(std::move(encoded[k]));
    submit_write(buckets_[jobs[k].bucket].file, {{frame->data(), frame->size()}}, frame->size(), frame,
                 frame->capacity());
  }
}

Lease BucketSpill::finish() {
  if (finished_) return {};
  // Flush in groups that fit the in-flight allowance.
  std::vector<uint32_t> group;
  uint64_t group_bytes = 0;
  for (uint32_t i = 0; i < buckets_.size(); ++i) {
    if (!buckets_[i].buffered) continue;
    uint64_t bytes = frame_bound(buckets_[i].buffered * record_size_);
    if (!group.empty() && group_bytes + bytes > in_flight_limit_) {
      flush(group);
      group.clear();
      group_bytes = 0;
    }
    group.push_back(i);
    group_bytes += bytes;
  }
  flush(group);
  {
    std::unique_lock lock(shared_->mutex);
    while (shared_->in_flight > 0 && !job_.stopped()) {
      shared_->written.wait_for(lock, std::chrono::milliseconds(20));
    }
  }
  job_.check();
  std::vector<uint32_t> files;
  for (const auto& b : buckets_) {
    if (b.file != UINT32_MAX) files.push_back(b.file);
  }
  ScratchStore* scratch = &scratch_;
  job_.io().call("scratch finalize", [scratch, files] {
    for (uint32_t f : files) scratch->finalize(f);
  });
  finished_ = true;
  return std::move(lease_);
}

}  // namespace qemflow::engine
