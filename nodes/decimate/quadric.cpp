#include "nodes/decimate/quadric.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

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
  const Vec3 n = cross(sub(p1, p0), sub(p2, p0));
  const double len = std::sqrt(dot(n, n));
  if (!(len > 0.0)) return {};
  const Vec3 unit{n[0] / len, n[1] / len, n[2] / len};
  return plane_quadric(unit, p0, 0.5 * len);
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
  Eigen::Matrix3d A;
  A << q[0], q[1], q[2], q[1], q[3], q[4], q[2], q[4], q[5];
  const Eigen::Vector3d b(q[6], q[7], q[8]);
  const Eigen::Vector3d mid(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2]));
  const double trace = q[0] + q[3] + q[5];
  if (!(trace > 0.0)) return {mid[0], mid[1], mid[2]};

  // Fast path: a clearly invertible A. det / trace^3 is about the product of the two
  // smaller eigenvalue ratios, so a small value flags a flat or crease-like quadric.
  const double det = A.determinant();
  if (det > 1e-7 * trace * trace * trace) {
    const Eigen::Vector3d x = A.inverse() * (-b);
    return {x[0], x[1], x[2]};
  }
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

}  // namespace qemflow::nodes
