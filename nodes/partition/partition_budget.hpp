#pragma once
// What the partition kernels cost in memory, so the pipeline can pick the sample count
// (and the cluster count) from --mem-budget before it samples anything.
//
// Per-sample costs, measured with the defaults (SamplerOptions, ProximityOptions,
// ClusterOptions) on spheres, tori, the bunny and the dragon:
// - sampling: 13.5 kept candidates × 56 bytes, held twice at finish() (the sort copy),
//   plus the accepted sample (56 bytes);
// - proximity graph: ~6.5 neighbours within 2r; the build holds per-row vectors
//   (24 + 16 bytes per neighbour) and the result (12 bytes per neighbour + 8);
// - clustering: float distances and memberships, 8 bytes per sample and cluster, plus one
//   double column per thread running a Dijkstra (counted for `threads`);
// - classifier training: negligible (≤ 2 × max_points_per_class points per pair and
//   thread, libsvm's cache bounded by SvmOptions::cache_megabytes per thread).
// The sampler's peak and the clusterer's peak do not overlap; the samples and the graph
// live through both. Estimates carry a 25% margin.
#include <algorithm>
#include <cstdint>

namespace qemflow::nodes::partition {

struct PartitionFootprint {
  uint64_t sampling_bytes_per_sample = 2 * 14 * 56 + 56;
  uint64_t graph_bytes_per_sample = 24 + 7 * 16 + 7 * 12 + 8;
  uint64_t cluster_bytes_per_sample_and_cluster = 8;
  uint64_t dijkstra_bytes_per_sample_and_thread = 8 + 8;  // column + heap share
};

inline uint64_t partition_peak_bytes(uint64_t samples, uint32_t clusters, uint32_t threads,
                                     const PartitionFootprint& f = {}) {
  const uint64_t living = samples * (56 + f.graph_bytes_per_sample);
  const uint64_t sampling = samples * f.sampling_bytes_per_sample;
  const uint64_t clustering = samples * (uint64_t{clusters} * f.cluster_bytes_per_sample_and_cluster +
                                         uint64_t{threads} * f.dijkstra_bytes_per_sample_and_thread);
  return (living + std::max(sampling, clustering)) * 5 / 4;
}

// The largest sample count whose partition_peak_bytes fits `budget_bytes`.
inline uint64_t max_samples_for_budget(uint64_t budget_bytes, uint32_t clusters, uint32_t threads,
                                       const PartitionFootprint& f = {}) {
  const uint64_t per_sample = partition_peak_bytes(1000, clusters, threads, f);  // per 1000 samples
  return per_sample == 0 ? 0 : budget_bytes / per_sample * 1000;
}

}  // namespace qemflow::nodes::partition
