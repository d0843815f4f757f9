#pragma once
// The checksum of raw scratch frames: catches a torn, truncated or corrupted frame
// (any changed, missing or reordered bytes), not an adversary. Frames live only as
// long as the job that wrote them, so it need not match any published hash.
//
// The shape is XXH3's long loop: eight 64-bit lanes take a 64-byte stripe at a time,
// each lane adding a data word and the 32×32-bit product of the word xor-ed with a
// per-stripe key (so equal words at different places sum differently); every 1 KiB
// the lanes are scrambled (so blocks are order-dependent too); the end mixes the lanes
// with the length. AVX2 does four lanes an instruction; CPUs and targets without it
// one at a time: the same arithmetic, the same result.
//
// Why not XXH64 (used before): it was a tenth of a re-encode's CPU time at 256M.
// `build/bench/engine_bench --benchmark_filter='Checksum|Xxh64'` on a 1 MiB buffer
// (AVX2, machine loaded): 21-36 GB/s of CPU time against XXH64's 13-14 GB/s.
//
// Contract: FrameChecksum fed any split of the bytes into add() calls finishes with
// frame_checksum() of the bytes laid end to end.
#include <cstddef>
#include <cstdint>

namespace qemflow::engine {

class FrameChecksum {
 public:
  FrameChecksum();
  void add(const void* data, size_t size);
  uint64_t finish() const;

 private:
  static constexpr size_t stripe_bytes = 64;
  alignas(16) uint64_t lanes_[8];
  unsigned char held_[stripe_bytes];
  size_t held_bytes_ = 0;
  size_t stripe_in_block_ = 0;
  uint64_t total_ = 0;
};

uint64_t frame_checksum(const void* data, size_t size);
// The same sum computed one lane at a time (what non-x86 targets run): for tests that
// the vector versions agree with it.
uint64_t frame_checksum_one_lane_at_a_time(const void* data, size_t size);

}  // namespace qemflow::engine
