#include "engine/frame_checksum.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace qemflow::engine {

namespace {

constexpr size_t lanes = 8;
constexpr size_t stripe_bytes = 64;
constexpr size_t stripes_per_block = 16;  // lanes scrambled every 1 KiB
constexpr uint64_t scramble_prime = 0x9E3779B1ull;  // 32 bits: one mul_epu32 per half

// Keys: stripe n of a block uses words [n, n + 8); the scramble [24, 32); the end
// [32, 40). Any fixed pseudo-random words do (splitmix64 of a constant).
constexpr std::array<uint64_t, 40> make_keys() {
  std::array<uint64_t, 40> keys{};
  uint64_t state = 0x5146434b43686b31ull;  // "QFCKChk1"
  for (uint64_t& key : keys) {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    key = z ^ (z >> 31);
  }
  return keys;
}
alignas(16) constexpr std::array<uint64_t, 40> keys = make_keys();
constexpr size_t scramble_keys = 24;
constexpr size_t final_keys = 32;

inline uint64_t load64(const unsigned char* p) {
  static_assert(std::endian::native == std::endian::little);
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

// `count` whole stripes at `p` into the lanes, starting at stripe `in_block` of the
// current block; returns the stripe of the block reached. Two versions of the same
// arithmetic: one lane at a time (any target; the reference) and AVX2 (four lanes an
// instruction), picked once by what the CPU has.
size_t consume_scalar(uint64_t* acc, const unsigned char* p, size_t count, size_t in_block) {
  for (size_t s = 0; s < count; ++s, p += stripe_bytes) {
    for (size_t i = 0; i < lanes; ++i) {
      const uint64_t data = load64(p + 8 * i);
      const uint64_t keyed = data ^ keys[in_block + i];
      acc[i ^ 1] += data;
      acc[i] += (keyed & 0xFFFFFFFFull) * (keyed >> 32);
    }
    if (++in_block == stripes_per_block) {
      in_block = 0;
      for (size_t i = 0; i < lanes; ++i) {
        uint64_t a = acc[i] ^ (acc[i] >> 47);
        acc[i] = (a ^ keys[scramble_keys + i]) * scramble_prime;
      }
    }
  }
  return in_block;
}

#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target("avx2"))) size_t consume_avx2(uint64_t* lane_words, const unsigned char* p, size_t count,
                                                   size_t in_block) {
  __m256i acc[2];
  for (int i = 0; i < 2; ++i) acc[i] = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(lane_words) + i);
  const __m256i prime = _mm256_set1_epi32(int(scramble_prime));
  for (size_t s = 0; s < count; ++s, p += stripe_bytes) {
    const auto* key = reinterpret_cast<const __m256i*>(keys.data() + in_block);
    for (int i = 0; i < 2; ++i) {
      const __m256i data = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p) + i);
      const __m256i keyed = _mm256_xor_si256(data, _mm256_loadu_si256(key + i));
      const __m256i product = _mm256_mul_epu32(keyed, _mm256_shuffle_epi32(keyed, _MM_SHUFFLE(0, 3, 0, 1)));
      const __m256i swapped = _mm256_shuffle_epi32(data, _MM_SHUFFLE(1, 0, 3, 2));
      acc[i] = _mm256_add_epi64(acc[i], _mm256_add_epi64(product, swapped));
    }
    if (++in_block == stripes_per_block) {
      in_block = 0;
      const auto* scramble = reinterpret_cast<const __m256i*>(keys.data() + scramble_keys);
      for (int i = 0; i < 2; ++i) {
        __m256i a = _mm256_xor_si256(acc[i], _mm256_srli_epi64(acc[i], 47));
        a = _mm256_xor_si256(a, _mm256_loadu_si256(scramble + i));
        const __m256i lo = _mm256_mul_epu32(a, prime);
        const __m256i hi = _mm256_mul_epu32(_mm256_srli_epi64(a, 32), prime);
        acc[i] = _mm256_add_epi64(lo, _mm256_slli_epi64(hi, 32));
      }
    }
  }
  for (int i = 0; i < 2; ++i) _mm256_storeu_si256(reinterpret_cast<__m256i*>(lane_words) + i, acc[i]);
  return in_block;
}

using Consume = size_t (*)(uint64_t*, const unsigned char*, size_t, size_t);
Consume pick_consume() {
  __builtin_cpu_init();  // this runs as a static initializer, maybe before libgcc's own
  return __builtin_cpu_supports("avx2") ? consume_avx2 : consume_scalar;
}
const Consume consume = pick_consume();
#else
constexpr auto consume = consume_scalar;
#endif

__extension__ typedef unsigned __int128 uint128;
uint64_t fold(uint64_t a, uint64_t b) {
  const uint128 product = static_cast<uint128>(a) * b;
  return uint64_t(product) ^ uint64_t(product >> 64);
}

// The lanes and the length mixed into the checksum.
uint64_t finish_lanes(const uint64_t* acc, uint64_t total) {
  uint64_t h = total * 0x9E3779B185EBCA87ull;
  for (size_t i = 0; i < lanes; i += 2) {
    h += fold(acc[i] ^ keys[final_keys + i], acc[i + 1] ^ keys[final_keys + i + 1]);
  }
  h ^= h >> 37;
  h *= 0x165667919E3779F9ull;
  h ^= h >> 32;
  return h;
}

}  // namespace

FrameChecksum::FrameChecksum() { std::copy(keys.begin(), keys.begin() + lanes, lanes_); }

void FrameChecksum::add(const void* data, size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  total_ += size;
  if (held_bytes_ > 0) {
    const size_t take = std::min(size, stripe_bytes - held_bytes_);
    std::memcpy(held_ + held_bytes_, p, take);
    held_bytes_ += take;
    p += take;
    size -= take;
    if (held_bytes_ < stripe_bytes) return;
    stripe_in_block_ = consume(lanes_, held_, 1, stripe_in_block_);
    held_bytes_ = 0;
  }
  const size_t whole = size / stripe_bytes;
  if (whole > 0) stripe_in_block_ = consume(lanes_, p, whole, stripe_in_block_);
  p += whole * stripe_bytes;
  size -= whole * stripe_bytes;
  std::memcpy(held_, p, size);
  held_bytes_ = size;
}

uint64_t FrameChecksum::finish() const {
  alignas(16) uint64_t acc[lanes];
  std::copy(lanes_, lanes_ + lanes, acc);
  if (held_bytes_ > 0) {  // the last partial stripe, zero-padded (the length tells it apart)
    unsigned char last[stripe_bytes] = {};
    std::memcpy(last, held_, held_bytes_);
    consume(acc, last, 1, stripe_in_block_);
  }
  return finish_lanes(acc, total_);
}

uint64_t frame_checksum(const void* data, size_t size) {
  FrameChecksum sum;
  sum.add(data, size);
  return sum.finish();
}

uint64_t frame_checksum_one_lane_at_a_time(const void* data, size_t size) {
  alignas(16) uint64_t acc[lanes];
  std::copy(keys.begin(), keys.begin() + lanes, acc);
  const auto* p = static_cast<const unsigned char*>(data);
  const size_t in_block = consume_scalar(acc, p, size / stripe_bytes, 0);
  const size_t held = size % stripe_bytes;
  if (held > 0) {
    unsigned char last[stripe_bytes] = {};
    std::memcpy(last, p + size - held, held);
    consume_scalar(acc, last, 1, in_block);
  }
  return finish_lanes(acc, size);
}

}  // namespace qemflow::engine
