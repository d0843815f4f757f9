#pragma once
// XXH64 (the xxHash 64-bit algorithm, seed 0 unless given): a fast checksum for
// scratch chunks and frames. Written out here because the packaged libxxhash ships no
// header.
#include <cstddef>
#include <cstdint>

namespace qemflow::io {

// XXH64 over bytes that arrive in pieces: finish() equals xxh64() of the pieces laid
// end to end, so a frame written from pages verifies like one encoded from one buffer.
class Xxh64Stream {
 public:
  explicit Xxh64Stream(uint64_t seed = 0);
  void add(const void* data, size_t size);
  uint64_t finish() const;

 private:
  void stripe(const unsigned char* p);
  uint64_t v_[4];
  unsigned char buffer_[32];
  size_t held_ = 0;
  uint64_t total_ = 0;
  uint64_t seed_;
};

uint64_t xxh64(const void* data, size_t size, uint64_t seed = 0);

}  // namespace qemflow::io
