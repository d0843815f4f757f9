#include "nodes/decimate/simplify.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "nodes/weld.hpp"

namespace qemflow::nodes {
namespace {

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

uint64_t target_face_count(uint64_t input_faces, const SimplifyOptions& options) {
  if (options.target_faces) return *options.target_faces;
  if (options.ratio) return static_cast<uint64_t>(std::llround(*options.ratio * double(input_faces)));
  throw std::invalid_argument("simplify: one of target_faces or ratio is required");
}

void copy_mesh(const PatchOutput& out, std::vector<Point>& points, std::vector<Triangle>& triangles) {
  points.resize(out.positions.size());
  for (size_t i = 0; i < out.positions.size(); ++i) points[i] = out.positions[i];
  triangles.resize(out.faces.size());
  for (size_t i = 0; i < out.faces.size(); ++i) triangles[i] = {out.faces[i][0], out.faces[i][1], out.faces[i][2]};
}

double removed_share(uint64_t input_faces, uint64_t target_faces, uint64_t faces) {
  const uint64_t to_remove = input_faces - std::min(input_faces, target_faces);
  return to_remove ? double(input_faces - std::min(input_faces, faces)) / double(to_remove) : 1.0;
}

EpochRunStats run_epochs(PatchDecimator& decimator, uint64_t target_faces,
                         const EpochOptions& options,
                         const std::function<void(uint64_t, uint64_t)>& on_round,
                         const EpochRunStart& start) {
  EpochRunStats st;
  DecimateParams params = start.params ? *start.params : decimator.params();
  uint64_t epoch_start = start.epoch_start_faces ? start.epoch_start_faces : decimator.face_count();
  bool relaxed = !(params.min_normal_cos > 0.0);
  auto round = [&](const RoundCut& cut) {
    decimator.apply_cut(cut);
    ++st.rounds;
    if (on_round) on_round(st.rounds, decimator.face_count());
  };
  while (decimator.face_count() > target_faces) {
    const DecimateParams summary = summary_params(params, epoch_start, target_faces, options);
    if (!(summary == decimator.params())) decimator.set_params(summary);
    epoch_start = decimator.face_count();
    decimator.prepare_round();
    const EpochPlan plan =
        plan_epoch(decimator.summarize(), decimator.face_count(), target_faces, relaxed, options);
    if (plan.kind == EpochPlan::Kind::stop) break;
    ++st.epochs;
    if (plan.kind == EpochPlan::Kind::relax) {
      // A global decision (the summed candidate count is zero), so partition-invariant;
      // the loop's top sets the relaxed params.
      params = relaxed_params(params);
      relaxed = true;
      continue;
    }
    if (plan.kind == EpochPlan::Kind::exact_cut) {
      const std::vector<Candidate> owned = decimator.owned_candidates();
      const std::span<const Candidate> lists[] = {owned};
      const auto cut = exact_cut(lists, plan.needed);
      if (!cut) break;
      round(*cut);
      continue;
    }
    // The epoch's rounds run blind, as every out-of-core patch does: no early exit.
    round(plan.cuts.front());
    for (size_t r = 1; r < plan.cuts.size(); ++r) {
      decimator.prepare_round(plan.cuts[r]);
      round(plan.cuts[r]);
    }
  }
  return st;
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
  release_memory(triangles);
  release_memory(representative);
  uint32_t next = 0;
  const size_t used = size_t(std::count(local.begin(), local.end(), 0u));
  input.positions.reserve(used);
  input.vertex_gids.reserve(used);
  for (uint64_t v = 0; v < points.size(); ++v) {
    if (local[v] == kUnused) continue;
    local[v] = next++;
    input.positions.push_back(points[v]);
    input.vertex_gids.push_back(v);
  }
  for (auto& t : input.faces)
    for (auto& v : t) v = local[v];
  release_memory(points);
  release_memory(local);

  PatchDecimator decimator(std::move(input), options.params);
  st.locked_vertices = decimator.locked_vertices();
  st.dropped_faces = decimator.dropped_faces();
  st.seconds_setup = seconds_since(t0);

  const auto t1 = std::chrono::steady_clock::now();
  const EpochRunStats run =
      run_epochs(decimator, st.target_faces, options.epochs, options.on_round);
  st.rounds = run.rounds;
  st.epochs = run.epochs;
  st.work = decimator.work();
  st.seconds_rounds = seconds_since(t1);

  const auto t2 = std::chrono::steady_clock::now();
  PatchOutput out = decimator.extract();
  copy_mesh(out, result.points, result.triangles);
  st.output_vertices = result.points.size();
  st.output_faces = result.triangles.size();
  st.seconds_extract = seconds_since(t2);
  return result;
}

}  // namespace qemflow::nodes
