// PatchDecimator::prepare_owned_summary_round: a patch's last prepare refreshes only
// the vertices near its owned part, yet its summary, owned candidates and extract (with
// the carried bests) are prepare_round()'s, bit for bit.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>

#include "mesh_fixtures.hpp"
#include "nodes/decimate/decimator.hpp"

namespace qemflow::nodes {
namespace {

// A noisy sphere as one patch that owns the faces whose centroid has x in a narrow band
// (most owned candidates then read bests outside the owned faces' corners),
// with the vertices of x > 0.85 given as incomplete (untrusted state at the far side,
// as a halo's edge has).
PatchInput capped_sphere_patch() {
  const testing::Mesh m = testing::icosphere(5, 0.05, 3);
  PatchInput in;
  for (size_t v = 0; v < m.points.size(); ++v) {
    in.positions.push_back(m.points[v]);
    in.vertex_gids.push_back(v);
    in.incomplete.push_back(m.points[v][0] > 0.85);
  }
  std::vector<int64_t> first_face(m.points.size(), -1);
  for (size_t f = 0; f < m.triangles.size(); ++f) {
    const auto& t = m.triangles[f];
    in.faces.push_back({uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2])});
    in.face_gids.push_back(f);
    double x = 0;
    for (uint64_t v : t) x += m.points[v][0] / 3;
    in.owned_face.push_back(std::abs(x + 0.3) < 0.04);
    for (uint64_t v : t)
      if (first_face[v] < 0) first_face[v] = int64_t(f);
  }
  for (size_t v = 0; v < m.points.size(); ++v)
    in.owned_vertex.push_back(!in.incomplete[v] && in.owned_face[size_t(first_face[v])]);
  return in;
}

// Runs `rounds` blind rounds, each cut at the median candidate key of the round.
void run_rounds(PatchDecimator& d, int rounds) {
  for (int r = 0; r < rounds; ++r) {
    d.prepare_round();
    const auto candidates = d.candidates();
    ASSERT_FALSE(candidates.empty());
    d.apply_cut({candidates[candidates.size() / 2].key});
  }
}

bool same_bits(double a, double b) { return std::bit_cast<uint64_t>(a) == std::bit_cast<uint64_t>(b); }

TEST(DecimateOwnedSummary, EqualsAFullPrepareOnTheOwnedPartAndRefreshesLess) {
  const DecimateParams params;
  PatchDecimator full(capped_sphere_patch(), params), near(capped_sphere_patch(), params);
  run_rounds(full, 3);
  run_rounds(near, 3);
  const uint64_t full_before = full.refreshes(), near_before = near.refreshes();
  ASSERT_EQ(full_before, near_before);
  full.prepare_round();
  near.prepare_owned_summary_round();
  // The restriction is real: the far side (about half the sphere) is not refreshed.
  EXPECT_LT(2 * (near.refreshes() - near_before), full.refreshes() - full_before);

  const RoundSummary a = full.summarize(), b = near.summarize();
  EXPECT_GT(a.candidates, 20u);
  EXPECT_EQ(a.candidates, b.candidates);
  EXPECT_EQ(a.candidate_faces, b.candidate_faces);
  EXPECT_EQ(a.inexact_candidates, b.inexact_candidates);
  EXPECT_EQ(a.faces_per_bin, b.faces_per_bin);
  const auto ca = full.owned_candidates(), cb = near.owned_candidates();
  ASSERT_EQ(ca.size(), cb.size());
  for (size_t i = 0; i < ca.size(); ++i) {
    EXPECT_TRUE(same_bits(ca[i].key.cost, cb[i].key.cost));
    EXPECT_EQ(ca[i].key.gid_lo, cb[i].key.gid_lo);
    EXPECT_EQ(ca[i].key.gid_hi, cb[i].key.gid_hi);
    EXPECT_EQ(full.vertex_gid(ca[i].keep), near.vertex_gid(cb[i].keep));
  }

  const PatchOutput oa = full.extract(), ob = near.extract();
  ASSERT_FALSE(oa.best_gids.empty());
  EXPECT_EQ(oa.vertex_gids, ob.vertex_gids);
  EXPECT_EQ(oa.face_gids, ob.face_gids);
  EXPECT_EQ(oa.faces, ob.faces);
  EXPECT_EQ(oa.degrees, ob.degrees);
  EXPECT_EQ(oa.trusted, ob.trusted);
  EXPECT_EQ(oa.best_gids, ob.best_gids);
  ASSERT_EQ(oa.best_costs.size(), ob.best_costs.size());
  for (size_t i = 0; i < oa.best_costs.size(); ++i) EXPECT_TRUE(same_bits(oa.best_costs[i], ob.best_costs[i]));
  ASSERT_EQ(oa.positions.size(), ob.positions.size());
  EXPECT_EQ(0, std::memcmp(oa.positions.data(), ob.positions.data(), oa.positions.size() * sizeof(Vec3)));

  // Final: the far side's bests are stale, so nothing may run on, and the diagnostic
  // extract of every face carries no bests.
  EXPECT_THROW(near.prepare_round(), std::logic_error);
  EXPECT_THROW(near.apply_cut({ca.front().key}), std::logic_error);
  EXPECT_TRUE(near.extract(false).best_gids.empty());
}

}  // namespace
}  // namespace qemflow::nodes
