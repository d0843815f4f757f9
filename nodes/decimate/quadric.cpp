#include "nodes/decimate/quadric.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

namespace qemflow::nodes {
namespace {

Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

}  // namespace

Quadric plane_quadric(const Vec3& n, const Vec3& point, double weight) {
  const double d = -dot(n, point);
  Quadric r;
  r.q = {weight * n[0] * n[0], weight * n[0] * n[1], weight * n[0] * n[2],
         weight * n[1] * n[1], weight * n[1] * n[2], weight * n[2] * n[2],
         weight * n[0] * d,    weight * n[1] * d,    weight * n[2] * d,
         weight * d * d};
  return r;
}

Quadric face_quadric(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  return face_quadric(triangle_plane(cross(sub(p1, p0), sub(p2, p0))), p0);
}

TrianglePlane triangle_plane(const Vec3& n) {
  const double len = std::sqrt(dot(n, n));
  return {len > 0.0 ? Vec3{n[0] / len, n[1] / len, n[2] / len} : Vec3{0, 0, 0}, len};
}

Quadric face_quadric(const TrianglePlane& plane, const Vec3& p0) {
  if (!(plane.length > 0.0)) return {};
  return plane_quadric(plane.unit, p0, 0.5 * plane.length);
}

Quadric boundary_quadric(const Vec3& p, const Vec3& q, const Vec3& face_normal, double weight) {
  const Vec3 e = sub(q, p);
  const Vec3 m = cross(e, face_normal);
  const double len = std::sqrt(dot(m, m));
  const double e2 = dot(e, e);
  if (!(len > 0.0) || !(e2 > 0.0)) return {};
  const Vec3 unit{m[0] / len, m[1] / len, m[2] / len};
  return plane_quadric(unit, p, weight * e2);
}

double quadric_error(const Quadric& Q, const Vec3& x) {
  const auto& q = Q.q;
  const double ax0 = q[0] * x[0] + q[1] * x[1] + q[2] * x[2];
  const double ax1 = q[1] * x[0] + q[3] * x[1] + q[4] * x[2];
  const double ax2 = q[2] * x[0] + q[4] * x[1] + q[5] * x[2];
  const double e = x[0] * (ax0 + 2.0 * q[6]) + x[1] * (ax1 + 2.0 * q[7]) +
                   x[2] * (ax2 + 2.0 * q[8]) + q[9];
  return e > 0.0 ? e : 0.0;
}

Vec3 collapse_position(const Quadric& Q, const Vec3& lo, const Vec3& hi) {
  const auto& q = Q.q;
  const Eigen::Vector3d mid(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2]));
  const double trace = q[0] + q[3] + q[5];
  if (!(trace > 0.0)) return {mid[0], mid[1], mid[2]};

  // Fast path: a clearly invertible A. det / trace^3 is about the product of the two
  // smaller eigenvalue ratios, so a small value flags a flat or crease-like quadric.
  // Written out, Eigen 3.4's A.determinant() and A.inverse() * (-b) for this symmetric
  // A, operation for operation (cofactors, the inverse's det from the first column's,
  // rows 0-1 of the product summed left to right as its packets do, row 2 as its redux,
  // p0 + (p1 + p2)): the same bits on every finite input (NaNs aside: their payloads may
  // differ, and a non-finite position is skipped either way); Eigen's product was not
  // inlined here. A is symmetric, so its cofactors are too, to the bit (the same
  // products, commuted), and determinant()'s own sum equals the inverse's wherever it is
  // positive (x - (-y) is x + y; only a zero's sign may differ): one det serves both.
  const double c00 = q[3] * q[5] - q[4] * q[4], c01 = q[4] * q[2] - q[5] * q[1],
               c02 = q[1] * q[4] - q[2] * q[3];
  const double det = (c00 * q[0] + c01 * q[1]) + c02 * q[2];
  if (det > 1e-7 * trace * trace * trace) {
    const double c11 = q[5] * q[0] - q[2] * q[2], c12 = q[2] * q[1] - q[0] * q[4],
                 c22 = q[0] * q[3] - q[1] * q[1];
    const double inv = 1.0 / det;
    const double r00 = c00 * inv, r01 = c01 * inv, r02 = c02 * inv, r11 = c11 * inv, r12 = c12 * inv,
                 r22 = c22 * inv;
    const double b0 = -q[6], b1 = -q[7], b2 = -q[8];
    return {(r00 * b0 + r01 * b1) + r02 * b2, (r01 * b0 + r11 * b1) + r12 * b2, r02 * b0 + (r12 * b1 + r22 * b2)};
  }
  Eigen::Matrix3d A;
  A << q[0], q[1], q[2], q[1], q[3], q[4], q[2], q[4], q[5];
  const Eigen::Vector3d b(q[6], q[7], q[8]);
  // Stable fallback: solve in the eigen-directions that are well determined, keep the
  // midpoint's coordinates along the others.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(A);
  const Eigen::Vector3d lambda = eig.eigenvalues();
  const Eigen::Matrix3d V = eig.eigenvectors();
  const double lambda_max = std::max({lambda[0], lambda[1], lambda[2]});
  const Eigen::Vector3d residual = -(A * mid + b);
  Eigen::Vector3d x = mid;
  for (int i = 0; i < 3; ++i) {
    if (lambda[i] > 1e-4 * lambda_max) {
      const Eigen::Vector3d v = V.col(i);
      x += v * (v.dot(residual) / lambda[i]);
    }
  }
  return {x[0], x[1], x[2]};
}

namespace {

// point_triangle_distance2 given the edge vectors ab = b - a and ac = c - a (the call
// was a sixth of its cost when inlined). FanDeviation's kernel (fan_kernel.inc)
// computes the same values without branches.
[[gnu::always_inline]] inline double distance2_with_edges(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c,
                                   const Vec3& ab, const Vec3& ac) {
  // Ericson, Real-Time Collision Detection 5.1.5: the Voronoi region of x decides
  // which feature (vertex, edge, face) is closest.
  auto at = [](const Vec3& o, const Vec3& u, double s, const Vec3& v, double t) {
    return Vec3{o[0] + s * u[0] + t * v[0], o[1] + s * u[1] + t * v[1], o[2] + s * u[2] + t * v[2]};
  };
  auto dist2 = [&](const Vec3& y) {
    const Vec3 d = sub(x, y);
    return dot(d, d);
  };
  const Vec3 ax = sub(x, a);
  const double d1 = dot(ab, ax), d2 = dot(ac, ax);
  if (d1 <= 0.0 && d2 <= 0.0) return dist2(a);
  const Vec3 bx = sub(x, b);
  const double d3 = dot(ab, bx), d4 = dot(ac, bx);
  if (d3 >= 0.0 && d4 <= d3) return dist2(b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return dist2(at(a, ab, d1 / (d1 - d3), ac, 0.0));
  const Vec3 cx = sub(x, c);
  const double d5 = dot(ab, cx), d6 = dot(ac, cx);
  if (d6 >= 0.0 && d5 <= d6) return dist2(c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return dist2(at(a, ab, 0.0, ac, d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const Vec3 bc = sub(c, b);
    return dist2(at(b, bc, (d4 - d3) / ((d4 - d3) + (d5 - d6)), bc, 0.0));
  }
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return std::min({dist2(a), dist2(b), dist2(c)});  // degenerate
  return dist2(at(a, ab, vb / sum, ac, vc / sum));
}

}  // namespace

double point_triangle_distance2(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c) {
  return distance2_with_edges(x, a, b, c, sub(b, a), sub(c, a));
}

double FanDeviation::charge(double area_a, double area_b) {
  if (pending_ > 0) flush();
  if (empty_) return 0.0;
  return area_a / 3.0 * nearest_[0] + area_b / 3.0 * nearest_[1];
}

double collapse_deviation(const Vec3& a, double area_a, const Vec3& b, double area_b,
                          std::span<const Triangle3> fan) {
  FanDeviation deviation(a, b);
  for (const Triangle3& t : fan) deviation.add(t[0], t[1], t[2]);
  return deviation.charge(area_a, area_b);
}

}  // namespace qemflow::nodes
