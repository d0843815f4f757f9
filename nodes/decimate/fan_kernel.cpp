// FanDeviation's kernel (fan_kernel.inc) for SSE2 (every x86-64), AVX2 and AVX-512F,
// chosen at start-up. The build targets baseline x86-64, so the wider versions are
// compiled under target pragmas and run only where the CPU has them. No version may
// use FMA (a fused multiply-add rounds once: other bits): AVX2 and AVX-512F do not
// enable it, and this file is compiled with -ffp-contract=off (nodes/CMakeLists.txt).
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string_view>
#include <utility>

#include "nodes/decimate/quadric.hpp"

namespace qemflow::nodes {
namespace {

namespace sse2 {
constexpr int kWidth = 2;
#include "nodes/decimate/fan_kernel.inc"
}  // namespace sse2

#pragma GCC push_options
#pragma GCC target("avx2")
namespace avx2 {
constexpr int kWidth = 4;
#include "nodes/decimate/fan_kernel.inc"
}  // namespace avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx512f")
namespace avx512 {
constexpr int kWidth = 8;
#include "nodes/decimate/fan_kernel.inc"
}  // namespace avx512
#pragma GCC pop_options

static_assert(kFanBlock % 4 == 0, "the AVX-512 version reads 4 triangles at a time");

using Kernel = void (*)(const FanRows&, int, const Vec3&, const Vec3&, double*);

bool supported(FanKernel kernel) {
  __builtin_cpu_init();
  switch (kernel) {
    case FanKernel::kSse2: return true;
    case FanKernel::kAvx2: return __builtin_cpu_supports("avx2");
    case FanKernel::kAvx512: return __builtin_cpu_supports("avx512f");
  }
  return false;
}

Kernel version(FanKernel kernel) {
  switch (kernel) {
    case FanKernel::kAvx2: return avx2::fan_block;
    case FanKernel::kAvx512: return avx512::fan_block;
    default: return sse2::fan_block;
  }
}

FanKernel initial_kernel() {
  if (const char* forced = std::getenv("QEMFLOW_FAN_KERNEL")) {
    const std::string_view name(forced);
    const FanKernel named = name == "avx512" ? FanKernel::kAvx512 : name == "avx2" ? FanKernel::kAvx2 : FanKernel::kSse2;
    if (supported(named)) return named;
  }
  return supported(FanKernel::kAvx2) ? FanKernel::kAvx2 : FanKernel::kSse2;
}

FanKernel current = initial_kernel();
Kernel kernel = version(current);

}  // namespace

FanKernel fan_kernel() { return current; }

bool use_fan_kernel(FanKernel k) {
  if (!supported(k)) return false;
  current = k;
  kernel = version(k);
  return true;
}

void FanDeviation::flush() {
  // Pad the block with copies of the last triangle (a minimum does not change).
  for (int k = pending_; k < kFanBlock; ++k)
    for (auto& row : rows_) row[k] = row[pending_ - 1];
  kernel(rows_, pending_, a_, b_, nearest_);
  pending_ = 0;
  empty_ = false;
}

}  // namespace qemflow::nodes
