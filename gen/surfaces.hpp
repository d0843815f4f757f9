#pragma once
// Internal to gen/: the closed quad grids behind the shapes, with vertex ids computed
// analytically so any row of vertices or quads can be produced on its own, in any
// order, on any thread, with no map from positions to ids.
//
// A surface is a closed grid of quads over "lattice" vertices, plus an optional centre
// vertex in some quads (a 4-triangle fan instead of 2 triangles) so the face count can
// be hit exactly. Vertex ids: lattice vertices first, in row order, then the centres in
// quad order. Lattice coordinates are jittered tangentially by less than an eighth of a
// cell, deterministically per vertex, so the triangulation is irregular like a scan's
// while every quad stays strictly convex (no face can fold or degenerate).
#include <cstdint>
#include <memory>
#include <string>

#include "util/geometry.hpp"

namespace qemflow::gen::detail {

__extension__ using Wide = unsigned __int128;  // products of two 64-bit counts

// `extra` of `quads` quads carry a centre vertex, spread evenly over the quad order.
struct CentreSpread {
  uint64_t quads = 1;
  uint64_t extra = 0;
  uint64_t before(uint64_t quad) const {  // centres among quads [0, quad)
    return static_cast<uint64_t>(static_cast<Wide>(quad) * extra / quads);
  }
  bool has(uint64_t quad) const { return before(quad + 1) != before(quad); }
  uint64_t quad_of(uint64_t centre) const {  // the quad holding centre number `centre`
    auto scaled = static_cast<Wide>(centre + 1) * quads;
    return static_cast<uint64_t>((scaled + extra - 1) / extra) - 1;
  }
};

class Surface {
 public:
  virtual ~Surface() = default;
  virtual std::string layout() const = 0;
  virtual int euler_characteristic() const = 0;

  virtual uint64_t lattice_vertex_count() const = 0;
  virtual uint64_t quad_count() const = 0;

  // Row r of lattice vertices holds ids [vertex_row_first(r), vertex_row_first(r + 1)).
  virtual uint64_t vertex_rows() const = 0;
  virtual uint64_t vertex_row_first(uint64_t row) const = 0;
  virtual void vertex_row(uint64_t row, Point* out) const = 0;

  // Row r of quads holds quads [quad_row_first(r), quad_row_first(r + 1)).
  virtual uint64_t quad_rows() const = 0;
  virtual uint64_t quad_row_first(uint64_t row) const = 0;
  // Corner vertex ids, counter-clockwise seen from outside.
  virtual void quad_corners(uint64_t quad, uint64_t corners[4]) const = 0;
  // Position of the centre vertex of `quad`, whose vertex id is `id`.
  virtual Point quad_centre(uint64_t quad, uint64_t id) const = 0;
};

// The quad count each shape makes at resolution m (increasing in m), and the surface.
uint64_t blob_quads(uint64_t m);
uint64_t terrain_quads(uint64_t m);
uint64_t figure_quads(uint64_t m);
std::unique_ptr<Surface> make_blob(uint64_t m, uint64_t seed);
std::unique_ptr<Surface> make_terrain(uint64_t m, uint64_t seed);
std::unique_ptr<Surface> make_figure(uint64_t m, uint64_t seed);

}  // namespace qemflow::gen::detail
