#pragma once
// Exact closest point on a triangle to a query point: Ericson, "Real-Time Collision
// Detection" §5.1.5 (ClosestPtPointTriangle). Works on degenerate triangles too (a
// segment or a point): every Voronoi-region test falls through to an edge or vertex.
#include "measure/vec3.hpp"

namespace qemflow::measure {

inline Point closest_point_on_segment(const Point& p, const Point& a, const Point& b) {
  const Point ab = b - a;
  const double length2 = squared_length(ab);
  if (!(length2 > 0.0)) return a;
  double t = dot(p - a, ab) / length2;
  t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
  return a + t * ab;
}

inline Point closest_point_on_triangle(const Point& p, const Point& a, const Point& b, const Point& c) {
  const Point ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;

  const Point bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) return b;

  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    // d1 - d3 = |ab|^2 (up to rounding): zero when a and b coincide.
    return d1 - d3 > 0.0 ? a + (d1 / (d1 - d3)) * ab : closest_point_on_segment(p, a, c);
  }

  const Point cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) return c;

  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    return d2 - d6 > 0.0 ? a + (d2 / (d2 - d6)) * ac : closest_point_on_segment(p, a, b);
  }

  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double bc = (d4 - d3) + (d5 - d6);
    return bc > 0.0 ? b + ((d4 - d3) / bc) * (c - b) : closest_point_on_segment(p, a, b);
  }

  // Inside the face. A degenerate triangle can reach here with va+vb+vc == 0 through
  // rounding; its closest point then lies on one of its edges.
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) {
    Point best = closest_point_on_segment(p, a, b);
    for (const Point& q : {closest_point_on_segment(p, b, c), closest_point_on_segment(p, c, a)})
      if (squared_distance(p, q) < squared_distance(p, best)) best = q;
    return best;
  }
  const double denom = 1.0 / sum;
  const double v = vb * denom, w = vc * denom;
  return a + v * ab + w * ac;
}

inline double squared_distance_point_triangle(const Point& p, const Point& a, const Point& b, const Point& c) {
  return squared_distance(p, closest_point_on_triangle(p, a, b, c));
}

}  // namespace qemflow::measure
