#include "engine/face_cells.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

namespace qemflow::engine {
namespace {

// Scalar and AVX2 kernels agree with cell_of on the barycenter, face by face, on
// positions spread over and past the grid's box (the clamps), on cell boundaries
// (float corners at exact cell edges), and with NaN and infinite coordinates, over
// counts that leave every remainder of the four-face step, with 12- and 16-byte records.
TEST(FaceCells, KernelsMatchCellOfOnEveryFace) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> spread(-1.5f, 11.5f);
  const uint64_t vertices = 4000, first = 100;
  std::vector<float> xyz(3 * vertices);
  for (uint64_t v = 0; v < vertices; ++v) {
    for (int k = 0; k < 3; ++k) {
      float x = spread(rng);
      if (v % 7 == 0) x = std::round(x);           // on cell edges
      if (v % 501 == 3) x = std::numeric_limits<float>::quiet_NaN();
      if (v % 733 == 5) x = (k == 1 ? -1 : 1) * std::numeric_limits<float>::infinity();
      xyz[3 * v + k] = x;
    }
  }
  BlockGrid grids[3];
  grids[0] = BlockGrid::around({0, 0, 0}, {10, 10, 10}, 1000);
  grids[1] = BlockGrid::around({0, 2, 0}, {10, 2, 3}, 64);  // a flat axis: extent 0
  grids[2].min = {1, 1, 1};
  grids[2].max = {9, 9, 9};
  grids[2].dims = {256, 3, 17};
  std::uniform_int_distribution<uint32_t> pick(uint32_t(first), uint32_t(first + vertices - 1));
  for (const uint32_t stride : {12u, 16u}) {
    for (const uint64_t n : {0ull, 1ull, 3ull, 4ull, 5ull, 21ull, 1000ull, 1003ull}) {
      std::vector<std::byte> records(n * stride + 16);
      for (uint64_t i = 0; i < n; ++i) {
        const uint32_t ids[3] = {pick(rng), pick(rng), pick(rng)};
        std::memcpy(records.data() + i * stride, ids, sizeof ids);
      }
      for (const BlockGrid& grid : grids) {
        std::vector<uint32_t> expected(n);
        for (uint64_t i = 0; i < n; ++i) {
          uint32_t ids[3];
          std::memcpy(ids, records.data() + i * stride, sizeof ids);
          Point bary;
          for (int k = 0; k < 3; ++k) {
            bary[k] = (double(xyz[3 * (ids[0] - first) + k]) + double(xyz[3 * (ids[1] - first) + k]) +
                       double(xyz[3 * (ids[2] - first) + k])) / 3;
          }
          expected[i] = grid.cell_of(bary);
        }
        for (const FaceCellsKernel kernel : {FaceCellsKernel::scalar, FaceCellsKernel::avx2, FaceCellsKernel::steps}) {
          if (!face_cells_kernel_available(kernel)) continue;
          std::vector<uint32_t> cells(n, UINT32_MAX);
          face_cells_xyz(kernel, grid, xyz.data(), first, vertices, records.data(), stride, n, cells.data());
          EXPECT_EQ(cells, expected) << "kernel " << int(kernel) << ", stride " << stride << ", n " << n;
        }
      }
    }
  }
}

// The steps kernel finds each cell edge by bisection over the corners' sums: faces
// whose three corners are one float, walked a few hundred floats either side of every
// cell edge of grids with inexact extents, land in cell_of's cell to the last bit.
TEST(FaceCells, StepsKernelMatchesCellOfAtEveryCellEdge) {
  BlockGrid grids[3];
  grids[0].min = {0.1, -0.7, 1e-3};
  grids[0].max = {0.7, 1.3, 1e-3 + 1e-6};
  grids[0].dims = {7, 13, 3};
  grids[1].min = {-1e6, 3, 0};
  grids[1].max = {1e6 / 3, 3, 1};  // a flat axis
  grids[1].dims = {41, 5, 1};
  grids[2].min = {0, 0, 0};
  grids[2].max = {1, 1, 1};
  grids[2].dims = {1, 2, 200};  // more than 16 steps: the bisecting count
  for (const BlockGrid& grid : grids) {
    std::vector<float> xyz;
    for (int k = 0; k < 3; ++k) {
      const double extent = grid.max[k] - grid.min[k];
      for (uint32_t j = 0; j <= grid.dims[k]; ++j) {
        float edge = float(grid.min[k] + extent * j / grid.dims[k]);
        for (int s = 0; s < 300; ++s) edge = std::nextafter(edge, -std::numeric_limits<float>::infinity());
        for (int s = 0; s < 600; ++s, edge = std::nextafter(edge, std::numeric_limits<float>::infinity())) {
          float p[3] = {float(grid.min[0]), float(grid.min[1]), float(grid.min[2])};
          p[k] = edge;
          xyz.insert(xyz.end(), p, p + 3);
        }
      }
    }
    const uint64_t vertices = xyz.size() / 3;
    std::vector<std::byte> records(vertices * 12);
    std::vector<uint32_t> expected(vertices);
    for (uint32_t v = 0; v < vertices; ++v) {
      const uint32_t ids[3] = {v, v, v};
      std::memcpy(records.data() + 12 * v, ids, sizeof ids);
      Point bary;
      for (int k = 0; k < 3; ++k) {
        const double x = xyz[3 * v + k];
        bary[k] = (x + x + x) / 3;
      }
      expected[v] = grid.cell_of(bary);
    }
    std::vector<uint32_t> cells(vertices, UINT32_MAX);
    face_cells_xyz(FaceCellsKernel::steps, grid, xyz.data(), 0, vertices, records.data(), 12, vertices, cells.data());
    EXPECT_EQ(cells, expected);
  }
}

}  // namespace
}  // namespace qemflow::engine
