#include "io/hash64.hpp"

#include <algorithm>
#include <bit>
#include <cstring>

namespace qemflow::io {

namespace {

constexpr uint64_t prime1 = 0x9E3779B185EBCA87ull;
constexpr uint64_t prime2 = 0xC2B2AE3D27D4EB4Full;
constexpr uint64_t prime3 = 0x165667B19E3779F9ull;
constexpr uint64_t prime4 = 0x85EBCA77C2B2AE63ull;
constexpr uint64_t prime5 = 0x27D4EB2F165667C5ull;

inline uint64_t read64(const unsigned char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;  // little-endian host (asserted below)
}
inline uint32_t read32(const unsigned char* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  return v;
}

inline uint64_t round(uint64_t accumulator, uint64_t input) {
  return std::rotl(accumulator + input * prime2, 31) * prime1;
}

inline uint64_t merge_round(uint64_t accumulator, uint64_t value) {
  accumulator ^= round(0, value);
  return accumulator * prime1 + prime4;
}

}  // namespace

Xxh64Stream::Xxh64Stream(uint64_t seed)
    : v_{seed + prime1 + prime2, seed + prime2, seed, seed - prime1}, seed_(seed) {}

void Xxh64Stream::stripe(const unsigned char* p) {
  for (int i = 0; i < 4; ++i) v_[i] = round(v_[i], read64(p + 8 * i));
}

void Xxh64Stream::add(const void* data, size_t n) {
  static_assert(std::endian::native == std::endian::little);
  const auto* p = static_cast<const unsigned char*>(data);
  total_ += n;
  if (held_ > 0) {
    const size_t take = std::min(n, size_t(32) - held_);
    std::memcpy(buffer_ + held_, p, take);
    held_ += take;
    p += take;
    n -= take;
    if (held_ < 32) return;
    stripe(buffer_);
    held_ = 0;
  }
  // The lanes in locals: through v_ the compiler would store them after every stripe
  // (the input may alias them); that was half again slower.
  uint64_t v1 = v_[0], v2 = v_[1], v3 = v_[2], v4 = v_[3];
  for (; n >= 32; p += 32, n -= 32) {
    v1 = round(v1, read64(p));
    v2 = round(v2, read64(p + 8));
    v3 = round(v3, read64(p + 16));
    v4 = round(v4, read64(p + 24));
  }
  v_[0] = v1, v_[1] = v2, v_[2] = v3, v_[3] = v4;
  std::memcpy(buffer_, p, n);
  held_ = n;
}

uint64_t Xxh64Stream::finish() const {
  uint64_t h;
  if (total_ >= 32) {
    h = std::rotl(v_[0], 1) + std::rotl(v_[1], 7) + std::rotl(v_[2], 12) + std::rotl(v_[3], 18);
    for (uint64_t v : v_) h = merge_round(h, v);
  } else {
    h = seed_ + prime5;
  }
  h += total_;
  const unsigned char* p = buffer_;
  const unsigned char* end = buffer_ + held_;
  for (; p + 8 <= end; p += 8) {
    h ^= round(0, read64(p));
    h = std::rotl(h, 27) * prime1 + prime4;
  }
  if (p + 4 <= end) {
    h ^= static_cast<uint64_t>(read32(p)) * prime1;
    h = std::rotl(h, 23) * prime2 + prime3;
    p += 4;
  }
  for (; p < end; ++p) {
    h ^= static_cast<uint64_t>(*p) * prime5;
    h = std::rotl(h, 11) * prime1;
  }
  h ^= h >> 33;
  h *= prime2;
  h ^= h >> 29;
  h *= prime3;
  h ^= h >> 32;
  return h;
}

uint64_t xxh64(const void* data, size_t size, uint64_t seed) {
  Xxh64Stream stream(seed);
  stream.add(data, size);
  return stream.finish();
}

}  // namespace qemflow::io
