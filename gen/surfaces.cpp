#include "gen/surfaces.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "gen/noise.hpp"

namespace qemflow::gen::detail {
namespace {

using noise::derive;
using noise::hash;
using noise::signed_unit;

// Jitter in lattice units. With corners moved at most J per axis, every corner
// triangle of a unit quad keeps a signed area of at least (1-2J)^2 - 2J(1+2J) = 0.28
// (in units of the cell area) for either diagonal, so quads stay strictly convex.
constexpr double kJitter = 0.12;
// Per-vertex "sensor" noise along the normal, in cell sizes.
constexpr double kScanNoise = 0.05;

enum Purpose : uint64_t { jitter_x, jitter_y, jitter_z, scan, shape_noise, detail_noise, warp_noise };

struct LatticePoint {
  double x, y, z;
};

// Octaves of a detail layer whose first octave has `base_frequency` (per unit
// length): enough that the finest wavelength spans about six cells, at most eight.
int detail_octaves(double cells_per_unit, double base_frequency) {
  int octaves = 1;
  double wavelength_cells = cells_per_unit / base_frequency;
  while (octaves < 8 && wavelength_cells / 2 >= 6) {
    ++octaves;
    wavelength_cells /= 2;
  }
  return octaves;
}

Point normalised(double x, double y, double z) {
  const double length = std::sqrt(x * x + y * y + z * z);
  return {x / length, y / length, z / length};
}

// ---------------------------------------------------------------------------------
// Box lattice: the surface of an A x B x C box of unit cells. Vertex rows: the bottom
// cap (z = 0) row by row in y, then one ring of 2A+2B vertices per interior z level,
// then the top cap (z = C) row by row. Quad rows: the six sides, each row by row.
class BoxSurface : public Surface {
 public:
  BoxSurface(uint64_t a, uint64_t b, uint64_t c, uint64_t seed) : size_{a, b, c} {
    for (int axis = 0; axis < 3; ++axis) jitter_seed_[axis] = derive(seed, jitter_x + axis);
    cap_ = (a + 1) * (b + 1);
    ring_ = 2 * a + 2 * b;
    // {fixed axis, its value, s axis, t axis}; e_s x e_t points outward on every side.
    const int layout[6][4] = {{2, 0, 1, 0}, {2, 1, 0, 1}, {1, 0, 0, 2},
                              {1, 1, 2, 0}, {0, 0, 2, 1}, {0, 1, 1, 2}};
    uint64_t first_quad = 0, first_row = 0;
    for (int f = 0; f < 6; ++f) {
      Side& side = sides_[f];
      side.fixed = layout[f][0];
      side.fixed_value = layout[f][1] ? size_[side.fixed] : 0;
      side.s_axis = layout[f][2];
      side.t_axis = layout[f][3];
      side.s_count = size_[side.s_axis];
      side.t_count = size_[side.t_axis];
      side.first_quad = first_quad;
      side.first_row = first_row;
      first_quad += side.s_count * side.t_count;
      first_row += side.t_count;
    }
    quads_ = first_quad;
    quad_rows_ = first_row;
  }

  uint64_t lattice_vertex_count() const override { return 2 * cap_ + (size_[2] - 1) * ring_; }
  uint64_t quad_count() const override { return quads_; }
  int euler_characteristic() const override { return 2; }

  uint64_t vertex_rows() const override { return 2 * (size_[1] + 1) + size_[2] - 1; }
  uint64_t vertex_row_first(uint64_t row) const override {
    const uint64_t b = size_[1], c = size_[2];
    if (row <= b + 1) return row * (size_[0] + 1);
    if (row <= b + c) return cap_ + (row - b - 1) * ring_;
    return cap_ + (c - 1) * ring_ + (row - b - c) * (size_[0] + 1);
  }
  void vertex_row(uint64_t row, Point* out) const override {
    const uint64_t a = size_[0], b = size_[1], c = size_[2];
    uint64_t id = vertex_row_first(row);
    if (row <= b || row >= b + c) {
      const uint64_t k = row <= b ? 0 : c, j = row <= b ? row : row - b - c;
      for (uint64_t i = 0; i <= a; ++i, ++id) *out++ = place(jittered({i, j, k}), id);
      return;
    }
    const uint64_t k = row - b;
    for (uint64_t p = 0; p < ring_; ++p, ++id) *out++ = place(jittered(ring_position(p, k)), id);
  }

  uint64_t quad_rows() const override { return quad_rows_; }
  uint64_t quad_row_first(uint64_t row) const override {
    if (row >= quad_rows_) return quads_;
    const Side& side = side_of_row(row);
    return side.first_quad + (row - side.first_row) * side.s_count;
  }
  void quad_corners(uint64_t quad, uint64_t corners[4]) const override {
    uint64_t lattice[4][3];
    quad_lattice(quad, lattice);
    for (int c = 0; c < 4; ++c) corners[c] = vertex_id(lattice[c]);
  }
  Point quad_centre(uint64_t quad, uint64_t id) const override {
    uint64_t lattice[4][3];
    quad_lattice(quad, lattice);
    LatticePoint mean{0, 0, 0};
    for (auto& corner : lattice) {
      const LatticePoint p = jittered({corner[0], corner[1], corner[2]});
      mean.x += p.x / 4;
      mean.y += p.y / 4;
      mean.z += p.z / 4;
    }
    return place(mean, id);
  }

 protected:
  virtual Point place(const LatticePoint& p, uint64_t id) const = 0;
  uint64_t size_[3];

 private:
  struct Side {
    int fixed, s_axis, t_axis;
    uint64_t fixed_value, s_count, t_count, first_quad, first_row;
  };
  struct Index {
    uint64_t i, j, k;
  };

  const Side& side_of_row(uint64_t row) const {
    int f = 5;
    while (sides_[f].first_row > row) --f;
    return sides_[f];
  }
  const Side& side_of_quad(uint64_t quad) const {
    int f = 5;
    while (sides_[f].first_quad > quad) --f;
    return sides_[f];
  }
  // Corners (s,t), (s+1,t), (s+1,t+1), (s,t+1) of a quad, as lattice indices.
  void quad_lattice(uint64_t quad, uint64_t lattice[4][3]) const {
    const Side& side = side_of_quad(quad);
    const uint64_t local = quad - side.first_quad;
    const uint64_t s = local % side.s_count, t = local / side.s_count;
    const uint64_t ds[4] = {0, 1, 1, 0}, dt[4] = {0, 0, 1, 1};
    for (int c = 0; c < 4; ++c) {
      lattice[c][side.fixed] = side.fixed_value;
      lattice[c][side.s_axis] = s + ds[c];
      lattice[c][side.t_axis] = t + dt[c];
    }
  }
  // The p-th vertex of a ring, walking the perimeter counter-clockwise from (0,0).
  Index ring_position(uint64_t p, uint64_t k) const {
    const uint64_t a = size_[0], b = size_[1];
    if (p < a) return {p, 0, k};
    if (p < a + b) return {a, p - a, k};
    if (p < 2 * a + b) return {a - (p - a - b), b, k};
    return {0, b - (p - 2 * a - b), k};
  }
  uint64_t vertex_id(const uint64_t ijk[3]) const {
    const uint64_t a = size_[0], b = size_[1], c = size_[2];
    const uint64_t i = ijk[0], j = ijk[1], k = ijk[2];
    if (k == 0) return j * (a + 1) + i;
    if (k == c) return cap_ + (c - 1) * ring_ + j * (a + 1) + i;
    uint64_t p;
    if (j == 0) p = i;
    else if (i == a) p = a + j;
    else if (j == b) p = a + b + (a - i);
    else p = 2 * a + b + (b - j);
    return cap_ + (k - 1) * ring_ + p;
  }
  // Moves a vertex along every axis on which it is not on the box's boundary, so
  // vertices on box edges slide along the edge and box corners stay put.
  LatticePoint jittered(Index v) const {
    const uint64_t index[3] = {v.i, v.j, v.k};
    double out[3];
    for (int axis = 0; axis < 3; ++axis) {
      out[axis] = static_cast<double>(index[axis]);
      if (index[axis] != 0 && index[axis] != size_[axis]) {
        out[axis] += kJitter * signed_unit(hash(jitter_seed_[axis], static_cast<int64_t>(v.i),
                                                static_cast<int64_t>(v.j), static_cast<int64_t>(v.k)));
      }
    }
    return {out[0], out[1], out[2]};
  }

  uint64_t cap_ = 0, ring_ = 0, quads_ = 0, quad_rows_ = 0;
  uint64_t jitter_seed_[3];
  Side sides_[6];
};

// ---------------------------------------------------------------------------------
// blob: a cube-sphere (equal-angle cube map) displaced radially by multi-octave
// gradient noise, then stretched. Radial displacement of a sphere keeps the surface
// star-shaped around the origin, so it can neither self-intersect nor flip a face.
class BlobSurface final : public BoxSurface {
 public:
  BlobSurface(uint64_t n, uint64_t seed)
      : BoxSurface(n, n, n, seed),
        n_(static_cast<double>(n)),
        shape_seed_(derive(seed, shape_noise)),
        detail_seed_(derive(seed, detail_noise)),
        scan_seed_(derive(seed, scan)) {
    const double cells_per_unit = 4 * n_ / (2 * std::numbers::pi);
    detail_octaves_ = detail_octaves(cells_per_unit, 5.0);
    scan_amplitude_ = kScanNoise / cells_per_unit;
  }
  std::string layout() const override {
    const auto n = std::to_string(size_[0]);
    return "cube-sphere, 6 grids of " + n + "x" + n;
  }

 private:
  Point place(const LatticePoint& p, uint64_t id) const override {
    constexpr double quarter_pi = std::numbers::pi / 4;
    const Point d = normalised(std::tan((2 * p.x / n_ - 1) * quarter_pi),
                               std::tan((2 * p.y / n_ - 1) * quarter_pi),
                               std::tan((2 * p.z / n_ - 1) * quarter_pi));
    const double lumps = noise::fbm(shape_seed_, 1.1 * d[0], 1.1 * d[1], 1.1 * d[2], 4);
    const double detail = noise::fbm(detail_seed_, 5 * d[0], 5 * d[1], 5 * d[2], detail_octaves_);
    const double grain = signed_unit(hash(scan_seed_, static_cast<int64_t>(id)));
    const double r = 1.0 + 0.38 * lumps + 0.035 * detail + scan_amplitude_ * grain;
    return {1.15 * r * d[0], 0.95 * r * d[1], 0.85 * r * d[2]};
  }

  double n_;
  uint64_t shape_seed_, detail_seed_, scan_seed_;
  int detail_octaves_ = 1;
  double scan_amplitude_ = 0;
};

// ---------------------------------------------------------------------------------
// terrain: a closed slab over [-1,1]^2 — a ridged-noise heightfield on top, a flat
// bottom at z = 0, and four walls whose rows interpolate between the two. Every
// vertical line meets the top once, so the slab cannot self-intersect.
class TerrainSurface final : public BoxSurface {
 public:
  TerrainSurface(uint64_t m, uint64_t walls, uint64_t seed)
      : BoxSurface(m, m, walls, seed),
        m_(static_cast<double>(m)),
        walls_(static_cast<double>(walls)),
        shape_seed_(derive(seed, shape_noise)),
        detail_seed_(derive(seed, detail_noise)),
        warp_seed_(derive(seed, warp_noise)),
        scan_seed_(derive(seed, scan)) {
    const double cells_per_unit = m_ / 2;
    ridge_octaves_ = std::max(4, detail_octaves(cells_per_unit, 1.4));
    detail_octaves_ = detail_octaves(cells_per_unit, 6.0);
    scan_amplitude_ = kScanNoise / cells_per_unit;
  }
  std::string layout() const override {
    return "slab, " + std::to_string(size_[0]) + "x" + std::to_string(size_[1]) + " top and bottom, walls " +
           std::to_string(size_[2]) + " high";
  }

 private:
  Point place(const LatticePoint& p, uint64_t id) const override {
    const double x = 2 * p.x / m_ - 1, y = 2 * p.y / m_ - 1;
    if (p.z == 0) return {x, y, 0};
    // A gentle domain warp bends the ridges so they do not follow the noise lattice.
    const double wx = x + 0.25 * noise::fbm(warp_seed_, 0.9 * x, 0.9 * y, 0.3, 3);
    const double wy = y + 0.25 * noise::fbm(warp_seed_, 0.9 * x + 5.2, 0.9 * y + 1.3, 0.7, 3);
    const double ridges = noise::ridged(shape_seed_, 1.2 * wx, 1.2 * wy, 0.5, ridge_octaves_);
    const double hills = noise::fbm(shape_seed_ + 99, 0.7 * x, 0.7 * y, 0.2, 3);
    const double detail = noise::fbm(detail_seed_, 6 * x, 6 * y, 0.5, detail_octaves_);
    const double grain = signed_unit(hash(scan_seed_, static_cast<int64_t>(id)));
    const double height = 0.3 + 0.04 * (x + 1) + 0.12 * hills + 0.3 * ridges + 0.012 * detail +
                          scan_amplitude_ * grain;
    return {x, y, height * p.z / walls_};
  }

  double m_, walls_;
  uint64_t shape_seed_, detail_seed_, warp_seed_, scan_seed_;
  int ridge_octaves_ = 4, detail_octaves_ = 1;
  double scan_amplitude_ = 0;
};

// ---------------------------------------------------------------------------------
// figure: a lumpy ring (genus 1) — a tube of varying, noisy radius around a wavy
// closed centre line, like a scanned ring sculpture. Grid of U (around the ring) by V
// (around the tube) vertices, row v holding ids v*U .. v*U+U-1. The tube radius stays
// below the centre line's smallest radius of curvature, so cross-sections never meet.
class FigureSurface final : public Surface {
 public:
  FigureSurface(uint64_t m, uint64_t seed)
      : u_count_(5 * m / 2),
        v_count_(m),
        jitter_u_(derive(seed, jitter_x)),
        jitter_v_(derive(seed, jitter_y)),
        shape_seed_(derive(seed, shape_noise)),
        detail_seed_(derive(seed, detail_noise)),
        scan_seed_(derive(seed, scan)) {
    const double cells_per_unit = static_cast<double>(u_count_) / (2 * std::numbers::pi);
    detail_octaves_ = detail_octaves(cells_per_unit, 6.0);
    scan_amplitude_ = kScanNoise / cells_per_unit;
  }
  std::string layout() const override {
    return "ring (genus 1), " + std::to_string(u_count_) + "x" + std::to_string(v_count_) + " grid";
  }
  int euler_characteristic() const override { return 0; }
  uint64_t lattice_vertex_count() const override { return u_count_ * v_count_; }
  uint64_t quad_count() const override { return u_count_ * v_count_; }

  uint64_t vertex_rows() const override { return v_count_; }
  uint64_t vertex_row_first(uint64_t row) const override { return row * u_count_; }
  void vertex_row(uint64_t row, Point* out) const override {
    for (uint64_t u = 0; u < u_count_; ++u) {
      const auto [x, y] = jittered(u, row);
      *out++ = place(x, y, row * u_count_ + u);
    }
  }

  uint64_t quad_rows() const override { return v_count_; }
  uint64_t quad_row_first(uint64_t row) const override { return row * u_count_; }
  void quad_corners(uint64_t quad, uint64_t corners[4]) const override {
    const uint64_t u = quad % u_count_, v = quad / u_count_;
    const uint64_t u1 = (u + 1) % u_count_, v1 = (v + 1) % v_count_;
    corners[0] = v * u_count_ + u;
    corners[1] = v * u_count_ + u1;
    corners[2] = v1 * u_count_ + u1;
    corners[3] = v1 * u_count_ + u;
  }
  Point quad_centre(uint64_t quad, uint64_t id) const override {
    const uint64_t u = quad % u_count_, v = quad / u_count_;
    double x = 0, y = 0;
    for (int c = 0; c < 4; ++c) {
      const uint64_t du = c == 1 || c == 2, dv = c >= 2;
      // Jitter is looked up at the wrapped index, but the coordinate is kept unwrapped
      // so the mean of a quad that crosses the seam is still inside it.
      auto [cx, cy] = jittered((u + du) % u_count_, (v + dv) % v_count_);
      x += (cx + (u + du == u_count_ ? static_cast<double>(u_count_) : 0)) / 4;
      y += (cy + (v + dv == v_count_ ? static_cast<double>(v_count_) : 0)) / 4;
    }
    return place(x, y, id);
  }

 private:
  std::pair<double, double> jittered(uint64_t u, uint64_t v) const {
    const auto iu = static_cast<int64_t>(u), iv = static_cast<int64_t>(v);
    return {static_cast<double>(u) + kJitter * signed_unit(hash(jitter_u_, iu, iv)),
            static_cast<double>(v) + kJitter * signed_unit(hash(jitter_v_, iu, iv))};
  }

  Point place(double gu, double gv, uint64_t id) const {
    constexpr double two_pi = 2 * std::numbers::pi;
    const double theta = two_pi * gu / static_cast<double>(u_count_);
    const double phi = two_pi * gv / static_cast<double>(v_count_);
    const double ct = std::cos(theta), st = std::sin(theta);
    const double cp = std::cos(phi), sp = std::sin(phi);
    // Centre line: radius 1 + a cos 3θ, height b sin 2θ.
    constexpr double a = 0.1, b = 0.25;
    const double radius = 1 + a * std::cos(3 * theta), dradius = -3 * a * std::sin(3 * theta);
    const Point centre{radius * ct, radius * st, b * std::sin(2 * theta)};
    const Point tangent = normalised(dradius * ct - radius * st, dradius * st + radius * ct,
                                     2 * b * std::cos(2 * theta));
    // Frame: N = the outward radial direction made normal to the tangent; B = N x T,
    // which keeps the standard torus orientation (outward normals).
    const double along = ct * tangent[0] + st * tangent[1];
    const Point normal = normalised(ct - along * tangent[0], st - along * tangent[1], -along * tangent[2]);
    const Point binormal{normal[1] * tangent[2] - normal[2] * tangent[1],
                         normal[2] * tangent[0] - normal[0] * tangent[2],
                         normal[0] * tangent[1] - normal[1] * tangent[0]};
    // Noise is sampled on the undeformed torus, so it is seamless around both circles.
    const double bx = (1 + 0.35 * cp) * ct, by = (1 + 0.35 * cp) * st, bz = 0.35 * sp;
    const double lumps = noise::fbm(shape_seed_, 1.3 * bx, 1.3 * by, 1.3 * bz, 4);
    const double detail = noise::fbm(detail_seed_, 6 * bx, 6 * by, 6 * bz, detail_octaves_);
    const double grain = signed_unit(hash(scan_seed_, static_cast<int64_t>(id)));
    const double tube = 0.33 * (1 + 0.4 * lumps + 0.06 * detail) + scan_amplitude_ * grain;
    return {centre[0] + tube * (cp * normal[0] + sp * binormal[0]),
            centre[1] + tube * (cp * normal[1] + sp * binormal[1]),
            centre[2] + tube * (cp * normal[2] + sp * binormal[2])};
  }

  uint64_t u_count_, v_count_;
  uint64_t jitter_u_, jitter_v_, shape_seed_, detail_seed_, scan_seed_;
  int detail_octaves_ = 1;
  double scan_amplitude_ = 0;
};

uint64_t terrain_walls(uint64_t m) { return std::max<uint64_t>(1, m / 6); }

}  // namespace

uint64_t blob_quads(uint64_t m) { return 6 * m * m; }
uint64_t terrain_quads(uint64_t m) { return 2 * (m * m + 2 * m * terrain_walls(m)); }
uint64_t figure_quads(uint64_t m) { return (5 * m / 2) * m; }

std::unique_ptr<Surface> make_blob(uint64_t m, uint64_t seed) { return std::make_unique<BlobSurface>(m, seed); }
std::unique_ptr<Surface> make_terrain(uint64_t m, uint64_t seed) {
  return std::make_unique<TerrainSurface>(m, terrain_walls(m), seed);
}
std::unique_ptr<Surface> make_figure(uint64_t m, uint64_t seed) {
  return std::make_unique<FigureSurface>(m, seed);
}

}  // namespace qemflow::gen::detail
