#pragma once
// Approximate geodesic distance between two oriented surface points (PPDS, Bowers et
// al. 2010, §4.1): assume the surface between p and q is an arc of constant
// curvature whose end tangents are given by the normals. With v̂ the chord direction
// and c_p = n_p·v̂, c_q = n_q·v̂, the arc length is |v|·(asin c_p − asin c_q)/(c_p − c_q)
// (|v| when c_p = c_q). For a circle this is exact.
//
// Pairs that are close in space but lie on different sheets get +infinity ("not
// neighbours"): normals that disagree by more than `min_normal_dot`, or a chord that
// leaves either tangent plane more steeply than `max_chord_slope` (|c| = sine of the
// angle between chord and tangent plane). The result is symmetric to the bit: the
// pair is evaluated in a canonical (lexicographic) order.
#include <algorithm>
#include <cmath>
#include <limits>

#include "nodes/partition/vec3.hpp"

namespace qemflow::nodes::partition {

struct SheetLimits {
  double min_normal_dot = -0.5;   // normals more than 120° apart: different sheets
  double max_chord_slope = 0.9;   // chord more than ~64° out of a tangent plane
};

inline double approx_geodesic(const Point& p, const Vec3& np, const Point& q, const Vec3& nq,
                              const SheetLimits& limits) {
  if (q < p || (q == p && nq < np)) return approx_geodesic(q, nq, p, np, limits);
  constexpr double infinity = std::numeric_limits<double>::infinity();
  if (dot(np, nq) < limits.min_normal_dot) return infinity;
  const Vec3 chord = sub(q, p);
  const double length = norm(chord);
  if (length == 0.0) return 0.0;
  const double cp = dot(np, chord) / length;
  const double cq = dot(nq, chord) / length;
  if (std::abs(cp) > limits.max_chord_slope || std::abs(cq) > limits.max_chord_slope)
    return infinity;
  const double difference = cp - cq;
  if (std::abs(difference) < 1e-6) return length;
  return length * (std::asin(std::clamp(cp, -1.0, 1.0)) - std::asin(std::clamp(cq, -1.0, 1.0))) /
         difference;
}

}  // namespace qemflow::nodes::partition
