#include "nodes/partition/proximity_graph.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "util/error.hpp"

namespace qemflow::nodes::partition {
namespace {

// Samples bucketed by grid cell: the ids of cell c are ids[ranges[r].first ..
// ranges[r].second) with r = range_of.find(c).
struct CellIndex {
  std::vector<uint32_t> ids;
  std::vector<std::pair<uint32_t, uint32_t>> ranges;
  CellMap range_of;
};

CellIndex bucket_by_cell(std::span<const SurfaceSample> samples, double inverse_cell) {
  std::vector<Cell> cells(samples.size());
  for (size_t i = 0; i < samples.size(); ++i) cells[i] = cell_of(samples[i].position, inverse_cell);
  CellIndex index;
  index.ids.resize(samples.size());
  std::iota(index.ids.begin(), index.ids.end(), 0u);
  std::sort(index.ids.begin(), index.ids.end(), [&](uint32_t a, uint32_t b) {
    return cells[a] != cells[b] ? cells[a] < cells[b] : a < b;
  });
  for (uint32_t begin = 0; begin < index.ids.size();) {
    uint32_t end = begin + 1;
    while (end < index.ids.size() && cells[index.ids[end]] == cells[index.ids[begin]]) ++end;
    index.range_of.insert(cells[index.ids[begin]], static_cast<uint32_t>(index.ranges.size()));
    index.ranges.emplace_back(begin, end);
    begin = end;
  }
  return index;
}

}  // namespace

ProximityGraph build_proximity_graph(std::span<const SurfaceSample> samples, double radius,
                                     const ProximityOptions& options) {
  if (!(radius > 0) || !(options.reach > 0))
    throw Error(ErrorKind::internal, "build_proximity_graph: radius and reach must be > 0");
  if (samples.size() >= UINT32_MAX) throw Error(ErrorKind::internal, "build_proximity_graph: too many samples");
  const double reach = options.reach * radius;
  const double reach_squared = reach * reach;
  const CellIndex index = bucket_by_cell(samples, 1.0 / reach);

  // Each row is found independently, so rows can be built in any order.
  std::vector<std::vector<std::pair<uint32_t, double>>> rows(samples.size());
  tbb::parallel_for(size_t{0}, samples.size(), [&](size_t i) {
    const SurfaceSample& p = samples[i];
    auto& row = rows[i];
    for_each_neighbour_cell(cell_of(p.position, 1.0 / reach), [&](const Cell& cell) {
      const uint32_t found = index.range_of.find(cell);
      if (found == CellMap::absent) return;
      for (uint32_t at = index.ranges[found].first; at < index.ranges[found].second; ++at) {
        const uint32_t j = index.ids[at];
        if (j == i) continue;
        const SurfaceSample& q = samples[j];
        if (squared_distance(p.position, q.position) >= reach_squared) continue;
        const double length = approx_geodesic(p.position, p.normal, q.position, q.normal, options.sheets);
        if (std::isfinite(length)) row.emplace_back(j, length);
      }
    });
    std::sort(row.begin(), row.end());
  });

  ProximityGraph graph;
  graph.offsets.resize(samples.size() + 1, 0);
  for (size_t i = 0; i < samples.size(); ++i) graph.offsets[i + 1] = graph.offsets[i] + rows[i].size();
  graph.neighbours.resize(graph.offsets.back());
  graph.lengths.resize(graph.offsets.back());
  for (size_t i = 0; i < samples.size(); ++i) {
    uint64_t at = graph.offsets[i];
    for (const auto& [j, length] : rows[i]) {
      graph.neighbours[at] = j;
      graph.lengths[at++] = length;
    }
  }
  return graph;
}

std::vector<uint32_t> connected_components(const ProximityGraph& graph) {
  constexpr uint32_t unset = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> component(graph.size(), unset);
  std::vector<uint32_t> stack;
  uint32_t next_id = 0;
  for (uint32_t start = 0; start < graph.size(); ++start) {
    if (component[start] != unset) continue;
    component[start] = next_id;
    stack.push_back(start);
    while (!stack.empty()) {
      const uint32_t v = stack.back();
      stack.pop_back();
      for (uint32_t w : graph.neighbours_of(v))
        if (component[w] == unset) {
          component[w] = next_id;
          stack.push_back(w);
        }
    }
    ++next_id;
  }
  return component;
}

}  // namespace qemflow::nodes::partition
