// Throughput of the mesh generator's core (no file writing): faces per second for
// each shape, into a sink that only counts, with all threads and with one.
//   build/bench/gen_bench --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include "gen/generator.hpp"

namespace {

using qemflow::gen::GenOptions;

class CountingSink final : public qemflow::gen::MeshSink {
 public:
  void begin(uint64_t, uint64_t) override {}
  void vertices(const qemflow::Point* points, size_t count) override {
    checksum_ += count ? points[count - 1][0] : 0;
  }
  void triangles(const qemflow::Triangle* triangles, size_t count) override {
    checksum_ += count ? static_cast<double>(triangles[count - 1][0]) : 0;
  }
  double checksum() const { return checksum_; }

 private:
  double checksum_ = 0;
};

void generate(benchmark::State& state, const char* shape, int threads) {
  std::unique_ptr<tbb::global_control> limit;
  if (threads) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
  const GenOptions options{shape, static_cast<uint64_t>(state.range(0)), 1};
  for (auto _ : state) {
    CountingSink sink;
    qemflow::gen::generate(options, sink);
    benchmark::DoNotOptimize(sink.checksum());
  }
  state.counters["faces/s"] =
      benchmark::Counter(static_cast<double>(state.range(0)) * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate);
}

void all_threads(benchmark::State& state, const char* shape) { generate(state, shape, 0); }
void one_thread(benchmark::State& state, const char* shape) { generate(state, shape, 1); }

}  // namespace

BENCHMARK_CAPTURE(all_threads, blob, "blob")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(all_threads, terrain, "terrain")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(all_threads, figure, "figure")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(one_thread, blob, "blob")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(one_thread, terrain, "terrain")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(one_thread, figure, "figure")->Arg(2'000'000)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
