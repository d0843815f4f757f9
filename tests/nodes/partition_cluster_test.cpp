// Fuzzy C-Means on geodesic distances (nodes/partition/fuzzy_clusterer): connected,
// similar-sized clusters; components handled; identical with any thread count.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <numeric>

#include "nodes/partition/fuzzy_clusterer.hpp"
#include "nodes/partition_test_surfaces.hpp"

namespace qemflow::nodes::partition {
namespace {

struct Sampled {
  SampleSet set;
  ProximityGraph graph;
};

Sampled sample(const shapes::Surface& surface, uint64_t count) {
  Sampled s;
  s.set = sample_faces(shapes::positioned_faces(surface), count, 9);
  s.graph = build_proximity_graph(s.set.samples, s.set.radius);
  return s;
}

// Connected pieces of each cluster's induced subgraph.
std::vector<uint32_t> pieces_per_cluster(const ProximityGraph& graph, const std::vector<uint32_t>& labels,
                                         uint32_t clusters) {
  std::vector<uint32_t> pieces(clusters, 0);
  std::vector<char> seen(graph.size(), 0);
  std::vector<uint32_t> stack;
  for (uint32_t start = 0; start < graph.size(); ++start) {
    if (seen[start]) continue;
    ++pieces[labels[start]];
    seen[start] = 1;
    stack.push_back(start);
    while (!stack.empty()) {
      const uint32_t v = stack.back();
      stack.pop_back();
      for (uint32_t w : graph.neighbours_of(v))
        if (!seen[w] && labels[w] == labels[v]) {
          seen[w] = 1;
          stack.push_back(w);
        }
    }
  }
  return pieces;
}

double size_ratio(const std::vector<uint32_t>& labels, uint32_t clusters) {
  std::vector<size_t> size(clusters, 0);
  for (uint32_t l : labels) ++size[l];
  const auto [smallest, largest] = std::minmax_element(size.begin(), size.end());
  return *smallest == 0 ? INFINITY : static_cast<double>(*largest) / static_cast<double>(*smallest);
}

TEST(PartitionCluster, BumpySphereGivesConnectedEvenClusters) {
  const Sampled s = sample(shapes::icosphere(5, 0.15), 3000);
  for (uint32_t clusters : {4u, 8u, 16u}) {
    const Clustering c = cluster_samples(s.set.samples, s.graph, {.clusters = clusters});
    ASSERT_EQ(c.labels.size(), s.set.samples.size());
    for (uint32_t pieces : pieces_per_cluster(s.graph, c.labels, clusters)) EXPECT_EQ(pieces, 1u) << clusters;
    const double ratio = size_ratio(c.labels, clusters);
    EXPECT_LT(ratio, 2.0) << clusters;
    std::vector<uint32_t> centres = c.centres;
    std::sort(centres.begin(), centres.end());
    EXPECT_TRUE(std::adjacent_find(centres.begin(), centres.end()) == centres.end());
    for (uint32_t k = 0; k < clusters; ++k) EXPECT_EQ(c.labels[c.centres[k]], k);
    RecordProperty("ratio_" + std::to_string(clusters), std::to_string(ratio));
    RecordProperty("iterations_" + std::to_string(clusters), std::to_string(c.iterations));
  }
}

TEST(PartitionCluster, TorusClustersAreConnected) {
  const Sampled s = sample(shapes::torus(160, 60), 2500);
  for (uint32_t clusters : {3u, 8u}) {
    const Clustering c = cluster_samples(s.set.samples, s.graph, {.clusters = clusters});
    for (uint32_t pieces : pieces_per_cluster(s.graph, c.labels, clusters)) EXPECT_EQ(pieces, 1u) << clusters;
    EXPECT_LT(size_ratio(c.labels, clusters), 2.5) << clusters;
  }
}

// Two separate spheres, one twice the other's area: clusters shared 2:1, none spans both.
TEST(PartitionCluster, ComponentsShareClustersBySize) {
  shapes::Surface two = shapes::icosphere(4, 0.0, {1.4142, 1.4142, 1.4142});
  shapes::append(two, shapes::icosphere(4), {5, 0, 0});
  const Sampled s = sample(two, 1500);
  const auto component = connected_components(s.graph);
  ASSERT_EQ(*std::max_element(component.begin(), component.end()), 1u);
  const Clustering c = cluster_samples(s.set.samples, s.graph, {.clusters = 6});
  std::vector<std::array<size_t, 2>> where(6, {0, 0});
  for (size_t i = 0; i < c.labels.size(); ++i) ++where[c.labels[i]][component[i]];
  size_t on_big = 0;
  for (const auto& w : where) {
    EXPECT_TRUE(w[0] == 0 || w[1] == 0);
    on_big += w[0] > 0;
  }
  EXPECT_EQ(on_big, 4u);
}

TEST(PartitionCluster, SameLabelsWithAnyThreadCount) {
  const Sampled s = sample(shapes::icosphere(5, 0.15), 2500);
  Clustering one, two;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    one = cluster_samples(s.set.samples, s.graph, {.clusters = 8});
  }
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 4);
    two = cluster_samples(s.set.samples, s.graph, {.clusters = 8});
  }
  EXPECT_EQ(one.labels, two.labels);
  EXPECT_EQ(one.centres, two.centres);
  EXPECT_EQ(one.iterations, two.iterations);
}

TEST(PartitionCluster, DistancesFollowTheGraph) {
  const Sampled s = sample(shapes::icosphere(4), 800);
  std::vector<double> d(s.graph.size());
  graph_distances(s.graph, 0, d);
  EXPECT_EQ(d[0], 0.0);
  const double diameter = *std::max_element(d.begin(), d.end());
  // Unit sphere: the farthest sample is about π away; graph paths overestimate a little.
  EXPECT_GT(diameter, 3.0);
  EXPECT_LT(diameter, 3.0 * 1.15 + s.set.radius);
  // Triangle inequality along every edge.
  for (uint32_t i = 0; i < s.graph.size(); ++i)
    for (size_t e = 0; e < s.graph.neighbours_of(i).size(); ++e)
      EXPECT_LE(d[s.graph.neighbours_of(i)[e]], d[i] + s.graph.lengths_of(i)[e] + 1e-12);
}

}  // namespace
}  // namespace qemflow::nodes::partition
