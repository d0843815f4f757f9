#include "nodes/partition/fuzzy_clusterer.hpp"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>

#include "util/error.hpp"

namespace qemflow::nodes::partition {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// How many clusters each component gets: D'Hondt over sample counts, never more
// clusters than samples in a component.
std::vector<uint32_t> share_clusters(const std::vector<uint64_t>& component_sizes, uint32_t clusters) {
  std::vector<uint32_t> share(component_sizes.size(), 0);
  for (uint32_t given = 0; given < clusters; ++given) {
    size_t best = component_sizes.size();
    double best_quotient = -1;
    for (size_t c = 0; c < component_sizes.size(); ++c) {
      if (share[c] >= component_sizes[c]) continue;
      const double quotient = static_cast<double>(component_sizes[c]) / (share[c] + 1.0);
      if (quotient > best_quotient) {
        best_quotient = quotient;
        best = c;
      }
    }
    ++share[best];
  }
  return share;
}

// argmax over `members` of distance (finite only), lowest id on ties.
uint32_t farthest(const std::vector<uint32_t>& members, const std::vector<double>& distance) {
  uint32_t best = members.front();
  double best_distance = -1;
  for (uint32_t i : members)
    if (std::isfinite(distance[i]) && distance[i] > best_distance) {
      best_distance = distance[i];
      best = i;
    }
  return best;
}

std::vector<uint32_t> seed_centres(const ProximityGraph& graph, uint32_t clusters,
                                   const std::vector<uint32_t>& component) {
  uint32_t component_count = 0;
  for (uint32_t c : component) component_count = std::max(component_count, c + 1);
  std::vector<std::vector<uint32_t>> members(component_count);
  for (uint32_t i = 0; i < component.size(); ++i) members[component[i]].push_back(i);
  std::vector<uint64_t> sizes(component_count);
  for (uint32_t c = 0; c < component_count; ++c) sizes[c] = members[c].size();
  const std::vector<uint32_t> share = share_clusters(sizes, clusters);

  std::vector<uint32_t> centres;
  std::vector<double> nearest_seed(graph.size(), kInfinity);
  std::vector<double> scratch(graph.size());
  for (uint32_t c = 0; c < component_count; ++c) {
    if (share[c] == 0) continue;
    graph_distances(graph, members[c].front(), scratch);
    uint32_t seed = farthest(members[c], scratch);
    for (uint32_t taken = 0; taken < share[c]; ++taken) {
      centres.push_back(seed);
      graph_distances(graph, seed, scratch);
      for (uint32_t i : members[c]) nearest_seed[i] = std::min(nearest_seed[i], scratch[i]);
      seed = farthest(members[c], nearest_seed);
    }
  }
  return centres;
}

struct FuzzyState {
  uint32_t samples = 0;
  uint32_t clusters = 0;
  std::vector<float> distance;    // cluster-major: distance[k * samples + i]
  std::vector<float> membership;  // sample-major: membership[i * clusters + k]
};

void distances_from_centres(const ProximityGraph& graph, const std::vector<uint32_t>& centres,
                            FuzzyState& state) {
  tbb::parallel_for(uint32_t{0}, state.clusters, [&](uint32_t k) {
    std::vector<double> column(state.samples);
    graph_distances(graph, centres[k], column);
    float* out = state.distance.data() + static_cast<size_t>(k) * state.samples;
    for (uint32_t i = 0; i < state.samples; ++i) out[i] = static_cast<float>(column[i]);
  });
}

// Memberships from the current distances; returns the largest change.
double update_memberships(std::span<const SurfaceSample> samples, const std::vector<uint32_t>& centres,
                          double exponent, FuzzyState& state) {
  return tbb::parallel_reduce(
      tbb::blocked_range<uint32_t>(0, state.samples), 0.0,
      [&](const tbb::blocked_range<uint32_t>& range, double change) {
        std::vector<double> d(state.clusters);
        for (uint32_t i = range.begin(); i < range.end(); ++i) {
          bool reachable = false;
          for (uint32_t k = 0; k < state.clusters; ++k) {
            d[k] = state.distance[static_cast<size_t>(k) * state.samples + i];
            reachable = reachable || std::isfinite(d[k]);
          }
          if (!reachable)  // an orphan: Euclidean distances to the centres
            for (uint32_t k = 0; k < state.clusters; ++k)
              d[k] = std::sqrt(squared_distance(samples[i].position, samples[centres[k]].position));
          float* u = state.membership.data() + static_cast<size_t>(i) * state.clusters;
          const auto at_centre = std::find(d.begin(), d.end(), 0.0);
          double total = 0;
          for (uint32_t k = 0; k < state.clusters; ++k) total += std::isfinite(d[k]) ? std::pow(d[k], -exponent) : 0.0;
          for (uint32_t k = 0; k < state.clusters; ++k) {
            double value;
            if (at_centre != d.end()) value = (at_centre - d.begin()) == k ? 1.0 : 0.0;
            else value = std::isfinite(d[k]) ? std::pow(d[k], -exponent) / total : 0.0;
            change = std::max(change, std::abs(value - static_cast<double>(u[k])));
            u[k] = static_cast<float>(value);
          }
        }
        return change;
      },
      [](double a, double b) { return std::max(a, b); });
}

// New centres: weighted barycenters snapped to the nearest sample reachable from the
// old centre, lower cluster indices choosing first.
std::vector<uint32_t> move_centres(std::span<const SurfaceSample> samples, double fuzziness,
                                   const FuzzyState& state) {
  std::vector<Point> barycenter(state.clusters);
  tbb::parallel_for(uint32_t{0}, state.clusters, [&](uint32_t k) {
    const float* d = state.distance.data() + static_cast<size_t>(k) * state.samples;
    Point sum{0, 0, 0};
    double weight = 0;
    for (uint32_t i = 0; i < state.samples; ++i) {
      if (!std::isfinite(d[i])) continue;
      const double w = std::pow(static_cast<double>(state.membership[static_cast<size_t>(i) * state.clusters + k]), fuzziness);
      sum = add(sum, scale(samples[i].position, w));
      weight += w;
    }
    barycenter[k] = weight > 0 ? scale(sum, 1.0 / weight) : sum;
  });
  std::vector<uint32_t> centres(state.clusters);
  std::vector<char> taken(state.samples, 0);
  for (uint32_t k = 0; k < state.clusters; ++k) {
    const float* d = state.distance.data() + static_cast<size_t>(k) * state.samples;
    uint32_t best = UINT32_MAX;
    double best_distance = kInfinity;
    for (uint32_t i = 0; i < state.samples; ++i) {
      if (!std::isfinite(d[i]) || taken[i]) continue;
      const double distance = squared_distance(samples[i].position, barycenter[k]);
      if (distance < best_distance) {
        best_distance = distance;
        best = i;
      }
    }
    centres[k] = best;
    taken[best] = 1;
  }
  return centres;
}

}  // namespace

void graph_distances(const ProximityGraph& graph, uint32_t source, std::span<double> distances) {
  std::fill(distances.begin(), distances.end(), kInfinity);
  using Entry = std::pair<double, uint32_t>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<>> frontier;
  distances[source] = 0;
  frontier.emplace(0.0, source);
  while (!frontier.empty()) {
    const auto [distance, v] = frontier.top();
    frontier.pop();
    if (distance > distances[v]) continue;
    const auto neighbours = graph.neighbours_of(v);
    const auto lengths = graph.lengths_of(v);
    for (size_t e = 0; e < neighbours.size(); ++e) {
      const double through = distance + lengths[e];
      if (through < distances[neighbours[e]]) {
        distances[neighbours[e]] = through;
        frontier.emplace(through, neighbours[e]);
      }
    }
  }
}

Clustering cluster_samples(std::span<const SurfaceSample> samples, const ProximityGraph& graph,
                           const ClusterOptions& options) {
  if (options.clusters == 0 || options.clusters > samples.size())
    throw Error(ErrorKind::internal, "cluster_samples: need 1 ≤ clusters ≤ samples");
  if (!(options.fuzziness > 1)) throw Error(ErrorKind::internal, "cluster_samples: fuzziness must be > 1");
  if (graph.size() != samples.size()) throw Error(ErrorKind::internal, "cluster_samples: graph/sample mismatch");

  FuzzyState state;
  state.samples = static_cast<uint32_t>(samples.size());
  state.clusters = options.clusters;
  state.distance.resize(static_cast<size_t>(state.samples) * state.clusters);
  state.membership.assign(static_cast<size_t>(state.samples) * state.clusters, 0.0f);
  const double exponent = 2.0 / (options.fuzziness - 1.0);

  Clustering result;
  result.centres = seed_centres(graph, options.clusters, connected_components(graph));
  for (;;) {
    distances_from_centres(graph, result.centres, state);
    result.last_change = update_memberships(samples, result.centres, exponent, state);
    ++result.iterations;
    if (result.iterations > 1 && result.last_change < options.tolerance) break;
    if (result.iterations >= options.max_iterations) break;
    std::vector<uint32_t> moved = move_centres(samples, options.fuzziness, state);
    if (moved == result.centres) break;
    result.centres = std::move(moved);
  }

  result.labels.resize(state.samples);
  for (uint32_t i = 0; i < state.samples; ++i) {
    const float* u = state.membership.data() + static_cast<size_t>(i) * state.clusters;
    result.labels[i] = static_cast<uint32_t>(std::max_element(u, u + state.clusters) - u);
  }
  return result;
}

}  // namespace qemflow::nodes::partition
