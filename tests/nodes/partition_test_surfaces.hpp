#pragma once
// Small analytic closed surfaces for the partition tests, independent
// of the generator in gen/: a bumpy icosphere, a torus and a flattened (two-sheet)
// ellipsoid. All outward oriented, built from their parameters alone.
#include <array>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "nodes/partition/surface_sampler.hpp"
#include "test_meshes.hpp"

namespace qemflow::nodes::partition::shapes {

struct Surface {
  std::vector<Point> vertices;
  std::vector<Triangle> triangles;
};

// Icosahedron subdivided `levels` times (20·4^levels faces), projected on the unit
// sphere, then radius 1 + bump·sin(3x)sin(4y)sin(5z), then scaled per axis.
inline Surface icosphere(int levels, double bump = 0.0, Point axes = {1, 1, 1}) {
  auto [vertices, triangles] = testing::subdivided_icosahedron(levels, /*on_sphere=*/true);
  for (auto& v : vertices) {
    const double r = 1.0 + bump * std::sin(3 * v[0]) * std::sin(4 * v[1]) * std::sin(5 * v[2]);
    v = {v[0] * r * axes[0], v[1] * r * axes[1], v[2] * r * axes[2]};
  }
  return {std::move(vertices), std::move(triangles)};
}

// Torus around the z axis: `around` × `across` quads, two triangles each.
inline Surface torus(uint64_t around, uint64_t across, double major = 1.0, double minor = 0.35) {
  constexpr double two_pi = 6.283185307179586;
  Surface s;
  for (uint64_t i = 0; i < around; ++i)
    for (uint64_t j = 0; j < across; ++j) {
      const double u = two_pi * static_cast<double>(i) / static_cast<double>(around);
      const double v = two_pi * static_cast<double>(j) / static_cast<double>(across);
      const double ring = major + minor * std::cos(v);
      s.vertices.push_back({ring * std::cos(u), ring * std::sin(u), minor * std::sin(v)});
    }
  auto id = [&](uint64_t i, uint64_t j) { return (i % around) * across + (j % across); };
  for (uint64_t i = 0; i < around; ++i)
    for (uint64_t j = 0; j < across; ++j) {
      s.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      s.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  return s;
}

// Appends `other` moved by `offset` (two disjoint pieces in one mesh).
inline void append(Surface& s, const Surface& other, Point offset) {
  const uint64_t base = s.vertices.size();
  for (const auto& v : other.vertices) s.vertices.push_back({v[0] + offset[0], v[1] + offset[1], v[2] + offset[2]});
  for (const auto& f : other.triangles) s.triangles.push_back({f[0] + base, f[1] + base, f[2] + base});
}

// Faces with positions, face id = index.
inline std::vector<PositionedFace> positioned_faces(const Surface& s) {
  std::vector<PositionedFace> faces(s.triangles.size());
  for (size_t f = 0; f < faces.size(); ++f) {
    faces[f].id = f;
    for (int c = 0; c < 3; ++c) faces[f].corners[c] = s.vertices[s.triangles[f][c]];
  }
  return faces;
}

}  // namespace qemflow::nodes::partition::shapes
