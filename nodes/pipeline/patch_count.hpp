#pragma once
// How many patches (clusters) the out-of-core run needs for a budget (issue 5: "the
// number of patches follows from the budget; --clusters N overrides").
//
// Contract
// - A patch's decimator holds about `decimator_bytes_per_face` per face (measured:
//   `qemflow simplify --in-core` on generated blobs, peak RSS slope between 0.5M and
//   2M faces = 109 bytes per input face, reading included), times `halo_factor` for
//   its halo (owned + halo faces ≤ 1.5 × owned), and `concurrent_patches` patches run
//   at once. Of the budget, `working_fraction` goes to patches; the rest is for the
//   block streams, the I/O thread's buffers and the process baseline.
// - patch_count_for_budget() = ceil(faces / faces_per_patch), at least 1 (1 means the
//   whole mesh fits: no partition, in core), at most max_patches.
// - Pure arithmetic: the same inputs give the same count everywhere.
#include <cstdint>

namespace qemflow::nodes::pipeline {

struct PatchBudget {
  uint64_t decimator_bytes_per_face = 110;
  double halo_factor = 1.5;
  uint32_t concurrent_patches = 2;
  double working_fraction = 0.6;
  uint32_t max_patches = 256;
};

// Owned faces one patch may hold under `budget_bytes` (the --mem-budget, baseline included).
uint64_t faces_per_patch(uint64_t budget_bytes, const PatchBudget& budget = {});

// Patches for `faces` (kept faces of the loaded mesh) under `budget_bytes`.
uint32_t patch_count_for_budget(uint64_t faces, uint64_t budget_bytes, const PatchBudget& budget = {});

}  // namespace qemflow::nodes::pipeline
