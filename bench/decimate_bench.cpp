// Kernel-level benchmarks of the decimator on generated meshes: setup (connectivity,
// locks, quadrics), one LME round, and the whole in-core run to 1%. Counters report
// input faces per second (divide by the thread count for per-core figures).
#include <benchmark/benchmark.h>

#include <map>

#include "gen/generator.hpp"
#include "nodes/decimate/quadric.hpp"
#include "nodes/decimate/simplify.hpp"

namespace {

using namespace qemflow;

const io::IndexedMesh& blob(uint64_t faces) {
  static std::map<uint64_t, io::IndexedMesh> cache;
  auto it = cache.find(faces);
  if (it == cache.end()) it = cache.emplace(faces, gen::generate_in_memory({"blob", faces, 1})).first;
  return it->second;
}

nodes::PatchInput patch_of(const io::IndexedMesh& mesh) {
  nodes::PatchInput in;
  in.positions.assign(mesh.vertices.begin(), mesh.vertices.end());
  in.vertex_gids.resize(mesh.vertices.size());
  for (size_t i = 0; i < in.vertex_gids.size(); ++i) in.vertex_gids[i] = i;
  in.faces.resize(mesh.triangles.size());
  in.face_gids.resize(mesh.triangles.size());
  for (size_t f = 0; f < mesh.triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) in.faces[f][k] = static_cast<uint32_t>(mesh.triangles[f][k]);
    in.face_gids[f] = f;
  }
  return in;
}

void BM_Setup(benchmark::State& state) {
  const auto& mesh = blob(state.range(0));
  for (auto _ : state) {
    state.PauseTiming();
    auto in = patch_of(mesh);
    state.ResumeTiming();
    nodes::PatchDecimator decimator(std::move(in), {});
    benchmark::DoNotOptimize(decimator.face_count());
  }
  state.counters["faces/s"] = benchmark::Counter(double(mesh.triangles.size()) * state.iterations(),
                                                 benchmark::Counter::kIsRate);
}

void BM_FirstRound(benchmark::State& state) {
  const auto& mesh = blob(state.range(0));
  for (auto _ : state) {
    state.PauseTiming();
    nodes::PatchDecimator decimator(patch_of(mesh), {});
    state.ResumeTiming();
    decimator.prepare_round();
    const auto plan = nodes::plan_round(decimator.summarize(), decimator.face_count(), 0, 0.1, 0.5);
    benchmark::DoNotOptimize(decimator.apply_cut(plan.cut));
  }
  state.counters["faces/s"] = benchmark::Counter(double(mesh.triangles.size()) * state.iterations(),
                                                 benchmark::Counter::kIsRate);
}

void BM_SimplifyToOnePercent(benchmark::State& state) {
  const auto& mesh = blob(state.range(0));
  uint64_t rounds = 0;
  for (auto _ : state) {
    state.PauseTiming();
    auto points = mesh.vertices;
    auto triangles = mesh.triangles;
    state.ResumeTiming();
    nodes::SimplifyOptions options;
    options.ratio = 0.01;
    const auto result = nodes::simplify_in_core(std::move(points), std::move(triangles), options);
    rounds = result.stats.rounds;
  }
  state.counters["faces/s"] = benchmark::Counter(double(mesh.triangles.size()) * state.iterations(),
                                                 benchmark::Counter::kIsRate);
  state.counters["rounds"] = double(rounds);
}

// The deviation charge's kernel as deviation() feeds it: two endpoints against a moved
// fan of 8 triangles around the collapse position (the decimator's usual fan), fans
// from a generated blob's vertices so the Voronoi regions hit are realistic.
void BM_FanDeviation(benchmark::State& state) {
  const auto& mesh = blob(20'000);
  std::vector<std::array<nodes::Vec3, 11>> fans;  // a, b, p, then a ring of 8
  for (size_t f = 0; f + 10 < mesh.vertices.size() && fans.size() < 1024; f += 11) {
    std::array<nodes::Vec3, 11> fan;
    for (int k = 0; k < 11; ++k) fan[k] = mesh.vertices[f + k];
    fans.push_back(fan);
  }
  double sum = 0.0;
  for (auto _ : state) {
    for (const auto& fan : fans) {
      nodes::FanDeviation deviation(fan[0], fan[1]);
      for (int i = 0; i < 8; ++i) deviation.add(fan[2], fan[3 + i], fan[3 + (i + 1) % 8]);
      sum += deviation.charge(1.0, 1.0);
    }
  }
  benchmark::DoNotOptimize(sum);
  state.counters["triangles/s"] = benchmark::Counter(8.0 * fans.size() * state.iterations(),
                                                     benchmark::Counter::kIsRate);
}

BENCHMARK(BM_FanDeviation);
BENCHMARK(BM_Setup)->Arg(200'000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FirstRound)->Arg(200'000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SimplifyToOnePercent)->Arg(200'000)->Unit(benchmark::kMillisecond)->Iterations(2);

}  // namespace

BENCHMARK_MAIN();
