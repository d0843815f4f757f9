#pragma once
// Small inline vector arithmetic on qemflow::Point (array<double,3>) for the measure
// kernels. Plain functions, no expression templates: the hot loops stay readable and
// the compiler inlines them.
#include <cmath>

#include "util/geometry.hpp"

namespace qemflow::measure {

inline Point operator-(const Point& a, const Point& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline Point operator+(const Point& a, const Point& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline Point operator*(double s, const Point& a) { return {s * a[0], s * a[1], s * a[2]}; }
inline double dot(const Point& a, const Point& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline Point cross(const Point& a, const Point& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline double squared_length(const Point& a) { return dot(a, a); }
inline double squared_distance(const Point& a, const Point& b) { return squared_length(a - b); }

// Twice the area vector of triangle abc (its unnormalised normal).
inline Point triangle_normal(const Point& a, const Point& b, const Point& c) { return cross(b - a, c - a); }
inline double triangle_area(const Point& a, const Point& b, const Point& c) {
  return 0.5 * std::sqrt(squared_length(triangle_normal(a, b, c)));
}

}  // namespace qemflow::measure
