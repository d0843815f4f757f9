// The epoch form of G and trust tracking (nodes/decimate/README.md): the in-core run
// with E rounds per epoch is deterministic and exact; and a two-patch simulation of
// the out-of-core schedule (owned faces + a k-ring halo per patch, one global plan per
// epoch from summed summaries, state exchanged through the owned outputs at each
// epoch's end) gives the in-core result bit for bit.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <bit>
#include <map>
#include <optional>
#include <set>
#include <span>

#include "nodes/decimate/cut.hpp"
#include "nodes/decimate/simplify.hpp"
#include "tests/nodes/mesh_fixtures.hpp"

namespace qemflow::nodes {
namespace {

using qemflow::testing::Mesh;

PatchInput whole_patch(const Mesh& m) {
  PatchInput in;
  in.positions.assign(m.points.begin(), m.points.end());
  in.vertex_gids.resize(m.points.size());
  for (size_t i = 0; i < m.points.size(); ++i) in.vertex_gids[i] = i;
  for (size_t f = 0; f < m.triangles.size(); ++f) {
    const auto& t = m.triangles[f];
    in.faces.push_back({uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2])});
    in.face_gids.push_back(f);
  }
  return in;
}

// A mesh keyed by global ids: what the out-of-core pipeline holds between epochs.
struct GlobalMesh {
  std::map<uint64_t, std::array<uint64_t, 3>> faces;  // face gid -> vertex gids
  struct Vertex {
    Vec3 position;
    Quadric quadric;
    uint8_t locked = 0;
    uint64_t best_gid = kBestUnknown;  // carried best edge (Simulation::carry)
    double best_cost = 0.0;
  };
  std::map<uint64_t, Vertex> vertices;
};

GlobalMesh in_core_result(const Mesh& m, uint64_t target, const EpochOptions& options,
                          EpochRunStats* stats = nullptr, const DecimateParams& params = {},
                          DecimatorWork* work = nullptr) {
  PatchDecimator d(whole_patch(m), params);
  const EpochRunStats st = run_epochs(d, target, options);
  if (stats) *stats = st;
  if (work) *work = d.work();
  const PatchOutput out = d.extract();
  GlobalMesh g;
  for (size_t i = 0; i < out.faces.size(); ++i)
    g.faces[out.face_gids[i]] = {out.vertex_gids[out.faces[i][0]], out.vertex_gids[out.faces[i][1]],
                                 out.vertex_gids[out.faces[i][2]]};
  for (size_t i = 0; i < out.positions.size(); ++i)
    g.vertices[out.vertex_gids[i]] = {out.positions[i], out.quadrics[i], out.locked[i]};
  return g;
}

bool same_bits(const Vec3& a, const Vec3& b) {
  for (int k = 0; k < 3; ++k)
    if (std::bit_cast<uint64_t>(a[k]) != std::bit_cast<uint64_t>(b[k])) return false;
  return true;
}
bool same_bits(const Quadric& a, const Quadric& b) {
  for (int k = 0; k < 10; ++k)
    if (std::bit_cast<uint64_t>(a.q[k]) != std::bit_cast<uint64_t>(b.q[k])) return false;
  return true;
}

void expect_same_mesh(const GlobalMesh& a, const GlobalMesh& b) {
  ASSERT_EQ(a.faces, b.faces);
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  for (const auto& [gid, v] : a.vertices) {
    const auto it = b.vertices.find(gid);
    ASSERT_NE(it, b.vertices.end()) << gid;
    ASSERT_TRUE(same_bits(v.position, it->second.position)) << "vertex " << gid;
  }
}

// The out-of-core schedule with two patches split by the plane x = split (faces owned
// by their ORIGINAL barycenter side), each with a `halo`-ring halo grown by BFS over
// the current global mesh. A patch that reports 'halo too small' (an owned inexact
// candidate, or an untrusted vertex on an owned face) makes the epoch restart from
// the saved state with a deeper halo, as the pipeline would. Each epoch first tries a
// halo 1 ring shallower than the last one that worked, so halos stay as tight as the
// trust rule allows: a trust rule that trusted too much would then show up as a
// difference from the in-core result.
struct Simulation {
  const Mesh& mesh;
  uint64_t target;
  EpochOptions options;
  int halo;
  double split = 0.0;
  int max_halo_used = 0, halo_growths = 0;
  uint64_t epochs = 0;

  std::vector<int> original_side;
  // The in-core decimator, run in lockstep: every TRUSTED vertex of every patch (halo
  // included) must have the in-core state at each epoch's end - the trust rule itself,
  // checked directly, not only through the owned outputs.
  PatchDecimator* reference = nullptr;
  uint64_t trusted_checked = 0;
  // Carry each vertex's best edge from an epoch's end (a plain prepare_round before the
  // exchange) to the next epoch's patches, as the pipeline does; cleared when the
  // guards relax. Counted: bests restored, and refreshes of the epochs' first prepare.
  bool carry = false;
  uint64_t restored = 0, first_refreshes = 0;
  // Rounds after an epoch's first prepared with the cut known, as the pipeline does
  // (prepare_round(cut): vertices above it are left stale), not with a plain prepare.
  bool blind = false;
  // The patches' work skipped at frozen vertices (PatchDecimator::frozen_refreshes,
  // frozen_collapses), and the refreshes they ran, summed over every patch built.
  uint64_t frozen_refreshes = 0, frozen_collapses = 0, patch_refreshes = 0;
  // Epoch attempts (halo retries included) whose summary weighed the deviation charge
  // (EpochOptions::charge_from).
  uint64_t charged_epochs = 0;

  void run_plan(std::span<PatchDecimator* const> ds, const EpochPlan& plan,
                const std::optional<RoundCut>& exact) const {
    if (plan.kind == EpochPlan::Kind::exact_cut) {
      for (auto* d : ds) d->apply_cut(*exact);
      return;
    }
    for (auto* d : ds) d->apply_cut(plan.cuts.front());
    for (size_t r = 1; r < plan.cuts.size(); ++r)
      for (auto* d : ds) {
        if (blind)
          d->prepare_round(plan.cuts[r]);
        else
          d->prepare_round();
        d->apply_cut(plan.cuts[r]);
      }
  }

  void check_trusted_against_reference(std::vector<PatchDecimator>& patches) {
    const PatchOutput ref = reference->extract(false);
    std::map<uint64_t, size_t> at;
    std::map<uint64_t, std::set<std::pair<uint64_t, std::array<uint64_t, 3>>>> ref_fan;
    for (size_t i = 0; i < ref.vertex_gids.size(); ++i) at[ref.vertex_gids[i]] = i;
    for (size_t f = 0; f < ref.faces.size(); ++f) {
      const auto& t = ref.faces[f];
      const std::array<uint64_t, 3> g = {ref.vertex_gids[t[0]], ref.vertex_gids[t[1]], ref.vertex_gids[t[2]]};
      for (uint64_t v : g) ref_fan[v].insert({ref.face_gids[f], g});
    }
    for (auto& p : patches) {
      const PatchOutput out = p.extract(false);
      std::map<uint64_t, std::set<std::pair<uint64_t, std::array<uint64_t, 3>>>> fan;
      for (size_t f = 0; f < out.faces.size(); ++f) {
        const auto& t = out.faces[f];
        const std::array<uint64_t, 3> g = {out.vertex_gids[t[0]], out.vertex_gids[t[1]], out.vertex_gids[t[2]]};
        for (uint64_t v : g) fan[v].insert({out.face_gids[f], g});
      }
      for (size_t i = 0; i < out.vertex_gids.size(); ++i) {
        if (!out.trusted[i]) continue;
        const uint64_t gid = out.vertex_gids[i];
        ++trusted_checked;
        const auto it = at.find(gid);
        ASSERT_NE(it, at.end()) << "trusted vertex " << gid << " is gone in core";
        ASSERT_TRUE(same_bits(out.positions[i], ref.positions[it->second])) << "trusted vertex " << gid;
        ASSERT_TRUE(same_bits(out.quadrics[i], ref.quadrics[it->second])) << "trusted vertex " << gid;
        ASSERT_EQ(out.locked[i], ref.locked[it->second]) << "trusted vertex " << gid;
        ASSERT_EQ(fan[gid], ref_fan[gid]) << "faces of trusted vertex " << gid;
      }
    }
  }

  PatchInput patch(const GlobalMesh& g, int side, int rings, bool first_epoch) const {
    // Vertex -> faces of the current global mesh.
    std::map<uint64_t, std::vector<uint64_t>> fan;
    for (const auto& [f, t] : g.faces)
      for (uint64_t v : t) fan[v].push_back(f);
    std::set<uint64_t> faces, verts;
    for (const auto& [f, t] : g.faces)
      if (original_side[f] == side) faces.insert(f);
    for (uint64_t f : faces)
      for (uint64_t v : g.faces.at(f)) verts.insert(v);
    for (int r = 0; r < rings; ++r) {
      for (uint64_t v : verts)
        for (uint64_t f : fan[v]) faces.insert(f);
      for (uint64_t f : faces)
        for (uint64_t v : g.faces.at(f)) verts.insert(v);
    }
    PatchInput in;
    std::map<uint64_t, uint32_t> local;
    for (uint64_t v : verts) {
      local[v] = uint32_t(in.vertex_gids.size());
      in.vertex_gids.push_back(v);
      const auto& state = g.vertices.at(v);
      in.positions.push_back(state.position);
      if (!first_epoch) {
        in.quadrics.push_back(state.quadric);
        in.locked.push_back(state.locked);
      }
      if (carry && !first_epoch) {
        in.best_gids.push_back(state.best_gid);
        in.best_costs.push_back(state.best_cost);
      }
      const auto& vf = fan[v];
      const size_t inside = size_t(std::count_if(vf.begin(), vf.end(),
                                                 [&](uint64_t f) { return faces.count(f) != 0; }));
      in.incomplete.push_back(inside != vf.size());
      // Vertex owner: the owner of its smallest-id face.
      in.owned_vertex.push_back(original_side[*std::min_element(vf.begin(), vf.end())] == side);
    }
    for (uint64_t f : faces) {
      const auto& t = g.faces.at(f);
      in.faces.push_back({local[t[0]], local[t[1]], local[t[2]]});
      in.face_gids.push_back(f);
      in.owned_face.push_back(original_side[f] == side);
    }
    return in;
  }

  // One epoch on both patches; false when a patch reports that its halo is too small.
  // `params`: the run's (the guards relax once); the epoch's summary and rounds run under
  // summary_params of the count the previous epoch began with (`previous_start`), as
  // run_epochs does.
  bool epoch(GlobalMesh& g, bool& relaxed, DecimateParams& params, uint64_t previous_start, bool first_epoch,
             int rings, bool& done) {
    const DecimateParams summary = summary_params(params, previous_start, target, options);
    charged_epochs += summary.deviation_weight > 0.0;
    std::vector<PatchDecimator> patches;
    for (int side = 0; side < 2; ++side) patches.emplace_back(patch(g, side, rings, first_epoch), summary);
    RoundSummary total;
    for (auto& p : patches) {
      restored += p.restored_bests();
      p.prepare_round();
      first_refreshes += p.refreshes();
      total.add(p.summarize());
    }
    if (total.inexact_candidates != 0) return false;
    const EpochPlan plan = plan_epoch(total, g.faces.size(), target, relaxed, options);
    if (reference) {
      if (!(summary == reference->params())) reference->set_params(summary);
      reference->prepare_round();
      const RoundSummary in_core = reference->summarize();
      EXPECT_EQ(in_core.faces_per_bin, total.faces_per_bin);
      EXPECT_EQ(in_core.candidates, total.candidates);
    }
    done = false;
    if (plan.kind == EpochPlan::Kind::stop) {
      done = true;
      return true;
    }
    if (plan.kind == EpochPlan::Kind::relax) {
      params = relaxed_params(params);  // the reference's too, at the next epoch's start
      relaxed = true;
      // The carried bests were found under the strict guards.
      for (auto& [gid, v] : g.vertices) v.best_gid = kBestUnknown;
      return true;
    }
    std::optional<RoundCut> cut;
    if (plan.kind == EpochPlan::Kind::exact_cut) {
      std::vector<std::vector<Candidate>> owned;
      for (auto& p : patches) owned.push_back(p.owned_candidates());
      const std::vector<std::span<const Candidate>> lists(owned.begin(), owned.end());
      cut = exact_cut(lists, plan.needed);
      if (!cut) {
        done = true;
        return true;
      }
    }
    PatchDecimator* both[] = {&patches[0], &patches[1]};
    run_plan(both, plan, cut);
    for (auto& p : patches) {
      frozen_refreshes += p.frozen_refreshes();
      frozen_collapses += p.frozen_collapses();
      patch_refreshes += p.refreshes();
    }
    // Exchange: the next state is the union of the owned outputs.
    GlobalMesh next;
    // The next epoch's summary params (this epoch began with g's faces): the carried bests
    // must be found under them.
    const DecimateParams next_summary = summary_params(params, g.faces.size(), target, options);
    for (auto& p : patches) {
      if (carry) {  // the epoch's summary: every best exact
        if (!(next_summary == p.params())) p.set_params(next_summary);
        p.prepare_round();
      }
      const PatchOutput out = p.extract();
      if (out.untrusted_vertices != 0) return false;
      EXPECT_EQ(out.best_gids.empty(), !carry);
      for (size_t i = 0; i < out.faces.size(); ++i) {
        const std::array<uint64_t, 3> t = {out.vertex_gids[out.faces[i][0]],
                                           out.vertex_gids[out.faces[i][1]],
                                           out.vertex_gids[out.faces[i][2]]};
        EXPECT_TRUE(next.faces.emplace(out.face_gids[i], t).second) << "face owned twice";
      }
      for (size_t i = 0; i < out.positions.size(); ++i) {
        GlobalMesh::Vertex v{out.positions[i], out.quadrics[i], out.locked[i]};
        if (carry) {
          v.best_gid = out.best_gids[i];
          v.best_cost = out.best_costs[i];
        }
        const auto [it, inserted] = next.vertices.emplace(out.vertex_gids[i], v);
        if (!inserted) {  // shared by both patches' owned faces: the same state
          EXPECT_TRUE(same_bits(it->second.position, v.position));
          EXPECT_TRUE(same_bits(it->second.quadric, v.quadric));
          EXPECT_EQ(it->second.locked, v.locked);
          // Two known bests are the global one; a patch may not know it (untrusted 2-ring).
          if (it->second.best_gid == kBestUnknown) {
            it->second.best_gid = v.best_gid;
            it->second.best_cost = v.best_cost;
          } else if (v.best_gid != kBestUnknown) {
            EXPECT_EQ(it->second.best_gid, v.best_gid);
            EXPECT_EQ(std::bit_cast<uint64_t>(it->second.best_cost), std::bit_cast<uint64_t>(v.best_cost));
          }
        }
      }
      // Degrees of trusted vertices are the global ones (checked below).
      for (size_t i = 0; i < out.degrees.size(); ++i) degree_seen[out.vertex_gids[i]].insert(out.degrees[i]);
    }
    if (reference) {
      PatchDecimator* in_core[] = {reference};
      run_plan(in_core, plan, cut);
      check_trusted_against_reference(patches);
    }
    std::map<uint64_t, uint32_t> degree;
    for (const auto& [f, t] : next.faces)
      for (uint64_t v : t) ++degree[v];
    for (const auto& [v, seen] : degree_seen) {
      EXPECT_EQ(seen.size(), 1u) << v;
      EXPECT_EQ(*seen.begin(), degree[v]) << v;
    }
    degree_seen.clear();
    g = std::move(next);
    return true;
  }
  std::map<uint64_t, std::set<uint32_t>> degree_seen;

  GlobalMesh run() {
    GlobalMesh g;
    for (size_t f = 0; f < mesh.triangles.size(); ++f) {
      const auto& t = mesh.triangles[f];
      g.faces[f] = {t[0], t[1], t[2]};
      const double x = (mesh.points[t[0]][0] + mesh.points[t[1]][0] + mesh.points[t[2]][0]) / 3;
      original_side.push_back(x < split ? 0 : 1);
    }
    for (size_t v = 0; v < mesh.points.size(); ++v) g.vertices[v] = {mesh.points[v], {}, 0};
    bool relaxed = false, first = true, done = false;
    DecimateParams params;
    uint64_t previous_start = g.faces.size();
    int rings = halo;
    while (g.faces.size() > target && !done) {
      rings = std::max(1, rings - 1);
      const uint64_t start = g.faces.size();
      for (;;) {
        GlobalMesh attempt = g;
        bool attempt_relaxed = relaxed;
        DecimateParams attempt_params = params;
        if (epoch(attempt, attempt_relaxed, attempt_params, previous_start, first, rings, done)) {
          g = std::move(attempt);
          relaxed = attempt_relaxed;
          params = attempt_params;
          break;
        }
        degree_seen.clear();
        rings += 1;
        ++halo_growths;
        if (rings > 200) {
          ADD_FAILURE() << "halo keeps growing";
          return g;
        }
      }
      max_halo_used = std::max(max_halo_used, rings);
      previous_start = start;
      first = false;
      ++epochs;
    }
    return g;
  }
};

struct Case {
  const char* name;
  Mesh mesh;
  uint64_t target;
  bool closed;  // closed meshes keep an even face count
  double split;
};

std::vector<Case> cases() {
  return {{"noisy sphere", qemflow::testing::icosphere(5, 0.02, 3), 200, true, 0.05},  // 20480 faces
          {"noisy grid", qemflow::testing::grid(70, 0.003, 5), 333, false, 0.43}};   // 9800 faces
}

TEST(DecimateEpochs, InCoreRunIsDeterministicAndExactForSeveralEpochLengths) {
  for (uint32_t e : {1u, 2u, 3u, 4u, 6u, 12u}) {
    EpochOptions options;
    options.epoch_rounds = e;
    for (const auto& c : cases()) {
      for (uint64_t target : {c.target, c.target * 5 + 1, uint64_t(c.mesh.triangles.size() / 2)}) {
        const uint64_t expected = (c.closed && target % 2) ? target + 1 : target;
        EpochRunStats st1, st2;
        GlobalMesh a, b;
        {
          tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
          a = in_core_result(c.mesh, target, options, &st1);
        }
        {
          tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
          b = in_core_result(c.mesh, target, options, &st2);
        }
        EXPECT_EQ(a.faces.size(), expected) << c.name << " E=" << e << " target " << target;
        expect_same_mesh(a, b);
        EXPECT_EQ(st1.rounds, st2.rounds);
        if (e > 1 && target == c.target) {
          EXPECT_LT(st1.epochs, st1.rounds) << c.name << " E=" << e;
        }
      }
    }
  }
}

TEST(DecimateEpochs, EpochOfOneRoundIsTheRoundByRoundSchedule) {
  // E = 1 takes the global decision every round: fewer epochs than rounds is impossible.
  EpochOptions options;
  options.epoch_rounds = 1;
  EpochRunStats st;
  in_core_result(qemflow::testing::icosphere(4, 0.01), 300, options, &st);
  EXPECT_GE(st.epochs, st.rounds);
}

TEST(DecimateEpochs, PlanEpochRisingCutsAndEndGame) {
  RoundSummary s;
  s.faces_per_bin[cost_bin(1.0)] = 100;
  s.faces_per_bin[cost_bin(4.0)] = 100;
  s.candidate_faces = 200;
  s.candidates = 100;
  EpochOptions o;
  o.epoch_rounds = 3;
  o.round_fraction = 0.1;
  o.candidate_fraction = 0.5;
  o.cut_rise = 0.5;
  // 1000 faces: budget 100 = the first bin; the first round removes 100, each later
  // one is taken to remove 10% of the rest: 100 + 90 + 81 < 900 still to remove.
  EpochPlan p = plan_epoch(s, 1000, 100, false, o);
  ASSERT_EQ(p.kind, EpochPlan::Kind::bin_cut);
  ASSERT_EQ(p.cuts.size(), 3u);
  EXPECT_LT(1.0, p.cuts[0].key.cost);
  EXPECT_LT(p.cuts[0].key.cost, 4.0);
  // The cut rises by floor(r * 0.5) bins: round 2 keeps the first cut, round 3 is one
  // bin (a quarter octave) higher.
  EXPECT_EQ(p.cuts[1].key.cost, p.cuts[0].key.cost);
  EXPECT_EQ(cost_bin(p.cuts[2].key.cost), cost_bin(p.cuts[0].key.cost) + 1);
  EXPECT_EQ(p.cuts[2].key.cost, cost_bin_upper(cost_bin(1.0) + 1));
  o.cut_rise = 2;
  p = plan_epoch(s, 1000, 100, false, o);
  ASSERT_EQ(p.cuts.size(), 3u);
  EXPECT_EQ(cost_bin(p.cuts[1].key.cost), cost_bin(1.0) + 2);
  EXPECT_EQ(cost_bin(p.cuts[2].key.cost), cost_bin(1.0) + 4);
  // 500 still to remove: 271 fits, three rounds.
  p = plan_epoch(s, 1000, 500, false, o);
  EXPECT_EQ(p.cuts.size(), 3u);
  // 150 still to remove: 100 + 90 does not fit, one round.
  p = plan_epoch(s, 1000, 850, false, o);
  ASSERT_EQ(p.kind, EpochPlan::Kind::bin_cut);
  EXPECT_EQ(p.cuts.size(), 1u);
  // Later rounds taken to remove 30% of the rest: 100 + 270 > 300 to remove, one round.
  o.round_fraction = 0.3;
  p = plan_epoch(s, 1000, 700, false, o);
  ASSERT_EQ(p.kind, EpochPlan::Kind::bin_cut);
  EXPECT_EQ(p.cuts.size(), 1u);
  o.round_fraction = 0.1;
  // The first bin covers what is left: exact.
  p = plan_epoch(s, 1000, 950, false, o);
  EXPECT_EQ(p.kind, EpochPlan::Kind::exact_cut);
  EXPECT_EQ(p.needed, 50u);
  // No candidate anywhere: relax once, then stop.
  const RoundSummary none;
  EXPECT_EQ(plan_epoch(none, 1000, 100, false, o).kind, EpochPlan::Kind::relax);
  EXPECT_EQ(plan_epoch(none, 1000, 100, true, o).kind, EpochPlan::Kind::stop);
  EXPECT_EQ(plan_epoch(s, 100, 100, false, o).kind, EpochPlan::Kind::stop);
}

TEST(DecimateEpochs, FlatCandidatesKeepTheSlowRise) {
  // Curved candidates only: the cut rises cut_rise = 0.75 bins per round.
  RoundSummary s;
  s.faces_per_bin[cost_bin(1.0)] = 100;
  s.faces_per_bin[cost_bin(4.0)] = 100;
  s.candidate_faces = 200;
  const EpochOptions o;
  EXPECT_EQ(epoch_cut_rise(s, o), 0.75);
  // Each round's cut in bins above the first curved bin (the first round's cut).
  auto rises = [&] {
    std::vector<size_t> bins;
    for (const RoundCut& cut : plan_epoch(s, 10000, 100, false, o).cuts)
      bins.push_back(cost_bin(cut.key.cost) - cost_bin(1.0));
    return bins;
  };
  EXPECT_EQ(rises(), (std::vector<size_t>{0, 0, 1, 2}));
  // A third of the candidates' faces flat (cost 0, bin 0): flat_cut_rise = 0.5; the
  // first round takes the flat bin and the first curved one, the last two rounds share
  // one bin more.
  s.faces_per_bin[0] = 100;
  s.candidate_faces = 300;
  EXPECT_EQ(epoch_cut_rise(s, o), 0.5);
  EXPECT_EQ(rises(), (std::vector<size_t>{0, 0, 1, 1}));
  // Below kFullyFlatShare, linear in the flat share: 5% flat, halfway.
  s.faces_per_bin[0] = 10;
  s.candidate_faces = 200;
  EXPECT_DOUBLE_EQ(epoch_cut_rise(s, o), 0.625);
  // flat_cut_rise >= cut_rise: the fixed rise; the flat rise never exceeds cut_rise.
  EpochOptions fixed;
  fixed.flat_cut_rise = 1.0;
  EXPECT_EQ(epoch_cut_rise(s, fixed), 0.75);
  fixed.cut_rise = 0.25;
  EXPECT_EQ(epoch_cut_rise(s, fixed), 0.25);
}

TEST(DecimateEpochs, SummaryParamsWeighTheChargeFromChargeFromTimesTheTarget) {
  EpochOptions options;
  options.charge_from = 3.0;
  DecimateParams params = relaxed_params({});
  params.deviation_weight = 7.0;
  // Off while the epoch began above 3 x the target, on from there; the rest as given.
  EXPECT_EQ(summary_params(params, 301, 100, options).deviation_weight, 0.0);
  EXPECT_EQ(summary_params(params, 300, 100, options).deviation_weight, 7.0);
  EXPECT_EQ(summary_params(params, 1, 100, options).deviation_weight, 7.0);
  DecimateParams off = params;
  off.deviation_weight = 0.0;
  EXPECT_TRUE(summary_params(params, 301, 100, options) == off);
  options.charge_from = 0.0;  // from the start
  EXPECT_TRUE(summary_params(params, 1000000, 100, options) == params);
}

// With charge_from 2 the charge is weighed in the last stretch only: fewer charges than
// a run charged throughout (the default), but some; a charge_from below 1 never reaches
// it (plain QEM to the bit), one above the input's ratio charges from the first summary
// (the run charged throughout, to the bit).
TEST(DecimateEpochs, TheChargeIsWeighedOnlyInTheLastStretch) {
  const Case c = cases()[0];  // 20480 faces -> 200
  auto run = [&](double charge_from, double weight, DecimatorWork* work = nullptr) {
    EpochOptions options;
    options.charge_from = charge_from;
    DecimateParams params;
    params.deviation_weight = weight;
    return in_core_result(c.mesh, c.target, options, nullptr, params, work);
  };
  DecimatorWork throughout, last_stretch, never;
  const GlobalMesh charged = run(0.0, 10.0, &throughout);
  const GlobalMesh last_stretch_mesh = run(2.0, 10.0, &last_stretch);
  const GlobalMesh not_reached = run(0.5, 10.0, &never);
  EXPECT_GT(last_stretch.charges, 0u);
  EXPECT_LT(2 * last_stretch.charges, throughout.charges);
  EXPECT_EQ(never.charges, 0u);
  EXPECT_NE(last_stretch_mesh.faces, charged.faces);
  expect_same_mesh(run(EpochOptions{}.charge_from, 10.0), charged);  // the default: throughout
  expect_same_mesh(not_reached, run(0.0, 0.0));
  expect_same_mesh(run(1e6, 10.0), charged);
  std::printf("charges: %llu throughout, %llu in the last stretch\n",
              static_cast<unsigned long long>(throughout.charges),
              static_cast<unsigned long long>(last_stretch.charges));
}

// Out of core, each patch sends exact_cut only its share of its candidates; the cut
// must be the one the whole lists give. The hand-made case is the end game that broke
// out of core (one face to go, a two-face candidate first): a share without the
// two-face candidate made the single-face one look next in order, and the cut at its
// key took every candidate before it.
TEST(DecimateEpochs, ExactCutOfThePatchesSharesIsTheExactCutOfTheirWholeLists) {
  auto candidate = [](double cost, uint64_t gid, uint32_t faces) {
    Candidate c;
    c.key = EdgeKey::of(cost, gid, gid + 1);
    c.faces_removed = faces;
    return c;
  };
  auto cut_of = [](const std::vector<std::vector<Candidate>>& lists, uint64_t needed) {
    const std::vector<std::span<const Candidate>> spans(lists.begin(), lists.end());
    return exact_cut(spans, needed);
  };
  auto same = [](const std::optional<RoundCut>& a, const std::optional<RoundCut>& b) {
    if (a.has_value() != b.has_value()) return false;
    return !a || (!(a->key < b->key) && !(b->key < a->key) && a->single_face_only == b->single_face_only);
  };
  const std::vector<std::vector<Candidate>> end_game = {{candidate(1.0, 10, 2), candidate(2.0, 20, 1)}};
  const auto whole = cut_of(end_game, 1);
  ASSERT_TRUE(whole.has_value());
  EXPECT_TRUE(whole->single_face_only);
  EXPECT_TRUE(same(cut_of({exact_cut_share(end_game[0], 1)}, 1), whole));

  uint64_t state = 12345;
  auto next = [&] { return state = state * 6364136223846793005ull + 1442695040888963407ull; };
  for (int trial = 0; trial < 2000; ++trial) {
    std::vector<std::vector<Candidate>> lists(1 + next() % 4), shares;
    uint64_t gid = 0;
    for (auto& list : lists) {
      for (uint64_t n = next() % 12; n > 0; --n)
        list.push_back(candidate(double(next() % 64), gid += 2, next() % 4 == 0 ? 1 : 2));
      std::sort(list.begin(), list.end(), [](const Candidate& a, const Candidate& b) { return a.key < b.key; });
    }
    const uint64_t needed = 1 + next() % 30;
    for (const auto& list : lists) shares.push_back(exact_cut_share(list, needed));
    ASSERT_TRUE(same(cut_of(shares, needed), cut_of(lists, needed))) << "trial " << trial;
  }
}

TEST(DecimateEpochs, TwoPatchSimulationEqualsInCoreBitForBit) {
  for (const auto& [e, c] : {std::pair{3u, cases()[0]}, std::pair{1u, cases()[1]}, std::pair{2u, cases()[1]}}) {
    EpochOptions options;
    options.epoch_rounds = e;
    {
      Simulation sim{c.mesh, c.target, options, int(kInitialQuadricRadius + kTrustSpread * e + 3)};
      sim.split = c.split;
      PatchDecimator lockstep(whole_patch(c.mesh), {});
      sim.reference = &lockstep;
      const GlobalMesh simulated = sim.run();
      const GlobalMesh reference = in_core_result(c.mesh, c.target, options);
      SCOPED_TRACE(std::string(c.name) + " E=" + std::to_string(e));
      expect_same_mesh(simulated, reference);
      // Quadrics exchanged at epoch ends are the in-core ones too.
      for (const auto& [gid, v] : reference.vertices)
        EXPECT_TRUE(same_bits(v.quadric, simulated.vertices.at(gid).quadric)) << gid;
      EXPECT_GT(sim.epochs, 5u);
      EXPECT_GT(sim.trusted_checked, c.mesh.points.size());
      std::printf("%s E=%u: %llu epochs, halo up to %d rings, %d growths\n", c.name, e,
                  static_cast<unsigned long long>(sim.epochs), sim.max_halo_used, sim.halo_growths);
    }
  }
}

// Runs `sim` on case c with the in-core decimator in lockstep (every trusted vertex of
// every patch checked at each epoch's end) and checks that the result is the in-core one.
void run_in_lockstep(Simulation& sim, const Case& c) {
  sim.split = c.split;
  PatchDecimator lockstep(whole_patch(c.mesh), {});
  sim.reference = &lockstep;
  expect_same_mesh(sim.run(), in_core_result(c.mesh, c.target, sim.options));
  sim.reference = nullptr;
  EXPECT_GT(sim.epochs, 5u);
}

TEST(DecimateEpochs, TwoPatchSimulationCarryingBestEdgesEqualsInCoreAndRefreshesLess) {
  // As above, with each vertex's best edge carried from one epoch's summary to the next
  // epoch's patches: a carried best that differed from what a refresh computes (or one
  // carried across the guards' relaxation, or restored near a patch's halo edge) would
  // change the LMEs and the result.
  const Case c = cases()[1];  // the grid: the quicker case
  EpochOptions options;
  options.epoch_rounds = 2;
  uint64_t refreshes[2] = {0, 0};
  for (const bool carry : {false, true}) {
    SCOPED_TRACE(carry ? "carrying" : "not carrying");
    Simulation sim{c.mesh, c.target, options, int(kInitialQuadricRadius + kTrustSpread * 2 + 3)};
    sim.carry = carry;
    run_in_lockstep(sim, c);
    if (carry) {
      EXPECT_GT(sim.restored, c.mesh.points.size());
    } else {
      EXPECT_EQ(sim.restored, 0u);
    }
    refreshes[carry] = sim.first_refreshes;
    std::printf("carry %d: %llu bests restored, %llu refreshes in the epochs' first prepare\n", int(carry),
                static_cast<unsigned long long>(sim.restored), static_cast<unsigned long long>(sim.first_refreshes));
  }
  EXPECT_LT(2 * refreshes[1], refreshes[0]);
}

TEST(DecimateEpochs, TwoPatchSimulationSwitchingTheChargeOnEqualsInCore) {
  // --charge-from 2: the charge switches on between an epoch's rounds and its summary
  // (summary_params), in every patch alike; with carried bests (found under the params
  // they are restored under) and blind rounds, as in the pipeline, the result is still
  // the in-core one, every trusted vertex checked against the lockstep decimator.
  const Case c = cases()[1];
  EpochOptions options;
  options.epoch_rounds = 2;
  options.charge_from = 2.0;
  Simulation sim{c.mesh, c.target, options, int(kInitialQuadricRadius + kTrustSpread * 2 + 3)};
  sim.carry = true;
  sim.blind = true;
  run_in_lockstep(sim, c);
  EXPECT_GT(sim.restored, c.mesh.points.size());
  EXPECT_GT(sim.charged_epochs, 0u);
  EXPECT_GT(sim.epochs, sim.charged_epochs + 5);
}

TEST(DecimateEpochs, TwoPatchSimulationFreezingTheUntrustedHaloEqualsInCore) {
  // Untrusted vertices that are not owned are frozen (no refresh, no LME) and inexact
  // candidates not owned with both ends within kDecisionRadius rings of untrusted state
  // are not collapsed. Both must happen here (the counters), with blind rounds as in the
  // pipeline, and the result must stay the in-core one, with every trusted vertex of
  // every patch equal to the lockstep in-core decimator's at each epoch's end. A freeze
  // one ring too wide breaks this: skipping also the inexact candidates with an end 5
  // rings out (their collapse reaches ring 6, which stays trusted) changes trusted
  // vertices' faces on both cases.
  for (const auto& [e, c] : {std::pair{3u, cases()[0]}, std::pair{2u, cases()[1]}}) {
    SCOPED_TRACE(std::string(c.name) + " E=" + std::to_string(e));
    EpochOptions options;
    options.epoch_rounds = e;
    Simulation sim{c.mesh, c.target, options, int(kInitialQuadricRadius + kTrustSpread * e + 3)};
    sim.blind = true;
    run_in_lockstep(sim, c);
    EXPECT_GT(sim.trusted_checked, c.mesh.points.size());
    EXPECT_GT(sim.frozen_refreshes, sim.patch_refreshes / 50);
    EXPECT_GT(sim.frozen_collapses, 0u);
    std::printf("%s E=%u: %llu refreshes, %llu skipped at frozen vertices, %llu collapses skipped\n", c.name, e,
                static_cast<unsigned long long>(sim.patch_refreshes),
                static_cast<unsigned long long>(sim.frozen_refreshes),
                static_cast<unsigned long long>(sim.frozen_collapses));
  }
}

TEST(DecimateEpochs, RestoredBestsContinueExactlyLikeTheDecimatorTheyCameFrom) {
  // In core (nothing untrusted): stop halfway, take a plain prepare_round's bests with
  // the state, and rebuild. With the bests every vertex is restored and the first
  // prepare refreshes none; with or without them, and the original decimator going on,
  // the result is the same bit for bit.
  const Mesh m = qemflow::testing::icosphere(5, 0.02, 3);
  EpochOptions options;
  // Charged throughout: a run_epochs that switched the charge on would refresh every
  // vertex (set_params) and restore nothing.
  options.charge_from = 0.0;
  PatchDecimator original(whole_patch(m), {});
  run_epochs(original, m.triangles.size() / 3, options);
  original.prepare_round();
  const PatchOutput half = original.extract(false);
  ASSERT_EQ(half.best_gids.size(), half.vertex_gids.size());
  EXPECT_EQ(std::count(half.best_gids.begin(), half.best_gids.end(), kBestUnknown), 0);
  enum class Bests { carried, none_carried, wrong };
  auto rebuilt = [&](Bests bests) {
    PatchInput in;
    in.positions = half.positions;
    in.vertex_gids = half.vertex_gids;
    in.quadrics = half.quadrics;
    in.locked = half.locked;
    in.faces = half.faces;
    in.face_gids = half.face_gids;
    if (bests == Bests::carried) {
      in.best_gids = half.best_gids;
      in.best_costs = half.best_costs;
    } else if (bests == Bests::wrong) {  // "no valid edge" everywhere
      in.best_gids.assign(half.vertex_gids.size(), kBestNone);
      in.best_costs.assign(half.vertex_gids.size(), 0.0);
    }
    return PatchDecimator(std::move(in), original.params());
  };
  PatchDecimator restored = rebuilt(Bests::carried), fresh = rebuilt(Bests::none_carried);
  EXPECT_EQ(restored.restored_bests(), half.vertex_gids.size());
  EXPECT_EQ(fresh.restored_bests(), 0u);
  restored.prepare_round();
  fresh.prepare_round();
  EXPECT_EQ(restored.refreshes(), 0u);
  EXPECT_EQ(fresh.refreshes(), half.vertex_gids.size());
  EXPECT_EQ(restored.summarize().faces_per_bin, fresh.summarize().faces_per_bin);
  const uint64_t target = m.triangles.size() / 20;
  for (PatchDecimator* d : {&original, &restored, &fresh}) run_epochs(*d, target, options);
  const PatchOutput a = original.extract(), b = restored.extract(), c = fresh.extract();
  ASSERT_EQ(a.face_gids, b.face_gids);
  ASSERT_EQ(a.face_gids, c.face_gids);
  ASSERT_EQ(a.vertex_gids, b.vertex_gids);
  ASSERT_EQ(a.vertex_gids, c.vertex_gids);
  for (size_t i = 0; i < a.positions.size(); ++i) {
    EXPECT_TRUE(same_bits(a.positions[i], b.positions[i])) << a.vertex_gids[i];
    EXPECT_TRUE(same_bits(a.positions[i], c.positions[i])) << a.vertex_gids[i];
  }
  // Wrong carried bests are trusted as given (the caller's duty): not the same run.
  PatchDecimator broken = rebuilt(Bests::wrong);
  run_epochs(broken, target, options);
  EXPECT_NE(broken.extract().face_gids, a.face_gids);
}

TEST(DecimateEpochs, TrustTrackingReportsATooSmallHalo) {
  // With a one-ring halo the first epoch cannot be exact: the patch must say so, either
  // in its summary (owned inexact candidates) or in its output (untrusted vertices).
  const Mesh m = qemflow::testing::icosphere(4, 0.02, 9);
  Simulation sim{m, 100, {}, 1};
  GlobalMesh g;
  for (size_t f = 0; f < m.triangles.size(); ++f) {
    const auto& t = m.triangles[f];
    g.faces[f] = {t[0], t[1], t[2]};
    sim.original_side.push_back((m.points[t[0]][0] + m.points[t[1]][0] + m.points[t[2]][0]) < 0 ? 0 : 1);
  }
  for (size_t v = 0; v < m.points.size(); ++v) g.vertices[v] = {m.points[v], {}, 0};
  PatchDecimator d(sim.patch(g, 0, 1, true), {});
  EXPECT_GT(d.untrusted_count(), 0u);
  d.prepare_round();
  EXPECT_GT(d.summarize().inexact_candidates, 0u);
  // Every vertex of an in-core patch is trusted, and stays so.
  PatchDecimator whole(whole_patch(m), {});
  EXPECT_EQ(whole.untrusted_count(), 0u);
  whole.prepare_round();
  EXPECT_EQ(whole.summarize().inexact_candidates, 0u);
  EXPECT_EQ(whole.owned_candidates().size(), whole.candidates().size());
}

}  // namespace
}  // namespace qemflow::nodes
