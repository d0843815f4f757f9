#pragma once
// Fuzzy C-Means clustering of surface samples with geodesic distances (paper §4.3).
//
// Distances: the paper measures the distance from a cluster centre to every sample with
// a Discrete Exponential Map [Schmidt et al. 2006] grown over the proximity graph. Here
// the distance is the shortest path (Dijkstra) over the proximity graph with the
// approximate geodesic edge lengths: the same propagation order as DEM, without the
// tangent-plane coordinates. On Poisson-disk samples it overestimates true geodesics by
// a few percent, uniformly, which FCM (like DEM's own error) tolerates.
//
// Contract
// - Seeds: clusters are shared out over the graph's connected components in proportion
//   to their sample counts (D'Hondt); in each component the first seed is the sample
//   farthest from its lowest-id sample, the next ones are farthest-point picks. Samples
//   of components that get no cluster ("orphans", e.g. tiny islands) use Euclidean
//   distances to the centres and never move a centre.
// - Iteration: memberships u_ik ∝ d_ik^(−2/(m−1)); centre k = Σ u_ik^m x_i / Σ u_ik^m,
//   snapped to the nearest sample of its component (lowest id on ties; a sample already
//   taken by a lower cluster index is skipped); distances recomputed from the new
//   centres. Stops when no membership changes by more than `tolerance`, when the centres
//   stop moving, or after `max_iterations`.
// - Labels: argmax membership (lowest cluster index on ties), i.e. the geodesically
//   nearest centre, so each cluster of a connected graph is connected.
// - Deterministic for any thread count: every sum runs in sample order.
// - Cost: per iteration C Dijkstra runs (parallel over clusters) plus O(N·C);
//   memory 8·N·C bytes (float distances and memberships).
#include <cstdint>
#include <span>
#include <vector>

#include "nodes/partition/proximity_graph.hpp"

namespace qemflow::nodes::partition {

struct ClusterOptions {
  uint32_t clusters = 8;
  double fuzziness = 2.0;     // m > 1
  double tolerance = 1e-3;    // on memberships
  uint32_t max_iterations = 50;
};

struct Clustering {
  std::vector<uint32_t> labels;   // cluster per sample
  std::vector<uint32_t> centres;  // sample id of each cluster's centre
  uint32_t iterations = 0;
  double last_change = 0;         // largest membership change in the last iteration
};

Clustering cluster_samples(std::span<const SurfaceSample> samples, const ProximityGraph& graph,
                           const ClusterOptions& options);

// Shortest-path distances over the graph from `source` (+inf where unreachable).
void graph_distances(const ProximityGraph& graph, uint32_t source, std::span<double> distances);

}  // namespace qemflow::nodes::partition
