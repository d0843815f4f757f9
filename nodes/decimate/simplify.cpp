#include "nodes/decimate/simplify.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "nodes/weld.hpp"

namespace qemflow::nodes {
namespace {

constexpr double kRelaxedNormalCos = 0.0;
constexpr double kRelaxedFaceQuality = 1e-9;

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

uint64_t target_face_count(uint64_t input_faces, const SimplifyOptions& options) {
  if (options.target_faces) return *options.target_faces;
  if (options.ratio) return static_cast<uint64_t>(std::llround(*options.ratio * double(input_faces)));
  throw std::invalid_argument("simplify: one of target_faces or ratio is required");
}

uint64_t run_rounds(PatchDecimator& decimator, uint64_t target_faces, double round_fraction,
                    double candidate_fraction,
                    const std::function<void(uint64_t, uint64_t)>& on_round) {
  uint64_t rounds = 0;
  while (decimator.face_count() > target_faces) {
    decimator.prepare_round();
    const RoundSummary summary = decimator.summarize();
    const RoundPlan plan =
        plan_round(summary, decimator.face_count(), target_faces, round_fraction,
                   candidate_fraction);
    RoundCut cut;
    if (plan.kind == RoundPlan::Kind::stop) {
      // No valid candidate left above the target: relax the geometric guards once
      // (normals may turn up to 90 degrees, faces may get thin but not degenerate).
      // A global decision (every patch sees zero candidates), so partition-invariant.
      DecimateParams relaxed = decimator.params();
      if (summary.candidate_faces != 0 || relaxed.min_normal_cos <= kRelaxedNormalCos) break;
      relaxed.min_normal_cos = kRelaxedNormalCos;
      relaxed.min_face_quality = std::min(relaxed.min_face_quality, kRelaxedFaceQuality);
      decimator.set_params(relaxed);
      continue;
    }
    if (plan.kind == RoundPlan::Kind::bin_cut) {
      cut = plan.cut;
    } else {
      const std::span<const Candidate> lists[] = {decimator.candidates()};
      const auto exact = exact_cut(lists, plan.needed);
      if (!exact) break;
      cut = *exact;
    }
    const uint64_t removed = decimator.apply_cut(cut);
    ++rounds;
    if (on_round) on_round(rounds, decimator.face_count());
    if (removed == 0) break;
  }
  return rounds;
}

SimplifyResult simplify_in_core(std::vector<Point>&& points, std::vector<Triangle>&& triangles,
                                const SimplifyOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  SimplifyResult result;
  SimplifyStats& st = result.stats;
  st.input_vertices = points.size();
  st.input_faces = triangles.size();
  st.target_faces = target_face_count(st.input_faces, options);

  // Weld, then keep only referenced vertices; a vertex's global id is its input index
  // (the smallest of its duplicates).
  std::vector<uint64_t> representative;
  if (options.weld) {
    representative = weld_representatives(points);
    for (uint64_t i = 0; i < representative.size(); ++i) st.welded_vertices += representative[i] != i;
  }
  constexpr uint32_t kUnused = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> local(points.size(), kUnused);
  PatchInput input;
  input.faces.resize(triangles.size());
  input.face_gids.resize(triangles.size());
  for (size_t f = 0; f < triangles.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      uint64_t v = triangles[f][k];
      if (v >= points.size()) throw std::invalid_argument("simplify: vertex index out of range");
      if (options.weld) v = representative[v];
      if (local[v] == kUnused) local[v] = 0;  // mark used; numbered below
      input.faces[f][k] = static_cast<uint32_t>(v);  // input index for now
    }
    input.face_gids[f] = f;
  }
  triangles = {};
  representative = {};
  uint32_t next = 0;
  for (uint64_t v = 0; v < points.size(); ++v) {
    if (local[v] == kUnused) continue;
    local[v] = next++;
    input.positions.push_back(points[v]);
    input.vertex_gids.push_back(v);
  }
  for (auto& t : input.faces)
    for (auto& v : t) v = local[v];
  points = {};
  local = {};

  PatchDecimator decimator(std::move(input), options.params);
  st.locked_vertices = decimator.locked_vertices();
  st.dropped_faces = decimator.dropped_faces();
  st.seconds_setup = seconds_since(t0);

  const auto t1 = std::chrono::steady_clock::now();
  st.rounds = run_rounds(decimator, st.target_faces, options.round_fraction,
                         options.candidate_fraction, options.on_round);
  st.seconds_rounds = seconds_since(t1);

  const auto t2 = std::chrono::steady_clock::now();
  PatchOutput out = decimator.extract();
  result.points.resize(out.positions.size());
  for (size_t i = 0; i < out.positions.size(); ++i) result.points[i] = out.positions[i];
  result.triangles.resize(out.faces.size());
  for (size_t i = 0; i < out.faces.size(); ++i)
    result.triangles[i] = {out.faces[i][0], out.faces[i][1], out.faces[i][2]};
  st.output_vertices = result.points.size();
  st.output_faces = result.triangles.size();
  st.seconds_extract = seconds_since(t2);
  return result;
}

}  // namespace qemflow::nodes
