#include "nodes/pipeline/partition_stage.hpp"

#include <oneapi/tbb/enumerable_thread_specific.h>

#include <algorithm>

#include "config/size.hpp"
#include "nodes/partition/fuzzy_clusterer.hpp"
#include "nodes/partition/partition_budget.hpp"
#include "nodes/partition/proximity_graph.hpp"
#include "nodes/partition/surface_sampler.hpp"
#include "nodes/pipeline/patch_count.hpp"
#include "util/error.hpp"

namespace qemflow::nodes::pipeline {

namespace {

using partition::PositionedFace;

constexpr uint64_t min_samples = 2000;

std::vector<PositionedFace> positioned(const engine::FrameHeader& header, const engine::Bytes& records,
                                       uint32_t record_size) {
  std::vector<engine::BlockFace> faces(header.count);
  engine::unpack_block_faces(records.data(), header.count, record_size, faces.data());
  std::vector<PositionedFace> out(header.count);
  for (uint64_t i = 0; i < header.count; ++i) out[i] = {faces[i].id, faces[i].positions};
  return out;
}

// Each compute thread feeds its own `State`; the states are merged at the end (the
// kernels' results do not depend on how faces were split or merged).
template <class State, class Add>
std::vector<State> over_all_faces(engine::Job& job, engine::ScratchStore& scratch, const engine::LoadedMesh& mesh,
                                  const char* stage, const State& empty, Add add) {
  tbb::enumerable_thread_specific<State> states(empty);
  engine::for_each_frame(
      job, scratch, stage, "partition frames", all_block_frames(mesh), mesh.block_record_size,
      [&](const engine::FrameHeader& header, engine::Bytes& records, engine::Lease&) {
        const auto faces = positioned(header, records, mesh.block_record_size);
        add(states.local(), std::span<const PositionedFace>(faces));
      },
      {}, sizeof(PositionedFace) + sizeof(engine::BlockFace));
  std::vector<State> out;
  for (auto& state : states) out.push_back(std::move(state));
  return out;
}

}  // namespace

std::vector<engine::FrameRef> all_block_frames(const engine::LoadedMesh& mesh) {
  std::vector<engine::FrameRef> frames;
  for (const auto& block : mesh.blocks) frames.insert(frames.end(), block.begin(), block.end());
  return frames;
}

uint32_t clusters_for(const engine::LoadedMesh& mesh, uint64_t budget_bytes, const PartitionOptions& options) {
  if (options.clusters) return options.clusters;
  // The epoch pipeline runs one patch at a time, but a patch peaks at ~430 B per patch
  // face while gathered and built (state records + PatchInput + decimator; measured on
  // 5M faces at 256M), with 1.4-2.1 patch faces per owned face at 26-32 halo rings
  // (the larger for small patches: 2.06 on 1M faces at 96M). An estimate: a patch
  // that does not fit its lease is split into parts by the epoch pass (epochs.hpp).
  PatchBudget patch;
  patch.decimator_bytes_per_face = 320;
  patch.halo_factor = 2.0;
  patch.concurrent_patches = 1;
  return patch_count_for_budget(mesh.kept_faces(), budget_bytes, patch);
}

Partition partition_blocks(engine::Job& job, engine::ScratchStore& scratch, const engine::LoadedMesh& mesh,
                           const PartitionOptions& options) {
  engine::StageTimer timer(job, "partition");  // the report's seconds, early returns included
  Partition result;
  // The capacity (budget less the measured baseline) is what patches may hold.
  result.clusters = clusters_for(mesh, job.capacity(), options);
  if (result.clusters <= 1 || mesh.kept_faces() == 0) {
    result.clusters = 1;
    return result;
  }
  const uint32_t clusters = result.clusters;
  const uint32_t threads = uint32_t(std::max(job.threads(), 1));
  // The kernels' working set, under one lease held for the stage; the frame streams
  // take their own small leases from what is left.
  const uint64_t wanted = options.samples ? options.samples : std::max<uint64_t>(20'000, 500ull * clusters);
  const uint64_t thread_sampling = (threads - 1) * partition::PartitionFootprint{}.sampling_bytes_per_sample;
  auto peak = [&](uint64_t samples) {
    return partition::partition_peak_bytes(samples, clusters, threads) + samples * thread_sampling;
  };
  job.require_fits(job.owner("partition"), peak(min_samples) + (8ull << 20));
  engine::Lease lease = job.governor().acquire_share(
      job.owner("partition"), peak(min_samples), [&](uint64_t free) { return std::min(peak(wanted), free / 2); },
      [&] { return job.stopped(); });
  job.check();
  uint64_t cap = min_samples;
  while (cap < wanted && peak(cap * 2) <= lease.bytes()) cap *= 2;
  const uint64_t target = std::min(wanted, std::max(cap, min_samples));

  // Pass 1: the surface area, for the radius.
  auto areas = over_all_faces(job, scratch, mesh, "partition", partition::SurfaceAreaSum{},
                              [](partition::SurfaceAreaSum& sum, std::span<const PositionedFace> faces) {
                                sum.add_faces(faces);
                              });
  partition::SurfaceAreaSum area;
  for (const auto& part : areas) area.merge(part);
  result.area = area.total();

  // Pass 2: Poisson-disk samples.
  partition::SamplerOptions sampler_options;
  sampler_options.radius = partition::radius_for_sample_count(result.area, target);
  sampler_options.max_samples = target;
  sampler_options.seed = options.seed;
  auto samplers = over_all_faces(job, scratch, mesh, "partition", partition::SurfaceSampler(sampler_options),
                                 [](partition::SurfaceSampler& sampler, std::span<const PositionedFace> faces) {
                                   sampler.add_faces(faces);
                                 });
  partition::SurfaceSampler sampler(sampler_options);
  for (auto& part : samplers) sampler.merge(std::move(part));
  samplers.clear();
  partition::SampleSet set = sampler.finish();
  sampler = partition::SurfaceSampler(sampler_options);
  // Too little surface for the clusters the budget asked for (every face a copy of one
  // triangle gives one sample): valid input, so as many clusters as there are samples,
  // and none (one patch) below two; the caller decides whether one patch can run.
  result.samples = set.samples.size();
  result.radius = set.radius;
  if (set.samples.size() < clusters) {
    if (set.samples.size() < 2) {
      result.clusters = 1;
      return result;
    }
    result.clusters = uint32_t(set.samples.size());
  }
  const uint32_t clusters_run = result.clusters;

  job.arena().execute([&] {
    const partition::ProximityGraph graph = partition::build_proximity_graph(set.samples, set.radius);
    const partition::Clustering clustering = partition::cluster_samples(set.samples, graph, {.clusters = clusters_run});
    result.classifier = partition::train_plane_classifier(set.samples, clustering.labels, clusters_run);
    result.fcm_iterations = clustering.iterations;
    result.samples_per_cluster.assign(clusters_run, 0);
    for (uint32_t label : clustering.labels) ++result.samples_per_cluster[label];
  });
  job.check();
  return result;
}

}  // namespace qemflow::nodes::pipeline
