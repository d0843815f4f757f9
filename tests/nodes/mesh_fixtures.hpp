#pragma once
// Small in-memory meshes and topology checks for the decimator tests.
#include <algorithm>
#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <vector>

#include "test_meshes.hpp"
#include "util/geometry.hpp"

namespace qemflow::testing {

struct Mesh {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
};

inline Mesh tetrahedron() {
  return {{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}}};
}

// n x n quads on [0,1]^2 at z = 0 (optionally noisy in z), split along alternating diagonals.
inline Mesh grid(int n, double noise = 0.0, uint32_t seed = 1) {
  Mesh m;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-noise, noise);
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.points.push_back({double(i) / n, double(j) / n, noise > 0 ? u(rng) : 0.0});
  auto id = [n](int i, int j) { return uint64_t(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      if ((i + j) % 2 == 0) {
        m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
        m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
      } else {
        m.triangles.push_back({id(i, j), id(i + 1, j), id(i, j + 1)});
        m.triangles.push_back({id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)});
      }
    }
  return m;
}

// Subdivided icosahedron on the unit sphere, radius optionally perturbed.
inline Mesh icosphere(int subdivisions, double noise = 0.0, uint32_t seed = 1) {
  auto [points, triangles] = subdivided_icosahedron(subdivisions, /*on_sphere=*/false);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-noise, noise);
  for (auto& p : points) {
    const double r = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) / (1.0 + u(rng));
    for (auto& x : p) x /= r;
  }
  return {std::move(points), std::move(triangles)};
}

struct Topology {
  uint64_t boundary_edges = 0, nonmanifold_edges = 0, misoriented_edges = 0;
  uint64_t degenerate_faces = 0;
};

inline Topology topology(const std::vector<Point>& points, const std::vector<Triangle>& tris,
                         double min_quality = 1e-12) {
  Topology t;
  std::map<std::pair<uint64_t, uint64_t>, std::pair<int, int>> edges;  // (count, direction sum)
  for (const auto& f : tris) {
    if (f[0] == f[1] || f[1] == f[2] || f[0] == f[2]) {
      ++t.degenerate_faces;
      continue;
    }
    const auto &p = points[f[0]], &q = points[f[1]], &r = points[f[2]];
    const double ux = q[0] - p[0], uy = q[1] - p[1], uz = q[2] - p[2];
    const double vx = r[0] - p[0], vy = r[1] - p[1], vz = r[2] - p[2];
    const double cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
    const double longest = std::max({ux * ux + uy * uy + uz * uz, vx * vx + vy * vy + vz * vz,
                                     (r[0] - q[0]) * (r[0] - q[0]) + (r[1] - q[1]) * (r[1] - q[1]) +
                                         (r[2] - q[2]) * (r[2] - q[2])});
    if (std::sqrt(cx * cx + cy * cy + cz * cz) <= min_quality * longest) ++t.degenerate_faces;
    for (int k = 0; k < 3; ++k) {
      const uint64_t a = f[k], b = f[(k + 1) % 3];
      auto& e = edges[std::minmax(a, b)];
      ++e.first;
      e.second += a < b ? 1 : -1;
    }
  }
  for (const auto& [key, e] : edges) {
    if (e.first == 1) ++t.boundary_edges;
    if (e.first > 2) ++t.nonmanifold_edges;
    if (e.first == 2 && e.second != 0) ++t.misoriented_edges;
  }
  return t;
}

// Faces whose normal points against `outward(centroid)`.
template <class Outward>
uint64_t count_flipped(const std::vector<Point>& points, const std::vector<Triangle>& tris,
                       Outward outward) {
  uint64_t flipped = 0;
  for (const auto& f : tris) {
    const auto &p = points[f[0]], &q = points[f[1]], &r = points[f[2]];
    const Point c{(p[0] + q[0] + r[0]) / 3, (p[1] + q[1] + r[1]) / 3, (p[2] + q[2] + r[2]) / 3};
    const double ux = q[0] - p[0], uy = q[1] - p[1], uz = q[2] - p[2];
    const double vx = r[0] - p[0], vy = r[1] - p[1], vz = r[2] - p[2];
    const Point n{uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx};
    const Point o = outward(c);
    if (n[0] * o[0] + n[1] * o[1] + n[2] * o[2] <= 0) ++flipped;
  }
  return flipped;
}

// Same triangles and bit-identical positions.
inline void expect_identical(const std::vector<Point>& a_points, const std::vector<Triangle>& a_tris,
                             const std::vector<Point>& b_points, const std::vector<Triangle>& b_tris) {
  ASSERT_EQ(a_tris, b_tris);
  ASSERT_EQ(a_points.size(), b_points.size());
  for (size_t i = 0; i < a_points.size(); ++i)
    for (int k = 0; k < 3; ++k)
      ASSERT_EQ(std::bit_cast<uint64_t>(a_points[i][k]), std::bit_cast<uint64_t>(b_points[i][k]));
}

}  // namespace qemflow::testing
