#pragma once
// The subdivided icosahedron that several suites' fixtures start from; each fixture
// then shapes it (radius, bumps, noise) its own way.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "util/geometry.hpp"

namespace qemflow::testing {

struct PointsAndTriangles {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};

inline Point unit_length(Point p) {
  const double l = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
  return {p[0] / l, p[1] / l, p[2] / l};
}

// Icosahedron (outward winding) split `levels` times into 20·4^levels faces. With
// `on_sphere`, the corners and every new midpoint are pushed onto the unit sphere
// (an even tessellation); without, midpoints stay on the flat faces of the
// icosahedron with its corners at distance sqrt(1 + golden²).
inline PointsAndTriangles subdivided_icosahedron(int levels, bool on_sphere) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  PointsAndTriangles m;
  m.points = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
              {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  m.triangles = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                 {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
                 {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
  if (on_sphere)
    for (auto& p : m.points) p = unit_length(p);
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<uint64_t, uint64_t>, uint64_t> midpoint;
    auto middle = [&](uint64_t a, uint64_t b) {
      auto [it, inserted] = midpoint.try_emplace(std::minmax(a, b), m.points.size());
      if (inserted) {
        const Point& p = m.points[a];
        const Point& q = m.points[b];
        const Point mid{(p[0] + q[0]) / 2, (p[1] + q[1]) / 2, (p[2] + q[2]) / 2};
        m.points.push_back(on_sphere ? unit_length(mid) : mid);
      }
      return it->second;
    };
    std::vector<Triangle> finer;
    finer.reserve(m.triangles.size() * 4);
    for (const auto& f : m.triangles) {
      const uint64_t ab = middle(f[0], f[1]), bc = middle(f[1], f[2]), ca = middle(f[2], f[0]);
      finer.push_back({f[0], ab, ca});
      finer.push_back({f[1], bc, ab});
      finer.push_back({f[2], ca, bc});
      finer.push_back({ab, bc, ca});
    }
    m.triangles = std::move(finer);
  }
  return m;
}

}  // namespace qemflow::testing
