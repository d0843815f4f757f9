// Out-of-core simplify jobs side by side on one governor (nodes/pipeline/epochs.hpp,
// run_ooc_job): each job reserves its share and runs on it as a lone run would, so the
// outputs are each job's alone (and in core's) byte for byte, the governor never lends
// more than its capacity, and a budget too tight for both makes them take turns.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <future>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"
#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/decimate/simplify.hpp"
#include "nodes/pipeline/epochs.hpp"
#include "test_support.hpp"
#include "util/error.hpp"

namespace qemflow::testing {
namespace {

using nodes::pipeline::OocJob;
using nodes::pipeline::run_ooc_job;

constexpr uint64_t MiB = 1ull << 20;

std::filesystem::path make_mesh(const TempDir& dir, uint64_t faces, uint64_t seed) {
  gen::GenOptions options;
  options.faces = faces;
  options.seed = seed;
  const auto path = dir / ("in" + std::to_string(faces) + ".ply");
  gen::generate_to_file(options, path);
  return path;
}

// --ratio 0.02 --double with 4 clusters, out of core down to 45000 faces: 3 and 7
// epochs on patches for 60k and 100k faces (down to 4000, 24 for 100k, took 1.6 times as long).
OocJob job_for(const TempDir& dir, const std::filesystem::path& input, const std::string& name) {
  OocJob job;
  job.input = input;
  job.output = dir / (name + ".ply");
  job.scratch_dir = dir.path();
  job.threads = 1;
  job.double_precision = true;
  job.job_name = name;
  job.options.simplify.ratio = 0.02;
  job.options.partition.clusters = 4;
  job.options.in_core_faces = 45000;
  return job;
}

// What `qemflow simplify IN OUT --ratio 0.02 --in-core --double` writes.
std::string in_core_bytes(const TempDir& dir, const std::filesystem::path& input) {
  io::IndexedMesh mesh = io::read_mesh(input);
  nodes::SimplifyOptions options;
  options.ratio = 0.02;
  auto result = nodes::simplify_in_core(std::move(mesh.vertices), std::move(mesh.triangles), options);
  const auto path = dir / "in_core.ply";
  io::WriteOptions write;
  write.double_precision = true;
  io::write_mesh(path, {std::move(result.points), std::move(result.triangles)}, write);
  return file_bytes(path);
}

// Runs the jobs on `governor`, one thread each; fails (and cancels them) if they have not
// all ended within `seconds`. Returns each job's error message ("" if none).
std::vector<std::string> run_side_by_side(engine::Governor& governor, const std::vector<OocJob>& jobs,
                                          std::vector<nlohmann::json>& reports, int seconds,
                                          const std::function<void(size_t)>& on_progress = {}) {
  std::vector<std::shared_ptr<engine::CancelToken>> cancels;
  std::vector<std::future<void>> runs;
  std::vector<std::string> errors(jobs.size());
  reports.assign(jobs.size(), {});
  for (size_t j = 0; j < jobs.size(); ++j) {
    cancels.push_back(std::make_shared<engine::CancelToken>());
    engine::JobHooks hooks{.cancel = cancels[j]};
    if (on_progress) hooks.progress = [&on_progress, j](double, const std::string&) { on_progress(j); };
    runs.push_back(std::async(std::launch::async, [&, j, hooks] {
      try {
        reports[j] = run_ooc_job(governor, jobs[j], hooks);
      } catch (const std::exception& e) {
        errors[j] = e.what();
      }
    }));
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  for (auto& run : runs) {
    if (run.wait_until(deadline) == std::future_status::timeout) {
      ADD_FAILURE() << "the jobs did not end within " << seconds << " s (deadlock?)";
      for (auto& cancel : cancels) cancel->cancel();
      break;
    }
  }
  for (auto& run : runs) run.wait();
  return errors;
}

void expect_owners_prefixed(const nlohmann::json& report, const std::string& prefix) {
  ASSERT_FALSE(report["nodes"].empty());
  for (const auto& node : report["nodes"])
    EXPECT_EQ(node["name"].get<std::string>().rfind(prefix, 0), 0u) << node["name"];
}

// The two inputs (each test is a process of its own: made once per test), and the
// in-core outputs, made when a test first asks.
struct Meshes {
  TempDir dir;
  std::filesystem::path small = make_mesh(dir, 60'000, 1), large = make_mesh(dir, 100'000, 2);
  const std::string& small_in_core() {
    if (small_bytes.empty()) small_bytes = in_core_bytes(dir, small);
    return small_bytes;
  }
  const std::string& large_in_core() {
    if (large_bytes.empty()) large_bytes = in_core_bytes(dir, large);
    return large_bytes;
  }
  std::string small_bytes, large_bytes;
};

Meshes& meshes() {
  static Meshes m;
  return m;
}

// Alone, on a governor of its own (the CLI's way): the in-core bytes, out of core.
TEST(SimplifyOocJobs, AJobAloneWritesTheInCoreBytes) {
  Meshes& m = meshes();
  engine::Governor governor(128 * MiB, 0);
  TempDir out;
  const OocJob job = job_for(out, m.small, "alone");
  const nlohmann::json report = run_ooc_job(governor, job, {});
  EXPECT_GT(report["out_of_core_epochs"].get<int>(), 0);
  EXPECT_EQ(report["patches"].get<int>(), 4);
  EXPECT_GT(report["in_core_peak_rss_bytes"].get<uint64_t>(), 0u);  // alone: measured
  EXPECT_TRUE(file_bytes(job.output) == m.small_in_core()) << "output differs from in core";
  EXPECT_EQ(governor.in_use(), 0u);
}

// What a host (and the CLI's bar) sees of a run: one fraction that never falls, moving
// through the load, the conversion, each epoch pass and the in-core finish to 1 at
// "done". The finish used to report nothing (a 20M-face finish is minutes of a frozen
// bar) and the conversion started again from 0 after the load.
TEST(SimplifyOocJobs, ProgressRisesThroughTheEpochsAndTheFinish) {
  Meshes& m = meshes();
  engine::Governor governor(128 * MiB, 0);
  TempDir out;
  const OocJob job = job_for(out, m.small, "progress");
  std::vector<std::pair<double, std::string>> seen;
  engine::JobHooks hooks;
  hooks.progress = [&](double fraction, const std::string& stage) { seen.emplace_back(fraction, stage); };
  const nlohmann::json report = run_ooc_job(governor, job, hooks);
  ASSERT_FALSE(seen.empty());
  for (size_t i = 1; i < seen.size(); ++i)
    EXPECT_GE(seen[i].first, seen[i - 1].first) << seen[i - 1].second << " then " << seen[i].second;
  EXPECT_EQ(seen.back(), std::make_pair(1.0, std::string("done")));
  // The finish (from 45000 faces to 1200) is followed round by round, from where the
  // epochs left off.
  std::vector<double> finish;
  for (const auto& [fraction, stage] : seen)
    if (stage == "in core") finish.push_back(fraction);
  ASSERT_GE(finish.size(), 2u) << "the in-core finish reported " << finish.size() << " times";
  EXPECT_LT(finish.front(), finish.back());
  EXPECT_GT(finish.front(), nodes::pipeline::kEpochsFrom);
  EXPECT_GT(report["out_of_core_epochs"].get<int>(), 0);
  // The first pass collapses nothing, yet moves the bar patch by patch (it stood still
  // at the epochs' start): its first report (a new stage's always goes through the
  // 50 ms limit) stands after its first patch, short of the pass's end.
  const auto first_pass = std::find_if(seen.begin(), seen.end(), [](const auto& s) { return s.second == "epoch 1"; });
  ASSERT_NE(first_pass, seen.end());
  using nodes::pipeline::kEpochsFrom, nodes::pipeline::kEpochsTo, nodes::pipeline::kFirstPassShare;
  const double pass_end = kEpochsFrom + kFirstPassShare * (kEpochsTo - kEpochsFrom);
  EXPECT_GT(first_pass->first, kEpochsFrom) << "the first pass held the bar";
  EXPECT_LT(first_pass->first, pass_end - 1e-9) << "the first pass reported its end after its first patch";
}

TEST(SimplifyOocJobs, AJobWritesItsOwnCodecWhateverTheProcessDefault) {
  // A job's frames follow its own store's codec: another job's codec scope (a re-encode
  // that went raw beside it) must not make a zstd job write raw frames onto a disk it
  // checked for zstd's bytes (review15).
  Meshes& m = meshes();
  TempDir out;
  OocJob job = job_for(out, m.small, "codec");
  job.scratch_codec = engine::ScratchCodec::zstd;
  // `other_job`: with a raw codec scope opened once this job runs (the newest scope
  // was the process default's winner).
  auto written = [&](bool other_job) {
    engine::Governor governor(128 * MiB, 0);
    std::unique_ptr<engine::DefaultFrameCodec> other;
    engine::JobHooks hooks;
    hooks.progress = [&](auto&&...) {
      if (other_job && !other) other = std::make_unique<engine::DefaultFrameCodec>(engine::FrameCodec::uncompressed());
    };
    const nlohmann::json report = run_ooc_job(governor, job, hooks);
    EXPECT_EQ(report["scratch_codec"], "zstd");
    EXPECT_EQ(other != nullptr, other_job);
    return report["scratch_bytes_written"].get<uint64_t>();
  };
  const uint64_t alone = written(false);
  const uint64_t beside_raw = written(true);
  EXPECT_GT(alone, 0u);
  EXPECT_EQ(beside_raw, alone);
  EXPECT_TRUE(file_bytes(job.output) == m.small_in_core());
}

// Runs job0 (60k faces) and job1 (100k) on `governor`, each reserving `job_budget`;
// both must end without error, with the in-core bytes (so those of each alone:
// AJobAloneWritesTheInCoreBytes), everything given back and every owner named per job.
void expect_two_jobs_run(engine::Governor& governor, uint64_t job_budget,
                         const std::function<void(size_t)>& on_progress = {}) {
  Meshes& m = meshes();
  TempDir out;
  std::vector<OocJob> jobs{job_for(out, m.small, "job0"), job_for(out, m.large, "job1")};
  for (auto& job : jobs) job.job_budget = job_budget;
  std::vector<nlohmann::json> reports;
  const auto errors = run_side_by_side(governor, jobs, reports, 120, on_progress);
  EXPECT_EQ(errors, (std::vector<std::string>{"", ""}));
  EXPECT_LE(governor.peak_in_use(), governor.capacity());
  EXPECT_EQ(governor.in_use(), 0u);
  std::set<std::string> owners;
  for (const auto& o : governor.owners()) owners.insert(o.owner);
  EXPECT_EQ(owners, (std::set<std::string>{"job0/job", "job1/job"}));
  for (size_t j = 0; j < 2; ++j) {
    expect_owners_prefixed(reports[j], jobs[j].job_name + "/");
    EXPECT_LE(reports[j]["governor_peak_bytes"].get<uint64_t>(), job_budget);
  }
  EXPECT_TRUE(file_bytes(jobs[0].output) == m.small_in_core()) << "job0's output differs from alone / in core";
  EXPECT_TRUE(file_bytes(jobs[1].output) == m.large_in_core()) << "job1's output differs from alone / in core";
}

// Two jobs whose reservations fit together run at the same time (each waits in its
// progress callback until the other has started).
TEST(SimplifyOocJobs, TwoJobsShareOneGovernorSideBySide) {
  engine::Governor governor(200 * MiB, 8 * MiB);
  std::mutex mutex;
  std::condition_variable cv;
  std::set<size_t> started;
  auto meet = [&](size_t j) {
    std::unique_lock lock(mutex);
    if (started.insert(j).second) cv.notify_all();
    cv.wait_for(lock, std::chrono::seconds(20), [&] { return started.size() == 2; });
  };
  expect_two_jobs_run(governor, 96 * MiB, meet);
  EXPECT_EQ(started.size(), 2u);
  EXPECT_EQ(governor.peak_in_use(), 2 * 96 * MiB) << "the jobs never ran at the same time";
}

// A shared budget that holds one reservation but not two: the second job waits, holding
// nothing, until the first ends; both finish (no deadlock) with the same bytes. (With
// job_budget 0, all of the capacity, jobs wait the same way: the cancel test below.)
TEST(SimplifyOocJobs, ATightSharedBudgetMakesTheJobsTakeTurns) {
  engine::Governor governor(120 * MiB, 8 * MiB);
  expect_two_jobs_run(governor, 72 * MiB);
  EXPECT_EQ(governor.peak_in_use(), 72 * MiB) << "both held at once";
}

// A job budget the governor can never hold fails up front, naming a budget; one
// waiting for its reservation ends at a cancel; either way nothing is written.
TEST(SimplifyOocJobs, AReservationThatCanNeverFitOrIsCancelledFails) {
  Meshes& m = meshes();
  TempDir out;
  engine::Governor governor(64 * MiB, 8 * MiB);
  OocJob job = job_for(out, m.small, "big");
  job.job_budget = 64 * MiB;
  try {
    run_ooc_job(governor, job, {});
    ADD_FAILURE() << "a job budget over the capacity ran";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
    EXPECT_NE(std::string(e.what()).find("minimum budget is"), std::string::npos) << e.what();
  }
  engine::Lease held = governor.try_acquire("host", governor.capacity());
  auto cancel = std::make_shared<engine::CancelToken>();
  job.job_budget = 0;
  auto run = std::async(std::launch::async, [&] { run_ooc_job(governor, job, {.cancel = cancel}); });
  EXPECT_EQ(run.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  cancel->cancel();
  ASSERT_EQ(run.wait_for(std::chrono::seconds(10)), std::future_status::ready);
  try {
    run.get();
    ADD_FAILURE() << "ran while everything was held";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::cancelled);
  }
  EXPECT_FALSE(std::filesystem::exists(job.output));
}

}  // namespace
}  // namespace qemflow::testing
