#pragma once
// Proximity graph on surface samples (paper §4.3): an edge joins two samples whose
// chord is shorter than reach × radius (the sampler's grid, with cells of that edge)
// and whose approximate geodesic distance (approx_geodesic) is finite, i.e. they
// lie on the same sheet. The edge length is that geodesic distance.
//
// Contract
// - Compressed rows: neighbours of sample i are neighbours[offsets[i] .. offsets[i+1]),
//   sorted by id, with lengths[] beside them. The graph is symmetric, with no self loops
//   and no duplicates; lengths are the same in both directions to the bit.
// - Deterministic for any thread count (rows are built independently, in parallel).
// - Cost: O(samples × neighbours-per-27-cells); memory 12 bytes per directed edge.
#include <cstdint>
#include <span>
#include <vector>

#include "nodes/partition/surface_sampler.hpp"

namespace qemflow::nodes::partition {

struct ProximityGraph {
  std::vector<uint64_t> offsets;     // samples + 1 entries
  std::vector<uint32_t> neighbours;
  std::vector<double> lengths;       // approximate geodesic length of each edge

  size_t size() const { return offsets.empty() ? 0 : offsets.size() - 1; }
  std::span<const uint32_t> neighbours_of(uint32_t i) const {
    return {neighbours.data() + offsets[i], neighbours.data() + offsets[i + 1]};
  }
  std::span<const double> lengths_of(uint32_t i) const {
    return {lengths.data() + offsets[i], lengths.data() + offsets[i + 1]};
  }
};

struct ProximityOptions {
  double reach = 2.0;  // edges up to reach × radius (chord)
  SheetLimits sheets{};
};

ProximityGraph build_proximity_graph(std::span<const SurfaceSample> samples, double radius,
                                     const ProximityOptions& options = {});

// Connected components: component id per sample, numbered by their lowest sample id.
std::vector<uint32_t> connected_components(const ProximityGraph& graph);

}  // namespace qemflow::nodes::partition
