// The partition kernels on a ~1M-face generated blob (gen::generate_in_memory):
// sampling (faces/s and samples made), proximity graph, Fuzzy C-Means, ν-SVM training
// for all C(C−1)/2 pairs, and DAG-SVM face classification (faces/s). 50k samples, the
// paper's "< 10% of the vertices".
//
// Also the driver for bench/partition_picture.py:
//   partition_bench --dump-partition=OUT.bin [--mesh=IN.ply[.zst]] [--clusters=N] [--samples=N]
// partitions the mesh (default: the 1M-face blob) and writes, little-endian:
// "QPRT", u32 vertex count, u32 face count, f32 xyz per vertex, u32 abc per face,
// u32 patch per face — then exits without running the benchmarks.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/partition/fuzzy_clusterer.hpp"
#include "nodes/partition/plane_classifier.hpp"

namespace {

using namespace qemflow;
using namespace qemflow::nodes::partition;

constexpr uint64_t kFaces = 1'000'000;
constexpr uint64_t kSamples = 50'000;

std::vector<PositionedFace> positioned(const std::vector<Point>& vertices, const std::vector<Triangle>& triangles) {
  std::vector<PositionedFace> faces(triangles.size());
  for (size_t f = 0; f < faces.size(); ++f) {
    faces[f].id = f;
    for (int c = 0; c < 3; ++c) faces[f].corners[c] = vertices[triangles[f][c]];
  }
  return faces;
}

struct Fixture {
  std::vector<PositionedFace> faces;
  SampleSet set;
  ProximityGraph graph;
  Fixture() {
    const auto mesh = gen::generate_in_memory({.shape = "blob", .faces = kFaces, .seed = 1});
    faces = positioned(mesh.vertices, mesh.triangles);
    set = sample_faces(faces, kSamples);
    graph = build_proximity_graph(set.samples, set.radius);
  }
};

const Fixture& fixture() {
  static const Fixture f;
  return f;
}

void BM_SampleSurface(benchmark::State& state) {
  const auto& f = fixture();
  size_t samples = 0;
  for (auto _ : state) samples = sample_faces(f.faces, kSamples).samples.size();
  state.counters["faces/s"] = benchmark::Counter(static_cast<double>(f.faces.size()), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["samples/s"] = benchmark::Counter(static_cast<double>(samples), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["samples"] = static_cast<double>(samples);
}
BENCHMARK(BM_SampleSurface)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

void BM_ProximityGraph(benchmark::State& state) {
  const auto& f = fixture();
  for (auto _ : state) benchmark::DoNotOptimize(build_proximity_graph(f.set.samples, f.set.radius));
  state.counters["edges/sample"] = static_cast<double>(f.graph.neighbours.size()) / static_cast<double>(f.graph.size());
}
BENCHMARK(BM_ProximityGraph)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

void BM_FuzzyCMeans(benchmark::State& state) {
  const auto& f = fixture();
  Clustering c;
  for (auto _ : state) c = cluster_samples(f.set.samples, f.graph, {.clusters = static_cast<uint32_t>(state.range(0))});
  state.counters["iterations"] = c.iterations;
}
BENCHMARK(BM_FuzzyCMeans)->Arg(16)->Arg(64)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

// Clusters for the SVM rows, made once per cluster count.
const std::vector<uint32_t>& labels_for(uint32_t clusters) {
  static std::vector<std::vector<uint32_t>> cache(257);
  if (cache[clusters].empty())
    cache[clusters] = cluster_samples(fixture().set.samples, fixture().graph, {.clusters = clusters}).labels;
  return cache[clusters];
}

void BM_TrainSvm(benchmark::State& state) {
  const auto clusters = static_cast<uint32_t>(state.range(0));
  const auto& labels = labels_for(clusters);
  for (auto _ : state) benchmark::DoNotOptimize(train_plane_classifier(fixture().set.samples, labels, clusters));
  state.counters["pairs"] = static_cast<double>(PlaneClassifier::pair_count(clusters));
}
BENCHMARK(BM_TrainSvm)->Arg(16)->Arg(64)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

void BM_ClassifyFaces(benchmark::State& state) {
  const auto clusters = static_cast<uint32_t>(state.range(0));
  const auto& f = fixture();
  const PlaneClassifier classifier = train_plane_classifier(f.set.samples, labels_for(clusters), clusters);
  std::vector<uint32_t> labels(f.faces.size());
  for (auto _ : state) {
    classify_faces(f.faces, classifier, labels);
    benchmark::ClobberMemory();
  }
  state.counters["faces/s"] = benchmark::Counter(static_cast<double>(f.faces.size()), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_ClassifyFaces)->Arg(16)->Arg(64)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(5);

std::string flag_value(int argc, char** argv, const std::string& name) {
  const std::string prefix = "--" + name + "=";
  for (int i = 1; i < argc; ++i)
    if (std::strncmp(argv[i], prefix.c_str(), prefix.size()) == 0) return argv[i] + prefix.size();
  return {};
}

int dump_partition(int argc, char** argv) {
  const std::string out = flag_value(argc, argv, "dump-partition");
  const std::string mesh_path = flag_value(argc, argv, "mesh");
  const std::string clusters_text = flag_value(argc, argv, "clusters");
  const std::string samples_text = flag_value(argc, argv, "samples");
  const uint32_t clusters = clusters_text.empty() ? 8 : static_cast<uint32_t>(std::stoul(clusters_text));
  const uint64_t samples = samples_text.empty() ? 20000 : std::stoull(samples_text);
  io::IndexedMesh mesh;
  if (mesh_path.empty()) {
    auto generated = gen::generate_in_memory({.shape = "blob", .faces = kFaces, .seed = 1});
    mesh.vertices = std::move(generated.vertices);
    mesh.triangles = std::move(generated.triangles);
  } else {
    mesh = io::read_mesh(mesh_path);
  }
  const auto faces = positioned(mesh.vertices, mesh.triangles);
  const SampleSet set = sample_faces(faces, samples);
  const ProximityGraph graph = build_proximity_graph(set.samples, set.radius);
  const Clustering clustering = cluster_samples(set.samples, graph, {.clusters = clusters});
  const PlaneClassifier classifier = train_plane_classifier(set.samples, clustering.labels, clusters);
  std::vector<uint32_t> patch(faces.size());
  classify_faces(faces, classifier, patch);

  std::ofstream file(out, std::ios::binary);
  auto put = [&](const void* data, size_t bytes) { file.write(static_cast<const char*>(data), static_cast<std::streamsize>(bytes)); };
  const uint32_t counts[2] = {static_cast<uint32_t>(mesh.vertices.size()), static_cast<uint32_t>(mesh.triangles.size())};
  put("QPRT", 4);
  put(counts, sizeof counts);
  for (const auto& v : mesh.vertices) {
    const float xyz[3] = {static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2])};
    put(xyz, sizeof xyz);
  }
  for (const auto& t : mesh.triangles) {
    const uint32_t abc[3] = {static_cast<uint32_t>(t[0]), static_cast<uint32_t>(t[1]), static_cast<uint32_t>(t[2])};
    put(abc, sizeof abc);
  }
  put(patch.data(), patch.size() * sizeof(uint32_t));
  std::printf("%zu faces, %zu samples (radius %g), %u clusters after %u FCM iterations -> %s\n", faces.size(),
              set.samples.size(), set.radius, clusters, clustering.iterations, out.c_str());
  return file ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (!flag_value(argc, argv, "dump-partition").empty()) return dump_partition(argc, argv);
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
