#pragma once
// XXH64 (the xxHash 64-bit algorithm, seed 0 unless given): a fast checksum for
// scratch chunks. Written out here because the packaged libxxhash ships no header.
#include <cstddef>
#include <cstdint>

namespace qemflow::io {

uint64_t xxh64(const void* data, size_t size, uint64_t seed = 0);

}  // namespace qemflow::io
