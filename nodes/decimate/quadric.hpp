#pragma once
// Garland-Heckbert quadrics and the collapse placement/cost kernels.
//
// Contract: every function here is a pure function of its arguments, compiled once
// (not inline), so the same inputs give the same bits wherever they are called - in
// core or in any out-of-core patch. Callers that combine quadrics must do it in a
// canonical order (see decimator.hpp); addition of two quadrics is commutative in
// IEEE arithmetic, so Q_a + Q_b == Q_b + Q_a bit for bit.
#include <array>
#include <limits>
#include <span>

namespace qemflow::nodes {

using Vec3 = std::array<double, 3>;

// Symmetric 4x4 matrix [A b; b^T c] stored as its 10 upper-triangle entries:
// a00 a01 a02 a11 a12 a22 b0 b1 b2 c. Q(x) = x^T A x + 2 b.x + c.
struct Quadric {
  std::array<double, 10> q{};
  Quadric& operator+=(const Quadric& o) {
    for (int i = 0; i < 10; ++i) q[i] += o.q[i];
    return *this;
  }
  friend Quadric operator+(Quadric a, const Quadric& b) { return a += b; }
};

// weight * (n.x + d)^2 for the plane through `point` with unit normal `unit_normal`.
Quadric plane_quadric(const Vec3& unit_normal, const Vec3& point, double weight);

// Area-weighted plane quadric of triangle (p0,p1,p2); zero for a degenerate triangle.
Quadric face_quadric(const Vec3& p0, const Vec3& p1, const Vec3& p2);
// A triangle's plane from its unnormalised normal (p1 - p0) x (p2 - p0): the normal's
// length (twice the area) and the unit normal (zero when the length is not positive).
struct TrianglePlane {
  Vec3 unit;
  double length;
};
TrianglePlane triangle_plane(const Vec3& normal);
// face_quadric(p0, p1, p2) from the triangle's plane, bit for bit.
Quadric face_quadric(const TrianglePlane& plane, const Vec3& p0);

// Boundary-preserving quadric of the border edge (p,q) of a face with (unnormalised)
// normal `face_normal`: the plane through the edge perpendicular to the face,
// weighted by `weight` * |q - p|^2. Zero when degenerate.
Quadric boundary_quadric(const Vec3& p, const Vec3& q, const Vec3& face_normal, double weight);

// Q(x), clamped at 0 (rounding can make it slightly negative).
double quadric_error(const Quadric& quadric, const Vec3& x);

// The collapse position of an edge: the minimiser of `quadric` when its 3x3 part is
// well conditioned; otherwise the minimiser restricted to the well-conditioned
// eigen-directions, anchored at the edge midpoint (Lindstrom's stable fallback).
// `lo` / `hi` are the endpoints ordered by global id so both ends compute the same.
Vec3 collapse_position(const Quadric& quadric, const Vec3& lo, const Vec3& hi);

// Squared Euclidean distance from x to the closest point of triangle (p0,p1,p2)
// (a degenerate triangle: to its closest edge or vertex).
double point_triangle_distance2(const Vec3& x, const Vec3& p0, const Vec3& p1, const Vec3& p2);

using Triangle3 = std::array<Vec3, 3>;

// The deviation charge of a collapse (a, b) -> p, in the quadrics' units (area times
// squared distance): each endpoint stands for a third of its current faces' area
// (`area_a`, `area_b`) and is charged that area times its squared distance to the
// collapsed fan (`fan`: the faces of a and b that survive the collapse, with a and b
// moved to p). The quadric sums squared distances over the original surface, so a
// small feature (a tip, a thin rim: little area) is cheap to cut off however far the
// surface moves; this term prices the move of the surface the current mesh stands for.
double collapse_deviation(const Vec3& a, double area_a, const Vec3& b, double area_b,
                          std::span<const Triangle3> fan);

// collapse_deviation fed one triangle at a time, so a caller walking its mesh needs no
// copy of the fan. Each triangle's two distances are point_triangle_distance2's bits
// (its edge vectors are shared by both points, the same differences either way); the
// nearest distances are minima, so the order of the triangles does not matter. The
// triangles are buffered and measured kFanBlock at a time by a kernel compiled for the
// widest vector unit the CPU has (fan_kernel.cpp): every version gives the same bits.
inline constexpr int kFanBlock = 4;
// Row 3 * i + c: coordinate c of vertex i of each buffered triangle k, once; the kernel
// duplicates it into lanes 2k and 2k + 1 (the distances of a and of b), so `add` stores
// 9 doubles per triangle.
using FanRows = double[9][kFanBlock];

class FanDeviation {
 public:
  FanDeviation(const Vec3& a, const Vec3& b) : a_(a), b_(b) {}
  // Inline: only copies (the arithmetic is in the kernel, compiled once).
  void add(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
    const Vec3* p[3] = {&p0, &p1, &p2};
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) rows_[3 * i + c][pending_] = (*p[i])[c];
    if (++pending_ == kFanBlock) flush();
  }
  // collapse_deviation(a, area_a, b, area_b, the triangles added).
  double charge(double area_a, double area_b);

 private:
  void flush();
  alignas(64) FanRows rows_;
  Vec3 a_, b_;
  double nearest_[2] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  int pending_ = 0;
  bool empty_ = true;
};

// The versions of FanDeviation's kernel, one per instruction set (same bits). AVX2 is
// used where the CPU runs it (AVX-512F was no faster: nodes/decimate/README.md), else
// SSE2, unless QEMFLOW_FAN_KERNEL (sse2, avx2, avx512) names another one it runs.
enum class FanKernel { kSse2, kAvx2, kAvx512 };
FanKernel fan_kernel();
// Testing: use `kernel` from now on; false (nothing changes) when the CPU lacks it.
bool use_fan_kernel(FanKernel kernel);

}  // namespace qemflow::nodes
