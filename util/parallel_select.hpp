#pragma once
// An ordered selection (stream compaction) in parallel: the indices i < n where
// pred(i) holds, each given its rank among them, so what is written is what a serial
// loop of push_backs writes, whatever the thread count. In blocks: each block's
// selected count, a prefix sum over the blocks, then each block emits from its offset.
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>
#include <vector>

namespace qemflow {

// The threads a parallel loop started here may get: the current arena's, under the
// process's global limit (--threads sets a tbb::global_control). One: loops that have
// a cheaper serial form should take it.
inline size_t parallel_threads() {
  const size_t arena = size_t(std::max(1, tbb::this_task_arena::max_concurrency()));
  const size_t global = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  return std::max<size_t>(1, std::min(arena, global));
}

// body(b, begin, end) for the blocks [b * block, min(n, (b + 1) * block)), in parallel,
// one block per task: a fixed split, so per-block results can be combined in block order.
template <class Body>
void for_each_block(size_t n, size_t block, Body&& body) {
  const size_t blocks = (n + block - 1) / block;
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, blocks, 1),
      [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b) body(b, b * block, std::min(n, (b + 1) * block));
      },
      tbb::simple_partitioner());
}

// Calls size(total) once, then emit(i, rank) for every selected i (rank: its place
// among them, ascending in i). pred is called twice per index: it must be pure.
template <class Pred, class Size, class Emit>
size_t parallel_select(size_t n, Pred&& pred, Size&& size, Emit&& emit) {
  constexpr size_t kBlock = size_t(1) << 14;
  const size_t blocks = (n + kBlock - 1) / kBlock;
  std::vector<size_t> at(blocks + 1, 0);
  auto each_block = [&](auto&& body) { for_each_block(n, kBlock, body); };
  each_block([&](size_t b, size_t begin, size_t end) {
    size_t count = 0;
    for (size_t i = begin; i < end; ++i) count += pred(i) ? 1 : 0;
    at[b + 1] = count;
  });
  for (size_t b = 0; b < blocks; ++b) at[b + 1] += at[b];
  const size_t total = at[blocks];
  size(total);
  each_block([&](size_t b, size_t begin, size_t end) {
    size_t rank = at[b];
    for (size_t i = begin; i < end; ++i)
      if (pred(i)) emit(i, rank++);
  });
  return total;
}

}  // namespace qemflow
