#pragma once
// Deterministic area-weighted surface sampling (Metro's face sampling).
//
// Every random number is a counter-based hash of (seed, global face id, counter), so
// a face's samples are the same on every run, for every thread count and however the
// mesh is split into chunks: no generator state is shared or carried between faces.
// A face of area a gets floor(a * density + u) samples, u uniform in [0,1) from the
// same hash, so the expected count is exactly a * density and the count is unbiased
// for faces much smaller than 1/density. Points are uniform on the triangle
// (the square-root warp of two uniforms to barycentric coordinates).
#include <cmath>
#include <cstdint>

#include "measure/vec3.hpp"
#include "util/hash.hpp"

namespace qemflow::measure {

inline uint64_t sample_hash(uint64_t seed, uint64_t face, uint64_t counter) {
  return mix64(mix64(seed ^ mix64(face + 0x9e3779b97f4a7c15ULL)) + counter * 0xd1b54a32d192ed03ULL);
}


inline constexpr uint64_t kSampleCountCounter = ~0ULL;  // the counter reserved for the count's u

inline uint64_t face_sample_count(double area, double density, uint64_t seed, uint64_t face) {
  const double expected = area * density;
  if (!(expected > 0)) return 0;
  const double u = unit_double(sample_hash(seed, face, kSampleCountCounter));
  return static_cast<uint64_t>(std::floor(expected + u));
}

// Sample number `k` of face `face` with corners a, b, c.
inline Point face_sample(const Point& a, const Point& b, const Point& c, uint64_t seed, uint64_t face,
                         uint64_t k) {
  const uint64_t bits = sample_hash(seed, face, k);
  const double r1 = unit_double(bits);
  const double r2 = unit_double(mix64(bits ^ 0x6a09e667f3bcc909ULL));
  const double s = std::sqrt(r1);
  const double wa = 1.0 - s, wb = s * (1.0 - r2), wc = s * r2;
  return {wa * a[0] + wb * b[0] + wc * c[0], wa * a[1] + wb * b[1] + wc * c[1],
          wa * a[2] + wb * b[2] + wc * c[2]};
}

}  // namespace qemflow::measure
