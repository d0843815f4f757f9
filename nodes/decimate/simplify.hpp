#pragma once
// simplify_in_core: the reference run of the decimator (DESIGN.md §3) on a whole mesh
// held in memory - weld, one PatchDecimator (everything owned and trusted), LME rounds
// in epochs with the global cut of cut.hpp (plan_epoch) until the target face count is
// reached. The out-of-core pipeline runs the same epoch schedule on patches.
//
// Contract: deterministic - the output (vertices sorted by global id, faces by global
// face id, positions as computed) is identical for any oneTBB thread count. The target
// is met exactly unless topology forbids (then within +2: closed meshes keep an even
// face count, tetrahedra and locked regions cannot shrink). Never drops input faces
// silently: faces around non-manifold vertices pass through; faces with a repeated
// vertex (zero area) are dropped and counted in stats.dropped_faces. Unreferenced vertices are not written.
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "nodes/decimate/cut.hpp"
#include "nodes/decimate/decimator.hpp"
#include "util/geometry.hpp"

namespace qemflow::nodes {

struct SimplifyOptions {
  std::optional<uint64_t> target_faces;  // one of target_faces / ratio
  std::optional<double> ratio;
  bool weld = true;
  EpochOptions epochs;  // the schedule of global decisions (cut.hpp)
  DecimateParams params;
  // Called after each round with (round, faces now); may be empty.
  std::function<void(uint64_t, uint64_t)> on_round;
};

struct SimplifyStats {
  uint64_t input_vertices = 0, input_faces = 0;
  uint64_t welded_vertices = 0;      // vertices merged into an earlier duplicate
  uint64_t locked_vertices = 0;
  uint64_t dropped_faces = 0;        // faces with a repeated vertex (zero area)
  uint64_t target_faces = 0;
  uint64_t output_vertices = 0, output_faces = 0;
  uint64_t rounds = 0;
  uint64_t epochs = 0;
  DecimatorWork work;
  double seconds_setup = 0, seconds_rounds = 0, seconds_extract = 0;
};

struct SimplifyResult {
  std::vector<Point> points;
  std::vector<Triangle> triangles;
  SimplifyStats stats;
};

// Consumes the input arrays (they are released as soon as the decimator holds its
// own copy, which keeps peak memory low).
SimplifyResult simplify_in_core(std::vector<Point>&& points, std::vector<Triangle>&& triangles,
                                const SimplifyOptions& options);

// An extracted mesh as the writer's arrays: points in global-id order, triangles in
// face-id order (the order PatchOutput holds them in), both runs' output.
void copy_mesh(const PatchOutput& out, std::vector<Point>& points, std::vector<Triangle>& triangles);

// The target face count the options ask for.
uint64_t target_face_count(uint64_t input_faces, const SimplifyOptions& options);

// The share of the faces to remove (input down to target) that are gone once `faces`
// are left, in [0, 1]; 1 when there is nothing to remove. A run's progress: a round or
// an epoch removes a share of the faces it passes over, so this grows about evenly
// with the work.
double removed_share(uint64_t input_faces, uint64_t target_faces, uint64_t faces);

struct EpochRunStats {
  uint64_t rounds = 0, epochs = 0;
};

// Where run_epochs starts. A fresh run: nothing given (the decimator holds the run's
// params, its face count is the input's). The out-of-core finish: the run's params
// (the guards as the passes left them, the full deviation weight; the decimator holds
// the last pass's summary params, maybe with the charge off) and the face count the
// last pass began with (the epoch its summary followed: summary_params' count).
struct EpochRunStart {
  std::optional<DecimateParams> params;
  uint64_t epoch_start_faces = 0;  // 0: the decimator's face count
};

// The epoch loop (cut.hpp) on one patch holding the whole mesh: the in-core reference
// of the out-of-core schedule (exposed for tests/benchmarks). on_round(round, faces).
// Each epoch's summary runs with summary_params (the charge from
// EpochOptions::charge_from on).
EpochRunStats run_epochs(PatchDecimator& decimator, uint64_t target_faces,
                         const EpochOptions& options,
                         const std::function<void(uint64_t, uint64_t)>& on_round = {},
                         const EpochRunStart& start = {});

}  // namespace qemflow::nodes
