#pragma once
// 64-bit checksums from libxxhash (xxHash 0.8): XXH64 for chunk files, whose format
// publishes the values, and XXH3 for raw scratch frames, which live only as long as
// their job and take the faster hash (a tenth of a 256M re-encode's CPU was XXH64).
// Both catch torn, truncated or corrupted bytes, not an adversary.
//
// Contract: a stream fed any split of the bytes into add() calls finishes with the
// one-shot hash of the bytes laid end to end, so a frame written from pages verifies
// like one encoded from one buffer.
#include <cstddef>
#include <cstdint>

#define XXH_STATIC_LINKING_ONLY  // the state types, to hold them by value
#include <xxhash.h>
#if defined(__x86_64__)
// XXH3 through the library's run-time dispatch (AVX2 where the CPU has it: 1.5-2x the
// SSE2 build's speed here); the header maps XXH3_64bits* onto the dispatching calls.
#include <xxh_x86dispatch.h>
#endif

namespace qemflow::io {

class Xxh64Stream {
 public:
  explicit Xxh64Stream(uint64_t seed = 0) { XXH64_reset(&state_, seed); }
  void add(const void* data, size_t size) { XXH64_update(&state_, data, size); }
  uint64_t finish() const { return XXH64_digest(&state_); }

 private:
  XXH64_state_t state_;
};

class Xxh3Stream {
 public:
  Xxh3Stream() { XXH3_64bits_reset(&state_); }
  void add(const void* data, size_t size) { XXH3_64bits_update(&state_, data, size); }
  uint64_t finish() const { return XXH3_64bits_digest(&state_); }

 private:
  XXH3_state_t state_;
};

inline uint64_t xxh64(const void* data, size_t size, uint64_t seed = 0) { return XXH64(data, size, seed); }
inline uint64_t xxh3(const void* data, size_t size) { return XXH3_64bits(data, size); }

}  // namespace qemflow::io
