// The deviation charge (quadric.hpp collapse_deviation, DecimateParams::deviation_weight):
// the point-triangle distance it rests on, the charge on hand-made fans, and its
// purpose - a thin spike keeps its tip where the pure quadric cost cuts it off.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "nodes/decimate/quadric.hpp"
#include "nodes/decimate/simplify.hpp"
#include "tests/nodes/mesh_fixtures.hpp"

namespace qemflow::nodes {
namespace {

TEST(PointTriangleDistance, EachVoronoiRegionOfTheTriangle) {
  const Vec3 a{0, 0, 0}, b{2, 0, 0}, c{0, 2, 0};
  EXPECT_DOUBLE_EQ(point_triangle_distance2({0.5, 0.5, 3}, a, b, c), 9.0);   // face
  EXPECT_DOUBLE_EQ(point_triangle_distance2({-1, -1, 0}, a, b, c), 2.0);     // vertex a
  EXPECT_DOUBLE_EQ(point_triangle_distance2({3, 0, 1}, a, b, c), 2.0);       // vertex b
  EXPECT_DOUBLE_EQ(point_triangle_distance2({1, -2, 0}, a, b, c), 4.0);      // edge ab
  EXPECT_DOUBLE_EQ(point_triangle_distance2({-3, 1, 0}, a, b, c), 9.0);      // edge ac
  EXPECT_DOUBLE_EQ(point_triangle_distance2({2, 2, 0}, a, b, c), 2.0);       // edge bc
  // Degenerate (collinear) triangle: the distance to the segment.
  EXPECT_DOUBLE_EQ(point_triangle_distance2({1, 1, 0}, a, b, {1, 0, 0}), 1.0);
}

TEST(CollapseDeviation, FlatFanIsFreeAndACutTipPaysItsAreaTimesTheDistance) {
  // A flat fan around the origin: moving the centre within the plane costs nothing.
  std::vector<Triangle3> flat;
  const Vec3 p{0.1, 0, 0};
  const int n = 6;
  for (int i = 0; i < n; ++i) {
    const double t0 = 2 * M_PI * i / n, t1 = 2 * M_PI * (i + 1) / n;
    flat.push_back({p, Vec3{std::cos(t0), std::sin(t0), 0}, Vec3{std::cos(t1), std::sin(t1), 0}});
  }
  EXPECT_LT(collapse_deviation({0, 0, 0}, 3.0, {0.2, 0, 0}, 3.0, flat), 1e-20);
  // The same ring with the centre raised to a tip at height 1, collapsed to p in the
  // plane: the tip is charged a third of its area times its squared height.
  EXPECT_DOUBLE_EQ(collapse_deviation({0, 0, 1}, 3.0, p, 0.0, flat), 1.0);
  EXPECT_EQ(collapse_deviation({0, 0, 1}, 3.0, p, 0.0, {}), 0.0);
}

// A unit sphere with a narrow rounded bump (a Gaussian of width `width` radians) of
// height `height` on its +z pole. The radii are jittered by 1e-4 so that no two edges
// cost exactly the same: the outcome must not hinge on how ties are broken.
qemflow::testing::Mesh bumpy_sphere(double height, double width) {
  auto m = qemflow::testing::icosphere(5, 1e-4);  // 20480 faces
  for (auto& q : m.points) {
    const double r = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    const double angle = std::acos(std::clamp(q[2] / r, -1.0, 1.0)) / width;
    const double s = 1.0 + height * std::exp(-angle * angle);
    for (double& x : q) x *= s / r;
  }
  return m;
}

double distance_to_mesh(const Vec3& x, const SimplifyResult& r) {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : r.triangles)
    best = std::min(best, point_triangle_distance2(x, r.points[t[0]], r.points[t[1]], r.points[t[2]]));
  return std::sqrt(best);
}

TEST(CollapseDeviation, ANarrowBumpKeepsItsTipWhereThePureQuadricCutsItOff) {
  // A spike 0.3 high and about 0.03 wide, far below the output's edge length (~0.38):
  // little area, so the quadric alone cuts it off; the charge keeps its tip.
  const auto original = bumpy_sphere(0.3, 0.03);
  const Vec3 tip = *std::max_element(original.points.begin(), original.points.end(),
                                     [](const Point& x, const Point& y) { return x[2] < y[2]; });
  auto simplify = [&](double weight, double new_fold_cos, double charge_from) {
    auto m = original;
    SimplifyOptions o;
    o.target_faces = 200;
    o.params.deviation_weight = weight;
    o.params.new_fold_cos = new_fold_cos;
    o.epochs.charge_from = charge_from;
    const auto r = simplify_in_core(std::move(m.points), std::move(m.triangles), o);
    EXPECT_EQ(r.triangles.size(), 200u);
    return distance_to_mesh(tip, r);
  };
  const double no_fold_check = -1.0;
  EXPECT_GT(simplify(0.0, no_fold_check, 0.0), 0.1);
  EXPECT_LT(simplify(DecimateParams{}.deviation_weight, no_fold_check, 0.0), 0.003);
  // Cutting the spike off folds its faces onto each other, which the fold check
  // (DecimateParams::new_fold_cos, on by default) refuses on a surface without folds:
  // it keeps the tip for the quadric alone too, and with the charge only in the last
  // stretch (--charge-from 2).
  const double fold_check = DecimateParams{}.new_fold_cos;
  EXPECT_LT(simplify(0.0, fold_check, 0.0), 0.003);
  EXPECT_LT(simplify(DecimateParams{}.deviation_weight, fold_check, 2.0), 0.003);
  EXPECT_LT(simplify(DecimateParams{}.deviation_weight, fold_check, 0.0), 0.003);
}

}  // namespace
}  // namespace qemflow::nodes
