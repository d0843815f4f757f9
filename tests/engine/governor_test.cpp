#include "engine/governor.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <memory>
#include <chrono>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "engine/job.hpp"
#include "util/error.hpp"

namespace qemflow::engine {
namespace {

TEST(Governor, GrantsUnderTheCapAndDeniesAboveIt) {
  Governor governor(1000, 100);  // 900 leasable
  EXPECT_EQ(governor.capacity(), 900u);
  Lease a = governor.try_acquire("a", 500);
  ASSERT_TRUE(a);
  EXPECT_EQ(a.bytes(), 500u);
  EXPECT_EQ(governor.available(), 400u);
  Lease b = governor.try_acquire("b", 401);
  EXPECT_FALSE(b);  // all-or-nothing: 401 > 400
  Lease c = governor.try_acquire("b", 400);
  ASSERT_TRUE(c);
  EXPECT_EQ(governor.available(), 0u);
  c.release();
  EXPECT_EQ(governor.available(), 400u);
  a = Lease();
  EXPECT_EQ(governor.in_use(), 0u);
  EXPECT_EQ(governor.peak_in_use(), 900u);
}

TEST(Governor, PartialGrantGivesWhatIsFreeWithinMinMax) {
  Governor governor(1000, 0);
  Lease big = governor.try_acquire("big", 700);
  Lease part = governor.try_acquire_partial("reader", 100, 500);
  ASSERT_TRUE(part);
  EXPECT_EQ(part.bytes(), 300u);  // less than asked: the node must adapt
  Lease none = governor.try_acquire_partial("reader", 1, 10);
  EXPECT_FALSE(none);
  auto owners = governor.owners();
  auto reader = std::find_if(owners.begin(), owners.end(), [](auto& o) { return o.owner == "reader"; });
  ASSERT_NE(reader, owners.end());
  EXPECT_EQ(reader->partial_grants, 1u);
  EXPECT_EQ(reader->denials, 1u);
  EXPECT_EQ(reader->peak, 300u);
}

TEST(Governor, RequestThatCanNeverFitFailsUpFrontNamingTheMinimumBudget) {
  Governor governor(64ull << 20, 16ull << 20);
  try {
    governor.try_acquire("block writer", 100ull << 20);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
    std::string message = e.what();
    EXPECT_NE(message.find("block writer"), std::string::npos) << message;
    EXPECT_NE(message.find("minimum budget is 116 MiB"), std::string::npos) << message;
  }
  EXPECT_THROW(Governor(10 << 20, 20 << 20), Error);
}

TEST(Governor, BlockingAcquireWaitsExactlyUntilEnoughIsReleased) {
  Governor governor(100, 0);
  Lease held = governor.try_acquire("held", 80);
  Lease small = governor.try_acquire("small", 10);
  std::atomic<int> stage{0};
  std::thread waiter([&] {
    Lease got = governor.acquire("waiter", 50, 50);
    EXPECT_EQ(got.bytes(), 50u);
    stage = 2;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(stage.load(), 0);
  small.release();  // 20 free: not enough
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(stage.load(), 0);
  held.shrink_to(40);  // 60 free
  waiter.join();
  EXPECT_EQ(stage.load(), 2);
}

TEST(Governor, BlockingAcquireStopsWhenAsked) {
  Governor governor(100, 0);
  Lease held = governor.try_acquire("held", 100);
  std::atomic<bool> stop{false};
  std::thread waiter([&] {
    Lease got = governor.acquire("waiter", 50, 50, [&] { return stop.load(); });
    EXPECT_FALSE(got);
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  stop = true;
  governor.wake_all();
  waiter.join();
}

// Two jobs that sized their working sets from available() before either acquired
// could together hold everything and leave both input streams waiting forever
// (Reencode.TwoJobsShareOneGovernor hung that way about once in 250 runs). A share
// is computed from what is free when it is granted.
TEST(Governor, AShareIsSizedFromWhatIsFreeAtItsGrant) {
  Governor governor(1000, 0);
  auto leave_a_quarter = [](uint64_t free) { return free - free / 4; };
  Lease first = governor.acquire_share("job0/reserve", 10, leave_a_quarter);
  EXPECT_EQ(first.bytes(), 750u);
  Lease second = governor.acquire_share("job1/reserve", 10, leave_a_quarter);
  EXPECT_EQ(second.bytes(), 188u);  // 250 free at its grant, not the 1000 of before
  EXPECT_EQ(governor.available(), 62u);  // room left for both jobs' streams
  Lease floor = governor.acquire_share("floor", 20, [](uint64_t) { return uint64_t{0}; });
  EXPECT_EQ(floor.bytes(), 20u);  // never below the minimum
  Lease all = governor.acquire_share("all", 1, [](uint64_t free) { return free * 2; });
  EXPECT_EQ(all.bytes(), 42u);  // never above what is free
  all.release();
  floor.release();

  std::atomic<uint64_t> granted{0};
  std::thread waiter([&] {  // 62 free: waits for its minimum of 100
    Lease got = governor.acquire_share("waiter", 100, leave_a_quarter);
    granted = got.bytes();
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(granted.load(), 0u);
  second.release();  // 250 free
  waiter.join();
  EXPECT_EQ(granted.load(), 188u);
}

TEST(Governor, NotifyCallbackFiresOnceWhenTheMinimumFits) {
  Governor governor(100, 0);
  Lease held = governor.try_acquire("held", 90);
  int calls = 0;
  Lease got = governor.acquire_or_notify("reader", 30, 30, [&] { ++calls; });
  EXPECT_FALSE(got);
  held.shrink_to(80);  // 20 free: not yet
  EXPECT_EQ(calls, 0);
  held.shrink_to(70);  // 30 free
  EXPECT_EQ(calls, 1);
  held.release();
  EXPECT_EQ(calls, 1);
}

TEST(Governor, LeasesShrinkGrowAndSplitWithExactAccounting) {
  Governor governor(100, 0);
  Lease a = governor.try_acquire("a", 60);
  EXPECT_TRUE(a.try_grow(40));
  EXPECT_FALSE(a.try_grow(1));
  Lease b = a.split(30);
  EXPECT_EQ(a.bytes(), 70u);
  EXPECT_EQ(b.bytes(), 30u);
  EXPECT_EQ(governor.in_use(), 100u);
  b.release();
  a.shrink_to(10);
  EXPECT_EQ(governor.in_use(), 10u);
  auto owners = governor.owners();
  ASSERT_EQ(owners.size(), 1u);
  EXPECT_EQ(owners[0].peak, 100u);
  EXPECT_EQ(owners[0].current, 10u);
}

TEST(Governor, AReservationIsHandedOutToNodesAndTakenBack) {
  Governor governor(100, 0);
  Lease reserve = governor.try_acquire("loader", 80);
  Lease window = reserve.split(30, "vertex window");
  Lease spill = reserve.split(40, "block writer");
  EXPECT_EQ(reserve.bytes(), 10u);
  EXPECT_EQ(governor.in_use(), 80u);  // handing out takes nothing more from the budget
  EXPECT_FALSE(governor.try_acquire("other", 21));
  reserve.merge(std::move(window));
  EXPECT_EQ(reserve.bytes(), 40u);
  EXPECT_EQ(window.bytes(), 0u);
  spill.release();  // a part released on its own goes back to the governor
  EXPECT_EQ(governor.in_use(), 40u);
  std::map<std::string, OwnerStats> by_name;
  for (const auto& o : governor.owners()) by_name[o.owner] = o;
  EXPECT_EQ(by_name["vertex window"].peak, 30u);
  EXPECT_EQ(by_name["vertex window"].current, 0u);
  EXPECT_EQ(by_name["block writer"].peak, 40u);
  EXPECT_EQ(by_name["loader"].current, 40u);
  EXPECT_EQ(by_name["loader"].peak, 80u);
}

// A daemon passes one shutdown token to every job it runs: a job, and the wait for its
// reservation, forget their cancel callbacks when they end, so the token keeps none.
TEST(Governor, JobsForgetTheirCancelCallbacksWhenTheyEnd) {
  Governor shared(1000, 100);
  auto token = std::make_shared<CancelToken>();
  JobHooks hooks{.progress = {}, .cancel = token};
  for (int run = 0; run < 3; ++run) {
    const std::unique_ptr<Governor> own = reserve_for_job(shared, "job/", 300, hooks);
    EXPECT_EQ(token->pending(), 0u);  // the reservation's wake-up is gone once it is made
    Job job(*own, hooks, {.threads = 1});
    EXPECT_EQ(token->pending(), 1u);
  }
  EXPECT_EQ(token->pending(), 0u);
  token->cancel();  // nothing left to call
  EXPECT_TRUE(token->cancelled());
}

TEST(Governor, ObserverSeesEveryChange) {
  Governor governor(100, 0);
  std::vector<uint64_t> seen;
  const uint64_t id = governor.add_observer([&](uint64_t v) { seen.push_back(v); });
  {
    Lease a = governor.try_acquire("a", 10);
    Lease b = governor.try_acquire("b", 20);
  }
  EXPECT_EQ(seen, (std::vector<uint64_t>{10, 30, 10, 0}));
  governor.remove_observer(id);
  Lease c = governor.try_acquire("c", 5);
  EXPECT_EQ(seen.size(), 4u);
}

// Two traced jobs on one governor (a traced re-encode leases from the shared one): each
// observer sees every change while it is added, and removing one leaves the other's.
TEST(Governor, ObserversOfJobsSideBySideAreEachKept) {
  Governor governor(100, 0);
  std::vector<uint64_t> first, second;
  const uint64_t a = governor.add_observer([&](uint64_t v) { first.push_back(v); });
  const uint64_t b = governor.add_observer([&](uint64_t v) { second.push_back(v); });
  { Lease x = governor.try_acquire("x", 10); }
  governor.remove_observer(a);
  { Lease y = governor.try_acquire("y", 7); }
  governor.remove_observer(b);
  EXPECT_EQ(first, (std::vector<uint64_t>{10, 0}));
  EXPECT_EQ(second, (std::vector<uint64_t>{10, 0, 7, 0}));
}

// A job's own governor (engine/governor.hpp, jobs side by side): its capacity is the
// reservation, held from the parent until it is gone; its leases never touch the parent.
TEST(Governor, AJobsGovernorGrantsFromItsReservationAlone) {
  Governor shared(1000, 100);
  {
    Governor own(shared, "job0/job", 600);
    EXPECT_EQ(own.capacity(), 600u);
    EXPECT_EQ(own.budget(), 700u);  // the parent's baseline + the reservation
    EXPECT_EQ(shared.in_use(), 600u);
    Lease a = own.try_acquire("job0/patch", 600);
    ASSERT_TRUE(a);
    EXPECT_FALSE(own.try_acquire("job0/more", 1));
    EXPECT_EQ(shared.in_use(), 600u);
    EXPECT_THROW(own.require_fits("x", 601), Error);
  }
  EXPECT_EQ(shared.in_use(), 0u);
  ASSERT_EQ(shared.owners().size(), 1u);
  EXPECT_EQ(shared.owners()[0].owner, "job0/job");
  // More than the parent could ever hold: refused up front, naming a budget.
  try {
    Governor own(shared, "job1/job", 901);
    ADD_FAILURE() << "a reservation over the capacity was granted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
    EXPECT_NE(std::string(e.what()).find("minimum budget"), std::string::npos) << e.what();
  }
}

// The second reservation waits, holding nothing, until the first is given back; a stop
// ends the wait with Error(cancelled).
TEST(Governor, AReservationThatDoesNotFitBesideAnotherWaitsForIt) {
  Governor shared(1000, 0);
  auto first = std::make_unique<Governor>(shared, "a/job", 700);
  std::atomic<bool> granted{false};
  std::thread second([&] {
    Governor own(shared, "b/job", 700);
    granted = true;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_FALSE(granted.load());
  first.reset();
  second.join();
  EXPECT_TRUE(granted.load());
  EXPECT_EQ(shared.peak_in_use(), 700u);

  Lease all = shared.try_acquire("host", 1000);
  std::atomic<bool> stop{false};
  std::thread cancelled([&] {
    try {
      Governor own(shared, "c/job", 10, [&] { return stop.load(); });
      ADD_FAILURE() << "granted while everything was held";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::cancelled);
    }
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  stop = true;
  shared.wake_all();
  cancelled.join();
}

// Waits until `owner` has asked the governor and been refused (it is waiting), or
// `granted` is set.
void wait_until_refused(const Governor& governor, const std::string& owner, const std::atomic<bool>& granted) {
  for (;;) {
    if (granted.load()) return;
    for (const auto& o : governor.owners())
      if (o.owner == owner && o.denials > 0) return;
    std::this_thread::yield();
  }
}

// Reservations are admitted in arrival order: a small one that would fit now waits
// behind an earlier whole-budget one, which a stream of small jobs would otherwise
// starve; leases taken directly (a running job's) are not queued.
TEST(Governor, AReservationThatFitsWaitsBehindAnEarlierOneThatDoesNot) {
  Governor shared(1000, 0);
  auto running = std::make_unique<Governor>(shared, "a/job", 500);
  std::atomic<bool> whole_granted{false}, small_granted{false};
  std::unique_ptr<Governor> whole_job;
  std::thread whole([&] {
    whole_job = std::make_unique<Governor>(shared, "whole/job", 1000);
    whole_granted = true;
  });
  wait_until_refused(shared, "whole/job", whole_granted);
  std::thread small([&] {
    Governor own(shared, "small/job", 300);  // 500 are free: it would fit now
    small_granted = true;
  });
  wait_until_refused(shared, "small/job", small_granted);
  EXPECT_FALSE(small_granted.load()) << "a reservation went ahead of an earlier one";
  // A running job's own lease from the shared governor is not queued.
  EXPECT_TRUE(shared.try_acquire("a/extra", 100));
  running.reset();  // the whole budget is free: the first in line goes
  whole.join();
  EXPECT_TRUE(whole_granted.load());
  EXPECT_FALSE(small_granted.load());
  EXPECT_EQ(shared.queued_reservations(), 1u);
  whole_job.reset();
  small.join();
  EXPECT_TRUE(small_granted.load());
  EXPECT_EQ(shared.queued_reservations(), 0u);
  EXPECT_EQ(shared.peak_in_use(), 1000u);
}

// A cancelled reservation leaves the queue: the one behind it is not held up.
TEST(Governor, ACancelledReservationLeavesTheLine) {
  Governor shared(1000, 0);
  auto running = std::make_unique<Governor>(shared, "a/job", 500);
  std::atomic<bool> stop{false}, cancelled{false}, small_granted{false};
  std::thread whole([&] {
    try {
      Governor own(shared, "whole/job", 1000, [&] { return stop.load(); });
    } catch (const Error& e) {
      cancelled = e.kind() == ErrorKind::cancelled;
    }
  });
  wait_until_refused(shared, "whole/job", cancelled);
  std::thread small([&] {
    Governor own(shared, "small/job", 300);
    small_granted = true;
  });
  wait_until_refused(shared, "small/job", small_granted);
  EXPECT_FALSE(small_granted.load());
  stop = true;
  shared.wake_all();
  whole.join();
  small.join();  // admitted beside the running job once the whole one left the line
  EXPECT_TRUE(cancelled.load());
  EXPECT_TRUE(small_granted.load());
}

// fix17: a stop callback that throws while its reservation waits (a job's cancel
// callback, JobHooks::cancel) must take the reservation out of the line too: left in
// it, its ticket stayed first and every later reservation waited for good.
TEST(Governor, AReservationWhoseStopThrowsLeavesTheLine) {
  Governor shared(1000, 0);
  auto running = std::make_unique<Governor>(shared, "a/job", 500);
  bool thrown = false;
  try {
    Governor own(shared, "whole/job", 1000, []() -> bool { throw std::runtime_error("cancel callback failed"); });
  } catch (const std::runtime_error&) {
    thrown = true;
  }
  EXPECT_TRUE(thrown);
  ASSERT_EQ(shared.queued_reservations(), 0u);
  // The next reservation that fits goes at once.
  Governor small(shared, "small/job", 300);
  EXPECT_EQ(shared.in_use(), 800u);
}

// The peak-RSS window (job.hpp) resets the process's VmHWM only for a job alone in its
// process's governor (jobs on a reserved governor count in the root), and measures
// nothing when another job was alive at its end or started in between.
TEST(Governor, APeakWindowIsMeasuredOnlyForAJobAlone) {
  Governor shared(256ull << 20, 0);
  Governor own(shared, "a/job", 64ull << 20);
  {
    Job alone(own, {}, {.threads = 1});
    EXPECT_EQ(shared.jobs_alive(), 1);
    EXPECT_GT(SoleJobPeakWindow(own).peak(), 0u);
    SoleJobPeakWindow window(own);
    { Job other(shared, {}, {.threads = 1}); }
    EXPECT_EQ(window.peak(), 0u);  // another job ran in it
    Job other(shared, {}, {.threads = 1});
    EXPECT_EQ(SoleJobPeakWindow(own).peak(), 0u);  // not opened beside another job
  }
  EXPECT_EQ(shared.jobs_alive(), 0);
  EXPECT_EQ(shared.jobs_started(), 3u);
}

// A one-thread job whose progress reports land in `seen` (the hook's fraction, stage).
struct ProgressSeen {
  Governor governor{1000, 0};
  std::vector<std::pair<double, std::string>> seen;
  Job job{governor,
          JobHooks{.progress = [this](double fraction, const std::string& stage) { seen.emplace_back(fraction, stage); },
                   .cancel = {}},
          {.threads = 1}};
};

// A job's progress is one rising fraction for the whole run: each stage reports its own
// share of work in [0, 1] and the driver maps it into the stage's span. The out-of-core
// simplify's conversion used to report from 0 again after the load had reached 0.9.
TEST(JobProgress, StagesReportIntoTheirSpansAndTheFractionNeverFalls) {
  ProgressSeen recorded;
  auto& [governor, seen, job] = recorded;
  // Reports closer than 50 ms apart are dropped (at most ~20 a second).
  auto report = [&](double fraction, const char* stage) {
    std::this_thread::sleep_for(std::chrono::milliseconds(60));
    job.progress(fraction, stage);
  };
  job.progress_span(0, 0.25);
  report(0.5, "load");
  report(1.0, "load");
  job.progress_span(0.25, 1);
  report(0.0, "convert");  // its own start: the job stays where the load ended
  report(0.5, "convert");
  report(0.4, "convert");  // a late report from another thread
  const std::vector<std::pair<double, std::string>> expected{
      {0.125, "load"}, {0.25, "load"}, {0.25, "convert"}, {0.625, "convert"}, {0.625, "convert"}};
  EXPECT_EQ(seen, expected);
}

// Reports within 50 ms of the last are dropped, but not a new stage's first: a short
// stage (an out-of-core pass over a few small patches) showed nothing of itself.
TEST(JobProgress, ANewStagesFirstReportIsNeverDropped) {
  ProgressSeen recorded;
  auto& [governor, seen, job] = recorded;
  job.progress(0.25, "a");
  job.progress(0.5, "a");  // dropped: the same stage, within 50 ms
  job.progress(0.5, "b");
  job.progress(0.75, "b");  // dropped
  job.progress(1.0, "b");   // the end always goes through
  const std::vector<std::pair<double, std::string>> expected{{0.25, "a"}, {0.5, "b"}, {1.0, "b"}};
  EXPECT_EQ(seen, expected);
}

}  // namespace
}  // namespace qemflow::engine
