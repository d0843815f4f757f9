#pragma once
// Small vector helpers for the partition kernels: Point doubles as a 3-vector.
// Every operation is written out in a fixed order so results are bit-identical
// on every run and thread count.
#include <cmath>

#include "util/geometry.hpp"

namespace qemflow::nodes::partition {

using Vec3 = Point;

inline Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline Vec3 add(const Vec3& a, const Vec3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline Vec3 scale(const Vec3& a, double s) { return {a[0] * s, a[1] * s, a[2] * s}; }
inline double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline double norm(const Vec3& a) { return std::sqrt(dot(a, a)); }
inline double squared_distance(const Vec3& a, const Vec3& b) {
  const Vec3 d = sub(a, b);
  return dot(d, d);
}

}  // namespace qemflow::nodes::partition
