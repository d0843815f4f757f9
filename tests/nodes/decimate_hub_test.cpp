// A vertex of very high degree (a fan of n triangles around one hub): every collapse on
// the rim touches the hub, so without kMaxCollapseDegree every rim vertex re-read the
// hub's n faces (validity and deviation charge of its edge to the hub) every round:
// O(n^2) per round (a 100k fan took 76 CPU-s, a 1M blob ~12). The work is counted,
// not timed: PatchDecimator::scanned_faces().
#include <gtest/gtest.h>

#include <cmath>

#include "nodes/decimate/cut.hpp"
#include "nodes/decimate/decimator.hpp"
#include "nodes/decimate/simplify.hpp"

namespace qemflow::nodes {
namespace {

// A flat disc: hub 0 at the centre, rim vertices 1..n on the unit circle, faces
// (hub, i, i + 1) counter-clockwise; open border on the rim.
PatchInput disc_fan(uint32_t n) {
  PatchInput in;
  in.positions.push_back({0.0, 0.0, 0.0});
  for (uint32_t i = 0; i < n; ++i) {
    const double a = 2.0 * M_PI * i / n;
    in.positions.push_back({std::cos(a), std::sin(a), 0.0});
  }
  for (uint32_t v = 0; v <= n; ++v) in.vertex_gids.push_back(v);
  for (uint32_t i = 0; i < n; ++i) {
    in.faces.push_back({0, 1 + i, 1 + (i + 1) % n});
    in.face_gids.push_back(i);
  }
  return in;
}

TEST(DecimateHub, AFanAroundOneVertexReadsFacesLinearlyInItsSize) {
  const uint32_t n = 4000;
  PatchDecimator d(disc_fan(n), {});
  const uint64_t target = n / 100;
  run_epochs(d, target, EpochOptions{});
  EXPECT_EQ(d.face_count(), target);
  // 292k here; without the cap 29.6M (7,400 per input face, growing with n).
  EXPECT_LT(d.scanned_faces(), 200u * n);
  // Simplified without a flip: every face still faces +z.
  const PatchOutput out = d.extract();
  for (const auto& t : out.faces) {
    const Vec3 &p = out.positions[t[0]], &q = out.positions[t[1]], &r = out.positions[t[2]];
    const double z = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    EXPECT_GT(z, 0.0);
  }
}

}  // namespace
}  // namespace qemflow::nodes
