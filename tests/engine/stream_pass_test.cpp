#include "engine/stream_pass.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <set>
#include <thread>

#include "util/error.hpp"

namespace qemflow::engine {
namespace {

struct Numbers {
  uint64_t first = 0;
  std::vector<uint64_t> values;
  uint64_t sum = 0;
};

// A source of `total` numbers read in batches sized by the lease (8 bytes each).
StreamPass<Numbers> counting_pass(uint64_t total, uint64_t& next, uint64_t min_items,
                                  uint64_t max_items) {
  StreamPass<Numbers> pass;
  pass.min_item_bytes = min_items * 8;
  pass.max_item_bytes = max_items * 8;
  pass.read = [total, &next](Numbers& item, Lease& lease) {
    if (next == total) return false;
    uint64_t n = std::min<uint64_t>(lease.bytes() / 8, total - next);
    lease.shrink_to(n * 8);
    item.first = next;
    for (uint64_t i = 0; i < n; ++i) item.values.push_back(next + i);
    next += n;
    return true;
  };
  pass.transform = [](Numbers& item, Lease&) {
    for (uint64_t v : item.values) item.sum += v * v;
  };
  return pass;
}

uint64_t sum_of_squares(uint64_t n) {  // 0..n-1
  return (n - 1) * n * (2 * n - 1) / 6;
}

TEST(StreamPass, EveryItemArrivesOnceUnderTheBudget) {
  Governor governor(10'000, 0);  // room for a few items only
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0, sum = 0, items = 0;
  auto pass = counting_pass(100'000, next, 100, 400);
  pass.sink = [&](Numbers& item, Lease&) {
    sum += item.sum;
    ++items;
  };
  run_stream_pass(job, pass);
  EXPECT_EQ(sum, sum_of_squares(100'000));
  EXPECT_LE(governor.peak_in_use(), governor.capacity());
  EXPECT_GE(items, 100'000u / 400);
  EXPECT_EQ(governor.in_use(), 0u);
}

TEST(StreamPass, AReaderGrantedLessReadsSmallerBatches) {
  Governor governor(4'000, 0);
  Lease squatter = governor.try_acquire("other job", 3'000);  // leaves 1000 bytes = 125 items
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0, sum = 0;
  size_t largest = 0;
  auto pass = counting_pass(10'000, next, 10, 1'000);
  pass.owner = "reader";
  pass.sink = [&](Numbers& item, Lease&) {
    sum += item.sum;
    largest = std::max(largest, item.values.size());
  };
  run_stream_pass(job, pass);
  EXPECT_EQ(sum, sum_of_squares(10'000));
  EXPECT_LE(largest, 125u);
  auto owners = governor.owners();
  auto reader = std::find_if(owners.begin(), owners.end(), [](auto& o) { return o.owner == "reader"; });
  ASSERT_NE(reader, owners.end());
  EXPECT_GT(reader->partial_grants, 0u);
  EXPECT_LE(reader->peak, 1'000u);
}

TEST(StreamPass, ReaderRunsAtMostMaxInFlightItemsAhead) {
  Governor governor(1 << 30, 0);  // memory is no limit here
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0;
  std::atomic<int> in_flight{0}, most{0};
  auto pass = counting_pass(20'000, next, 10, 10);
  pass.max_in_flight = 3;
  auto read = pass.read;
  pass.read = [&](Numbers& item, Lease& lease) {
    int now = ++in_flight;
    most = std::max(most.load(), now);
    return read(item, lease) || (--in_flight, false);
  };
  pass.sink = [&](Numbers&, Lease&) { --in_flight; };
  run_stream_pass(job, pass);
  EXPECT_LE(most.load(), 3);
  EXPECT_EQ(next, 20'000u);
}

TEST(StreamPass, OrderedPassSeesReadOrder) {
  Governor governor(1 << 20, 0);
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0, expected_first = 0;
  bool in_order = true;
  auto pass = counting_pass(50'000, next, 10, 100);
  pass.ordered = true;
  pass.sink = [&](Numbers& item, Lease&) {
    in_order = in_order && item.first == expected_first;
    expected_first += item.values.size();
  };
  run_stream_pass(job, pass);
  EXPECT_TRUE(in_order);
  EXPECT_EQ(expected_first, 50'000u);
}

TEST(StreamPass, ReadsRunOnTheIoThreadAndComputeElsewhere) {
  Governor governor(1 << 20, 0);
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0;
  std::atomic<bool> read_on_io{true}, transform_off_io{true};
  auto pass = counting_pass(10'000, next, 10, 100);
  auto read = pass.read;
  pass.read = [&](Numbers& item, Lease& lease) {
    read_on_io = read_on_io && job.io().on_io_thread();
    return read(item, lease);
  };
  pass.transform = [&](Numbers&, Lease&) { transform_off_io = transform_off_io && !job.io().on_io_thread(); };
  run_stream_pass(job, pass);
  EXPECT_TRUE(read_on_io);
  EXPECT_TRUE(transform_off_io);
}

TEST(StreamPass, AFailingNodeStopsThePassWithItsError) {
  Governor governor(1 << 20, 0);
  Job job(governor, {}, {.threads = 2});
  uint64_t next = 0;
  std::atomic<int> after_failure{0};
  auto pass = counting_pass(1'000'000, next, 10, 10);
  pass.transform = [&](Numbers& item, Lease&) {
    if (item.first == 500) throw Error(ErrorKind::bad_input, "in.ply: 500: broken");
    if (item.first > 100'000) ++after_failure;
  };
  try {
    run_stream_pass(job, pass);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_STREQ(e.what(), "in.ply: 500: broken");
  }
  EXPECT_LT(next, 1'000'000u);  // stopped reading early
  EXPECT_EQ(governor.in_use(), 0u);
}

TEST(StreamPass, CancelStopsAReaderParkedOnTheGovernor) {
  Governor governor(1'000, 0);
  auto cancel = std::make_shared<CancelToken>();
  Job job(governor, {.cancel = cancel}, {.threads = 2});
  Lease squatter = governor.try_acquire("other job", 1'000);  // the reader can never start
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    cancel->cancel();
  });
  uint64_t next = 0;
  auto pass = counting_pass(1'000, next, 10, 10);
  try {
    run_stream_pass(job, pass);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::cancelled);
  }
  canceller.join();
  EXPECT_EQ(next, 0u);
}

TEST(StreamPass, ItemBiggerThanTheBudgetFailsUpFront) {
  Governor governor(1'000, 0);
  Job job(governor, {}, {});
  uint64_t next = 0;
  auto pass = counting_pass(10, next, 1'000, 1'000);
  EXPECT_THROW(run_stream_pass(job, pass), Error);
}

// A stage's seconds, CPU and busy time are its own: stages time one after another,
// and one timed inside another is a programming error, caught where it happens.
TEST(StageTimer, StagesTimeOneAfterAnotherAndNeverNest) {
  Governor governor(1 << 20, 0);
  Job job(governor, {}, {.threads = 1});
  {
    StageTimer outer(job, "load");
    try {
      StageTimer inner(job, "weld");
      FAIL() << "a stage timed inside another";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::internal);
      EXPECT_NE(std::string(e.what()).find("\"weld\" timed inside stage \"load\""), std::string::npos) << e.what();
    }
  }
  { StageTimer again(job, "weld"); }  // after the outer one ended: fine
  { StageTimer load(job, "load"); }   // a stage timed twice adds up
  std::vector<std::string> names;
  for (const StageStats* s : job.stages()) names.push_back(s->name);
  EXPECT_EQ(names, (std::vector<std::string>{"load", "weld"}));
}

}  // namespace
}  // namespace qemflow::engine
