#pragma once
// The block cell of each face, from its three vertex ids and xyz float positions: the
// loaders' per-face cost on a re-encode (a fifth to a quarter of its CPU), most of it
// six double divisions a face (barycenter / 3, then / extent), each in its own scalar
// instruction. The AVX2 kernel divides four faces at once; every operation is the
// scalar one's, lane by lane (IEEE, no contraction), so the cells are the same bits.
// The steps kernel divides nothing: each axis's index is a monotone step function of
// the corners' sum, whose steps it finds once a grid (face_cells.cpp); same cells.
#include <cstddef>
#include <cstdint>

#include "engine/blocks.hpp"

namespace qemflow::engine {

enum class FaceCellsKernel { scalar, avx2, steps };

// Cells of `n` faces: face i's ids are three u32 at `ids + i * stride`; vertex v's
// position is xyz[3 * (v - first)] (ids below `first` wrap). Every face's ids must lie
// in [first, first + vertices) (nothing checks them; the AVX2 kernel is chosen by
// `vertices`, its gathers' 32-bit offsets must reach). Results go
// to cells[0, n), which may overlap no record.
void face_cells_xyz(const BlockGrid& grid, const float* xyz, uint64_t first, uint64_t vertices, const std::byte* ids,
                    uint32_t stride, uint64_t n, uint32_t* cells);
// The same with one kernel (tests; avx2 only where the CPU has it).
void face_cells_xyz(FaceCellsKernel kernel, const BlockGrid& grid, const float* xyz, uint64_t first,
                    uint64_t vertices, const std::byte* ids, uint32_t stride, uint64_t n, uint32_t* cells);
bool face_cells_kernel_available(FaceCellsKernel kernel);

}  // namespace qemflow::engine
