#include "engine/face_cells.hpp"

#include <immintrin.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

namespace qemflow::engine {

namespace {

// Faces ahead whose positions are asked for (as the loaders' other face loops): enough
// to cover a miss to memory at a few ns a face.
constexpr uint64_t prefetch_ahead = 16;

// A corner's id (u32) at `at`.
[[gnu::always_inline]] inline uint32_t id_at(const std::byte* at) {
  uint32_t id;
  std::memcpy(&id, at, sizeof id);
  return id;
}

// Unchecked: the faces prefetched are ones the kernel reads anyway, whose ids lie in the
// window by contract (checking them again was a third of the steps kernel's
// instructions a face).
[[gnu::always_inline]] inline void prefetch_face(const float* xyz, uint64_t first, const std::byte* ids) {
  // Three scalars, not an array: an array went through the stack every face.
#pragma GCC unroll 3
  for (int k = 0; k < 3; ++k) __builtin_prefetch(xyz + 3 * (id_at(ids + 4 * k) - first));
}

// cells[i] = cell(a, b, c) of face i's corner positions, prefetched ahead.
template <class Cell>
[[gnu::always_inline]] inline void for_each_face(const float* xyz, uint64_t first, const std::byte* ids,
                                                 uint32_t stride, uint64_t n, uint32_t* cells, Cell cell) {
  for (uint64_t i = 0; i < n; ++i) {
    if (i + prefetch_ahead < n) prefetch_face(xyz, first, ids + (i + prefetch_ahead) * stride);
    uint32_t v[3];
    std::memcpy(v, ids + i * stride, sizeof v);
    cells[i] = cell(xyz + 3 * (v[0] - first), xyz + 3 * (v[1] - first), xyz + 3 * (v[2] - first));
  }
}

void cells_scalar(const BlockGrid& grid, const float* xyz, uint64_t first, const std::byte* ids,
                  uint32_t stride, uint64_t n, uint32_t* cells) {
  for_each_face(xyz, first, ids, stride, n, cells, [&grid](const float* a, const float* b, const float* c) {
    Point bary;
    for (int k = 0; k < 3; ++k) bary[k] = (double(a[k]) + double(b[k]) + double(c[k])) / 3;
    return grid.cell_of(bary);
  });
}

// Four faces a step, one lane each: per axis, the three corners gathered and widened,
// summed in the scalar order, / 3, - min, / extent (or 0 where extent > 0 fails),
// * dims, then cell_of's floor and clamp as masks.
__attribute__((target("avx2"))) void cells_avx2(const BlockGrid& grid, const float* xyz, uint64_t first,
                                                 const std::byte* ids, uint32_t stride, uint64_t n, uint32_t* cells) {
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
      for (uint64_t j = 0; j < 4; ++j) prefetch_face(xyz, first, ids + (i + prefetch_ahead + j) * stride);
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
  cells_scalar(grid, xyz, first, ids + whole * stride, stride, n - whole, cells + whole);
}

// Division-free cells. Per axis, cell_of's index of the barycenter is a function of
// the corners' sum t = (a + b) + c alone: t / 3, - min, / extent, * dims are each
// correctly rounded, so monotone in t, and the index is how many of 1 .. dims - 1 that
// x reaches, except 0 where x is NaN or reaches 2^63. So it is the count of steps
// T_j <= t (T_j the least double t whose x reaches j, found once by bisection over the
// doubles' order), and 0 from U (x reaches 2^63) up: two additions and a few
// comparisons a face instead of six divisions (the re-encode's largest CPU item).
// Only for a grid whose box is finite: with an infinite min, t - min is not monotone.
struct AxisSteps {
  std::vector<double> steps;  // T_1 .. T_m, the ones that exist (m <= dims - 1)
  double drop = std::numeric_limits<double>::quiet_NaN();  // U, NaN when no t reaches it
};

struct GridSteps {
  BlockGrid grid;
  AxisSteps axis[3];
};

// cell_of's x for the corners' sum t on axis k, with its very operations.
double axis_x(const BlockGrid& grid, int k, double t) {
  const double bary = t / 3;
  const double extent = grid.max[k] - grid.min[k];
  return (extent > 0 ? (bary - grid.min[k]) / extent : 0.0) * grid.dims[k];
}

// Doubles in order as integers (-inf lowest, then -0 just below +0), and back.
int64_t order_key(double d) {
  int64_t i;
  std::memcpy(&i, &d, sizeof i);
  return i < 0 ? INT64_MIN - i - 1 : i;  // negatives reversed below the positives
}
double from_order_key(int64_t i) {
  if (i < 0) i = INT64_MIN - i - 1;
  double d;
  std::memcpy(&d, &i, sizeof d);
  return d;
}

// The least t (not NaN) with reached(axis_x(t)), NaN when none; `reached` must be
// monotone in x and false at -inf's x.
template <class Reached>
double least_sum(const BlockGrid& grid, int k, Reached reached) {
  int64_t lo = order_key(-std::numeric_limits<double>::infinity());
  int64_t hi = order_key(std::numeric_limits<double>::infinity());
  if (!reached(axis_x(grid, k, from_order_key(hi)))) return std::numeric_limits<double>::quiet_NaN();
  while (lo + 1 < hi) {  // reached at hi, not at lo
    const int64_t mid = lo + int64_t((uint64_t(hi) - uint64_t(lo)) / 2);  // the span passes INT64_MAX
    (reached(axis_x(grid, k, from_order_key(mid))) ? hi : lo) = mid;
  }
  return from_order_key(hi);
}

bool steps_fit(const BlockGrid& grid) {
  for (int k = 0; k < 3; ++k) {
    if (!std::isfinite(grid.min[k]) || !std::isfinite(grid.max[k])) return false;
  }
  return true;
}

const GridSteps& grid_steps(const BlockGrid& grid) {
  // Built once a grid and thread (a load has one grid; each bisection is ~64 tries a step).
  thread_local std::unique_ptr<GridSteps> cached;
  if (cached && cached->grid.min == grid.min && cached->grid.max == grid.max && cached->grid.dims == grid.dims) {
    return *cached;
  }
  auto built = std::make_unique<GridSteps>();
  built->grid = grid;
  for (int k = 0; k < 3; ++k) {
    AxisSteps& axis = built->axis[k];
    for (uint32_t j = 1; j < grid.dims[k]; ++j) {
      const double step = least_sum(grid, k, [j](double x) { return x >= double(j); });
      if (std::isnan(step)) break;  // none reaches j, so none reaches the next ones
      axis.steps.push_back(step);
    }
    axis.drop = least_sum(grid, k, [](double x) { return x >= 0x1p63; });
  }
  cached = std::move(built);
  return *cached;
}

uint32_t axis_index(const AxisSteps& axis, double t) {
  if (t >= axis.drop) return 0;  // never true for NaN
  const size_t m = axis.steps.size();
  if (m <= 16) {
    uint32_t idx = 0;
    for (size_t j = 0; j < m; ++j) idx += t >= axis.steps[j];
    return idx;
  }
  if (std::isnan(t)) return 0;
  return uint32_t(std::upper_bound(axis.steps.begin(), axis.steps.end(), t) - axis.steps.begin());
}

void cells_steps(const GridSteps& steps, const float* xyz, uint64_t first, const std::byte* ids,
                 uint32_t stride, uint64_t n, uint32_t* cells) {
  const BlockGrid& grid = steps.grid;
  for_each_face(xyz, first, ids, stride, n, cells, [&](const float* a, const float* b, const float* c) {
    uint32_t idx[3];
    for (int k = 0; k < 3; ++k) idx[k] = axis_index(steps.axis[k], double(a[k]) + double(b[k]) + double(c[k]));
    return (idx[2] * grid.dims[1] + idx[1]) * grid.dims[0] + idx[0];
  });
}

// The steps kernel with a face's three axes in the lanes of one vector: each axis's
// step j in lane k (NaN past its last step, so never reached), counted by compares.
// For grids of at most 16 steps an axis (a load's grid: a few cells an axis).
constexpr size_t max_vector_steps = 16;

bool steps_vector_fit(const GridSteps& steps) {
  for (const AxisSteps& axis : steps.axis) {
    if (axis.steps.size() > max_vector_steps) return false;
  }
  return true;
}

// The loop for exactly M steps an axis, unrolled: the steps stay in registers, the
// corners never go through the stack (with a run-time count, GCC kept both in memory:
// ~110 instructions a face).
// x, y and z loaded apart: 12 bytes copied to a 16-byte temporary and loaded whole
// missed store forwarding, three times slower than the scalar kernel.
[[gnu::always_inline]] __attribute__((target("avx2"))) inline __m256d corner_xyz(const float* p) {
  const __m128 xy = _mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)));
  return _mm256_cvtps_pd(_mm_movelh_ps(xy, _mm_load_ss(p + 2)));
}

// A face's cell from its M steps an axis: each lane counts the steps its sum reaches
// as an integer (a compare's all-ones is -1), and the cell is the counts' dot product
// with the weights in u64 lanes: exact, and two instructions a step where counting in
// doubles took three (and the dot product in doubles two more).
// `origin`: where vertex 0's position would be (xyz - 3 * first, as an address: the
// subtraction done once, not six times a face).
[[gnu::always_inline]] inline const float* position_at(uintptr_t origin, uint32_t id) {
  return reinterpret_cast<const float*>(origin + 3 * sizeof(float) * uint64_t(id));
}

template <size_t M>
[[gnu::always_inline]] __attribute__((target("avx2"))) inline uint32_t steps_cell(const __m256d* s, __m256d drop,
                                                                                  __m256i weight, uintptr_t origin,
                                                                                  const std::byte* face) {
  // (a + b) + c per lane, the scalar kernels' sum.
  const __m256d t = _mm256_add_pd(_mm256_add_pd(corner_xyz(position_at(origin, id_at(face))),
                                                corner_xyz(position_at(origin, id_at(face + 4)))),
                                  corner_xyz(position_at(origin, id_at(face + 8))));
  __m256i idx = _mm256_setzero_si256();
  for (size_t j = 0; j < M; ++j) idx = _mm256_sub_epi64(idx, _mm256_castpd_si256(_mm256_cmp_pd(t, s[j], _CMP_GE_OQ)));
  idx = _mm256_andnot_si256(_mm256_castpd_si256(_mm256_cmp_pd(t, drop, _CMP_GE_OQ)), idx);
  const __m256i w = _mm256_mul_epu32(idx, weight);
  const __m128i pair = _mm_add_epi64(_mm256_castsi256_si128(w), _mm256_extracti128_si256(w, 1));
  return uint32_t(_mm_cvtsi128_si64(_mm_add_epi64(pair, _mm_unpackhi_epi64(pair, pair))));
}

// The loop for exactly M steps an axis, unrolled: the steps stay in registers and the
// corners never go through the stack (with a run-time count, GCC kept both in memory:
// ~110 instructions a face). `lanes`: the M steps, then the drop; `weights` the cell's.
// In two parts, so that only the first asks whether a face lies ahead to prefetch.
template <size_t M>
__attribute__((target("avx2"))) void cells_steps_avx2_m(const double (*lanes)[4], const uint64_t* weights,
                                                         const float* xyz, uint64_t first, const std::byte* ids,
                                                         uint32_t stride, uint64_t n, uint32_t* cells) {
  __m256d s[M > 0 ? M : 1];
  for (size_t j = 0; j < M; ++j) s[j] = _mm256_load_pd(lanes[j]);
  const __m256d drop = _mm256_load_pd(lanes[M]);
  const __m256i weight = _mm256_load_si256(reinterpret_cast<const __m256i*>(weights));
  const uintptr_t origin = reinterpret_cast<uintptr_t>(xyz) - 3 * sizeof(float) * first;
  const uint64_t prefetching = n > prefetch_ahead ? n - prefetch_ahead : 0;
  for (uint64_t i = 0; i < prefetching; ++i) {
    const std::byte* ahead = ids + (i + prefetch_ahead) * stride;
#pragma GCC unroll 3
    for (int k = 0; k < 3; ++k) __builtin_prefetch(position_at(origin, id_at(ahead + 4 * k)));
    cells[i] = steps_cell<M>(s, drop, weight, origin, ids + i * stride);
  }
  for (uint64_t i = prefetching; i < n; ++i) cells[i] = steps_cell<M>(s, drop, weight, origin, ids + i * stride);
  _mm256_zeroupper();
}

template <size_t... M>
constexpr auto steps_kernels(std::index_sequence<M...>) {
  return std::array{&cells_steps_avx2_m<M>...};
}

void cells_steps_avx2(const GridSteps& steps, const float* xyz, uint64_t first, const std::byte* ids,
                      uint32_t stride, uint64_t n, uint32_t* cells) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  size_t m = 0;
  for (const AxisSteps& axis : steps.axis) m = std::max(m, axis.steps.size());
  alignas(32) double lanes[max_vector_steps + 1][4];
  for (size_t j = 0; j <= m; ++j) {
    for (int k = 0; k < 4; ++k) {
      const AxisSteps* axis = k < 3 ? &steps.axis[k] : nullptr;
      lanes[j][k] = j == m ? (axis ? axis->drop : nan) : axis && j < axis->steps.size() ? axis->steps[j] : nan;
    }
  }
  // The cell as a dot product (below 2^32, as are the weights).
  const BlockGrid& grid = steps.grid;
  alignas(32) const uint64_t weights[4] = {1, grid.dims[0], uint64_t(grid.dims[0]) * grid.dims[1], 0};
  static constexpr auto kernels = steps_kernels(std::make_index_sequence<max_vector_steps + 1>());
  kernels[m](lanes, weights, xyz, first, ids, stride, n, cells);
}

bool avx2_fits(uint64_t vertices) { return 3 * vertices + 3 <= uint64_t(INT32_MAX); }

}  // namespace

bool face_cells_kernel_available(FaceCellsKernel kernel) {
  return kernel != FaceCellsKernel::avx2 || __builtin_cpu_supports("avx2");
}

void face_cells_xyz(FaceCellsKernel kernel, const BlockGrid& grid, const float* xyz, uint64_t first,
                    uint64_t vertices, const std::byte* ids, uint32_t stride, uint64_t n, uint32_t* cells) {
  if (kernel == FaceCellsKernel::avx2 && avx2_fits(vertices)) {
    cells_avx2(grid, xyz, first, ids, stride, n, cells);
  } else if (kernel == FaceCellsKernel::steps && steps_fit(grid)) {
    const GridSteps& steps = grid_steps(grid);
    if (__builtin_cpu_supports("avx2") && steps_vector_fit(steps)) {
      cells_steps_avx2(steps, xyz, first, ids, stride, n, cells);
    } else {
      cells_steps(steps, xyz, first, ids, stride, n, cells);
    }
  } else {
    cells_scalar(grid, xyz, first, ids, stride, n, cells);
  }
}

void face_cells_xyz(const BlockGrid& grid, const float* xyz, uint64_t first, uint64_t vertices, const std::byte* ids,
                    uint32_t stride, uint64_t n, uint32_t* cells) {
  // Steps first: no divisions at all beat the AVX2 kernel's four at once.
  static const FaceCellsKernel divides =
      face_cells_kernel_available(FaceCellsKernel::avx2) ? FaceCellsKernel::avx2 : FaceCellsKernel::scalar;
  face_cells_xyz(steps_fit(grid) ? FaceCellsKernel::steps : divides, grid, xyz, first, vertices, ids, stride, n, cells);
}

}  // namespace qemflow::engine
