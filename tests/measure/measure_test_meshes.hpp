#pragma once
// Small analytic meshes for the measure tests.
#include <array>
#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include "util/geometry.hpp"

namespace qemflow::measure::testing {

struct TestMesh {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};

// Icosahedron subdivided `levels` times, vertices on the sphere of radius `radius`,
// outward winding.
inline TestMesh icosphere(int levels, double radius = 1.0) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  TestMesh m;
  m.points = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
              {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  m.triangles = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                 {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
                 {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
  auto project = [](Point p) {
    const double n = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    return Point{p[0] / n, p[1] / n, p[2] / n};
  };
  for (auto& p : m.points) p = project(p);
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<uint64_t, uint64_t>, uint64_t> midpoint;
    auto mid = [&](uint64_t a, uint64_t b) {
      auto key = std::minmax(a, b);
      auto it = midpoint.find(key);
      if (it != midpoint.end()) return it->second;
      const Point& p = m.points[a];
      const Point& q = m.points[b];
      m.points.push_back(project({(p[0] + q[0]) / 2, (p[1] + q[1]) / 2, (p[2] + q[2]) / 2}));
      return midpoint[key] = m.points.size() - 1;
    };
    std::vector<Triangle> next;
    for (const auto& f : m.triangles) {
      const uint64_t a = mid(f[0], f[1]), b = mid(f[1], f[2]), c = mid(f[2], f[0]);
      next.push_back({f[0], a, c});
      next.push_back({f[1], b, a});
      next.push_back({f[2], c, b});
      next.push_back({a, b, c});
    }
    m.triangles = std::move(next);
  }
  for (auto& p : m.points) p = {p[0] * radius, p[1] * radius, p[2] * radius};
  return m;
}

// The square [0,size]^2 at height z, as an n x n grid of quads split in two, facing +z.
// `height(x, y)` may bend it (default flat).
template <class Height>
TestMesh grid(int n, double size, Height height) {
  TestMesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) {
      const double x = size * i / n, y = size * j / n;
      m.points.push_back({x, y, height(x, y)});
    }
  auto at = [&](int i, int j) { return static_cast<uint64_t>(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      m.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  return m;
}
inline TestMesh square(int n, double size, double z) {
  return grid(n, size, [z](double, double) { return z; });
}

// Axis-aligned cube [0,1]^3 + offset, 12 triangles, outward winding.
inline TestMesh cube(Point offset = {0, 0, 0}) {
  TestMesh m;
  for (int i = 0; i < 8; ++i)
    m.points.push_back({double(i & 1) + offset[0], double(i >> 1 & 1) + offset[1], double(i >> 2 & 1) + offset[2]});
  m.triangles = {{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},
                 {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
  return m;
}

}  // namespace qemflow::measure::testing
