#include "nodes/weld.hpp"

#include <tbb/parallel_sort.h>

#include <numeric>

namespace qemflow::nodes {

std::vector<uint64_t> weld_representatives(std::span<const Point> points) {
  std::vector<uint64_t> order(points.size());
  std::iota(order.begin(), order.end(), uint64_t{0});
  // (position, index) is a strict total order, so the sorted order is unique.
  auto normalized = [](double x) { return x == 0.0 ? 0.0 : x; };
  tbb::parallel_sort(order.begin(), order.end(), [&](uint64_t a, uint64_t b) {
    for (int k = 0; k < 3; ++k) {
      const double x = normalized(points[a][k]), y = normalized(points[b][k]);
      if (x != y) return x < y;
    }
    return a < b;
  });
  std::vector<uint64_t> representative(points.size());
  for (size_t i = 0; i < order.size(); ++i) {
    const bool same = i > 0 && points[order[i]][0] == points[order[i - 1]][0] &&
                      points[order[i]][1] == points[order[i - 1]][1] &&
                      points[order[i]][2] == points[order[i - 1]][2];
    representative[order[i]] = same ? representative[order[i - 1]] : order[i];
  }
  return representative;
}

}  // namespace qemflow::nodes
