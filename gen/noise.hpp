#pragma once
// Deterministic noise for the generator. Every value is a pure function of integer
// lattice coordinates and a seed (a counter-based hash, no std:: random engines, whose
// streams differ between library versions), evaluated with +, -, *, floor only, so a
// vertex gets the same bits on every run and on every thread that computes it.
#include <cmath>
#include <cstdint>

#include "util/hash.hpp"

namespace qemflow::gen::noise {

inline uint64_t mix(uint64_t x) { return mix64(x); }

inline uint64_t hash(uint64_t seed, int64_t a, int64_t b = 0, int64_t c = 0) {
  return mix(seed + static_cast<uint64_t>(a) * 0x9e3779b97f4a7c15ULL +
             static_cast<uint64_t>(b) * 0xc2b2ae3d27d4eb4fULL +
             static_cast<uint64_t>(c) * 0x165667b19e3779f9ULL);
}

// A hash mapped to [-1, 1).
inline double signed_unit(uint64_t h) {
  return static_cast<double>(h >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

// A fresh seed per purpose, so the streams of different uses never coincide.
inline uint64_t derive(uint64_t seed, uint64_t purpose) { return mix(seed ^ mix(purpose + 1)); }

inline double fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }
inline double lerp(double a, double b, double t) { return a + t * (b - a); }

// Perlin's twelve cube-edge gradients, chosen per lattice corner by the hash.
inline double corner(uint64_t seed, int64_t x, int64_t y, int64_t z, double dx, double dy, double dz) {
  switch ((hash(seed, x, y, z) >> 32) % 12) {
    case 0: return dx + dy;
    case 1: return -dx + dy;
    case 2: return dx - dy;
    case 3: return -dx - dy;
    case 4: return dx + dz;
    case 5: return -dx + dz;
    case 6: return dx - dz;
    case 7: return -dx - dz;
    case 8: return dy + dz;
    case 9: return -dy + dz;
    case 10: return dy - dz;
    default: return -dy - dz;
  }
}

// Gradient noise in about [-1, 1], zero at lattice points.
inline double gradient(uint64_t seed, double x, double y, double z) {
  const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
  const auto ix = static_cast<int64_t>(fx), iy = static_cast<int64_t>(fy), iz = static_cast<int64_t>(fz);
  const double tx = x - fx, ty = y - fy, tz = z - fz;
  const double u = fade(tx), v = fade(ty), w = fade(tz);
  const double c000 = corner(seed, ix, iy, iz, tx, ty, tz);
  const double c100 = corner(seed, ix + 1, iy, iz, tx - 1, ty, tz);
  const double c010 = corner(seed, ix, iy + 1, iz, tx, ty - 1, tz);
  const double c110 = corner(seed, ix + 1, iy + 1, iz, tx - 1, ty - 1, tz);
  const double c001 = corner(seed, ix, iy, iz + 1, tx, ty, tz - 1);
  const double c101 = corner(seed, ix + 1, iy, iz + 1, tx - 1, ty, tz - 1);
  const double c011 = corner(seed, ix, iy + 1, iz + 1, tx, ty - 1, tz - 1);
  const double c111 = corner(seed, ix + 1, iy + 1, iz + 1, tx - 1, ty - 1, tz - 1);
  return lerp(lerp(lerp(c000, c100, u), lerp(c010, c110, u), v),
              lerp(lerp(c001, c101, u), lerp(c011, c111, u), v), w);
}

// Each octave is rotated (a fixed orthogonal-ish shear) and offset so that the lattices
// of successive octaves do not line up into visible grid artefacts.
inline void next_octave(double& x, double& y, double& z) {
  const double nx = 1.60 * x + 1.20 * y;
  const double ny = -1.20 * x + 1.60 * y;
  const double nz = 2.0 * z;
  x = nx + 17.31;
  y = ny - 5.73;
  z = nz + 9.17;
}

// Fractal sum of `octaves` gradient-noise octaves (gain 1/2), normalised to about [-1, 1].
inline double fbm(uint64_t seed, double x, double y, double z, int octaves) {
  double sum = 0, amplitude = 1, total = 0;
  for (int o = 0; o < octaves; ++o) {
    sum += amplitude * gradient(seed + static_cast<uint64_t>(o), x, y, z);
    total += amplitude;
    amplitude *= 0.5;
    next_octave(x, y, z);
  }
  return sum / total;
}

// Ridged multifractal (Musgrave): sharp crests where the noise crosses zero, each
// octave weighted by the one before so detail gathers on the ridges. About [0, 1].
inline double ridged(uint64_t seed, double x, double y, double z, int octaves) {
  double sum = 0, amplitude = 1, total = 0, weight = 1;
  for (int o = 0; o < octaves; ++o) {
    double ridge = 1.0 - std::fabs(gradient(seed + static_cast<uint64_t>(o), x, y, z));
    ridge *= ridge * weight;
    weight = ridge * 2.0;
    if (weight > 1) weight = 1;
    sum += amplitude * ridge;
    total += amplitude;
    amplitude *= 0.5;
    next_octave(x, y, z);
  }
  return sum / total;
}

}  // namespace qemflow::gen::noise
