#include "engine/face_cells.hpp"

#include <immintrin.h>

#include <cstring>

namespace qemflow::engine {

namespace {

// Faces ahead whose positions are asked for (as the loaders' other face loops): enough
// to cover a miss to memory at a few ns a face.
constexpr uint64_t prefetch_ahead = 16;

void prefetch_face(const float* xyz, uint64_t first, uint64_t vertices, const std::byte* ids) {
  uint32_t v[3];
  std::memcpy(v, ids, sizeof v);
  for (uint32_t id : v) {
    const uint64_t at = uint64_t(id) - first;  // wraps past the end when below
    if (at < vertices) __builtin_prefetch(xyz + 3 * at);
  }
}

void cells_scalar(const BlockGrid& grid, const float* xyz, uint64_t first, uint64_t vertices, const std::byte* ids,
                  uint32_t stride, uint64_t n, uint32_t* cells) {
  for (uint64_t i = 0; i < n; ++i) {
    if (i + prefetch_ahead < n) prefetch_face(xyz, first, vertices, ids + (i + prefetch_ahead) * stride);
    uint32_t v[3];
    std::memcpy(v, ids + i * stride, sizeof v);
    const float* a = xyz + 3 * (v[0] - first);
    const float* b = xyz + 3 * (v[1] - first);
    const float* c = xyz + 3 * (v[2] - first);
    Point bary;
    for (int k = 0; k < 3; ++k) bary[k] = (double(a[k]) + double(b[k]) + double(c[k])) / 3;
    cells[i] = grid.cell_of(bary);
  }
}

// Four faces a step, one lane each: per axis, the three corners gathered and widened,
// summed in the scalar order, / 3, - min, / extent (or 0 where extent > 0 fails),
// * dims, then cell_of's floor and clamp as masks.
__attribute__((target("avx2"))) void cells_avx2(const BlockGrid& grid, const float* xyz, uint64_t first,
                                                 uint64_t vertices, const std::byte* ids, uint32_t stride, uint64_t n,
                                                 uint32_t* cells) {
  const uint64_t whole = n / 4 * 4;
  __m256d min[3], extent[3], dims[3], last[3];
  bool spread[3];
  for (int k = 0; k < 3; ++k) {
    const double e = grid.max[k] - grid.min[k];
    spread[k] = e > 0;
    min[k] = _mm256_set1_pd(grid.min[k]);
    extent[k] = _mm256_set1_pd(e);
    dims[k] = _mm256_set1_pd(double(grid.dims[k]));
    last[k] = _mm256_set1_pd(double(grid.dims[k] - 1));
  }
  const __m256d three = _mm256_set1_pd(3.0), zero = _mm256_setzero_pd(), big = _mm256_set1_pd(0x1p63);
  const __m128i dim0 = _mm_set1_epi32(int(grid.dims[0])), dim1 = _mm_set1_epi32(int(grid.dims[1]));
  const __m128i first32 = _mm_set1_epi32(int(uint32_t(first)));
  for (uint64_t i = 0; i < whole; i += 4) {
    if (i + prefetch_ahead + 4 <= n) {
      for (uint64_t j = 0; j < 4; ++j) prefetch_face(xyz, first, vertices, ids + (i + prefetch_ahead + j) * stride);
    }
    uint32_t v[4][3];
    for (int j = 0; j < 4; ++j) std::memcpy(v[j], ids + (i + uint64_t(j)) * stride, sizeof v[j]);
    // 3 * (id - first) per corner: below 2^31 (checked by the caller).
    __m128i at[3];
    for (int c = 0; c < 3; ++c) {
      const __m128i id = _mm_sub_epi32(_mm_setr_epi32(int(v[0][c]), int(v[1][c]), int(v[2][c]), int(v[3][c])), first32);
      at[c] = _mm_add_epi32(id, _mm_add_epi32(id, id));
    }
    __m128i idx[3];
    for (int k = 0; k < 3; ++k) {
      const float* base = xyz + k;
      const __m256d a = _mm256_cvtps_pd(_mm_i32gather_ps(base, at[0], 4));
      const __m256d b = _mm256_cvtps_pd(_mm_i32gather_ps(base, at[1], 4));
      const __m256d c = _mm256_cvtps_pd(_mm_i32gather_ps(base, at[2], 4));
      const __m256d bary = _mm256_div_pd(_mm256_add_pd(_mm256_add_pd(a, b), c), three);
      const __m256d q = spread[k] ? _mm256_div_pd(_mm256_sub_pd(bary, min[k]), extent[k]) : zero;
      const __m256d x = _mm256_mul_pd(q, dims[k]);
      const __m256d inside = _mm256_cmp_pd(x, dims[k], _CMP_LT_OQ);
      const __m256d below_big = _mm256_cmp_pd(x, big, _CMP_LT_OQ);
      const __m256d non_negative = _mm256_cmp_pd(x, zero, _CMP_GE_OQ);
      const __m256d truncated = _mm256_round_pd(x, _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC);
      __m256d r = _mm256_blendv_pd(_mm256_and_pd(last[k], below_big), truncated, inside);
      r = _mm256_and_pd(r, non_negative);
      idx[k] = _mm256_cvttpd_epi32(r);
    }
    const __m128i cell =
        _mm_add_epi32(_mm_mullo_epi32(_mm_add_epi32(_mm_mullo_epi32(idx[2], dim1), idx[1]), dim0), idx[0]);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(cells + i), cell);
  }
  // GCC left the tail call below without one: SSE code after it, with the upper
  // halves dirty, ran three times slower (the scalar kernel, and every later loop on
  // the thread).
  _mm256_zeroupper();
  cells_scalar(grid, xyz, first, vertices, ids + whole * stride, stride, n - whole, cells + whole);
}

bool avx2_fits(uint64_t vertices) { return 3 * vertices + 3 <= uint64_t(INT32_MAX); }

}  // namespace

bool face_cells_kernel_available(FaceCellsKernel kernel) {
  return kernel == FaceCellsKernel::scalar || __builtin_cpu_supports("avx2");
}

void face_cells_xyz(FaceCellsKernel kernel, const BlockGrid& grid, const float* xyz, uint64_t first,
                    uint64_t vertices, const std::byte* ids, uint32_t stride, uint64_t n, uint32_t* cells) {
  if (kernel == FaceCellsKernel::avx2 && avx2_fits(vertices)) {
    cells_avx2(grid, xyz, first, vertices, ids, stride, n, cells);
  } else {
    cells_scalar(grid, xyz, first, vertices, ids, stride, n, cells);
  }
}

void face_cells_xyz(const BlockGrid& grid, const float* xyz, uint64_t first, uint64_t vertices, const std::byte* ids,
                    uint32_t stride, uint64_t n, uint32_t* cells) {
  static const FaceCellsKernel best =
      face_cells_kernel_available(FaceCellsKernel::avx2) ? FaceCellsKernel::avx2 : FaceCellsKernel::scalar;
  face_cells_xyz(best, grid, xyz, first, vertices, ids, stride, n, cells);
}

}  // namespace qemflow::engine
