#pragma once
// Small analytic meshes for the measure tests.
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "test_meshes.hpp"
#include "util/geometry.hpp"

namespace qemflow::measure::testing {

struct TestMesh {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};

// Icosahedron subdivided `levels` times, vertices on the sphere of radius `radius`,
// outward winding.
inline TestMesh icosphere(int levels, double radius = 1.0) {
  auto [points, triangles] = qemflow::testing::subdivided_icosahedron(levels, /*on_sphere=*/true);
  for (auto& p : points) p = {p[0] * radius, p[1] * radius, p[2] * radius};
  return {std::move(points), std::move(triangles)};
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
