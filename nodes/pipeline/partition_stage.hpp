#pragma once
// The partition stage of the out-of-core pipeline (paper §4.3-4.4, DESIGN §4): from
// the loaded blocks to a classifier that gives every face its owner patch.
//
//   blocks ──area pass──► radius ──sample pass (a sampler per frame, merged)──► samples
//   samples ──proximity graph──► FCM (C clusters) ──ν-SVM planes (DAG)──► classifier
//
// Contract
// - Reads every block frame twice (engine::for_each_frame): once for the surface area
//   (an exact, order-free sum), once for Poisson-disk samples (each frame's sampler
//   merged in the sink; the sampler's result does not depend on merge order).
// - Sample count: about max(20000, 500 C), capped by what the stage's lease holds
//   (partition_budget.hpp: max_samples_for_budget); the lease is taken from the job's
//   governor for the stage's duration (Error(resource) if not even 2000 samples fit).
// - C = options.clusters if set, else patch_count_for_budget(kept faces, budget).
//   C == 1: no sampling at all; every face is owned by patch 0 (in core).
// - The owner of a face is classifier.classify(barycenter of its three positions)
//   (Partition::owner_of): cheap (C−1 plane tests), so readers recompute it for
//   every face they read instead of storing it.
// - Deterministic: the same blocks give bit-identical planes for any thread count,
//   frame order or block size (faces_per_block): the samples depend only on the set of
//   faces, and every later kernel is deterministic (nodes/partition contracts).
#include <cstdint>

#include "engine/blocks.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"
#include "nodes/partition/plane_classifier.hpp"

namespace qemflow::nodes::pipeline {

struct PartitionOptions {
  uint32_t clusters = 0;      // 0: from the budget (patch_count.hpp); 1: no partition
  uint64_t samples = 0;       // 0: max(20000, 500 C), capped by the lease
  uint64_t seed = 0;          // sampler seed
};

struct Partition {
  uint32_t clusters = 1;
  partition::PlaneClassifier classifier;  // classes == clusters when clusters > 1
  // Diagnostics for the report.
  uint64_t samples = 0;
  double radius = 0;
  double area = 0;
  uint32_t fcm_iterations = 0;
  std::vector<uint64_t> samples_per_cluster;

  uint32_t owner_of(const std::array<Point, 3>& positions) const {
    return clusters <= 1 ? 0 : classifier.classify(partition::barycenter(positions));
  }
  uint32_t owner_of(const engine::BlockFace& face) const { return owner_of(face.positions); }
};

// The clusters for `mesh` when options.clusters == 0: from the governor's budget.
uint32_t clusters_for(const engine::LoadedMesh& mesh, uint64_t budget_bytes, const PartitionOptions& options);

Partition partition_blocks(engine::Job& job, engine::ScratchStore& scratch, const engine::LoadedMesh& mesh,
                           const PartitionOptions& options);

// Every frame of every block, in block order (what for_each_frame takes).
std::vector<engine::FrameRef> all_block_frames(const engine::LoadedMesh& mesh);

}  // namespace qemflow::nodes::pipeline
