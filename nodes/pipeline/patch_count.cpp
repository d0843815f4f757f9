#include "nodes/pipeline/patch_count.hpp"

#include <algorithm>

namespace qemflow::nodes::pipeline {

uint64_t faces_per_patch(uint64_t budget_bytes, const PatchBudget& budget) {
  const double per_face = double(budget.decimator_bytes_per_face) * budget.halo_factor * budget.concurrent_patches;
  return std::max<uint64_t>(1, uint64_t(double(budget_bytes) * budget.working_fraction / per_face));
}

uint32_t patch_count_for_budget(uint64_t faces, uint64_t budget_bytes, const PatchBudget& budget) {
  const uint64_t per_patch = faces_per_patch(budget_bytes, budget);
  const uint64_t patches = (faces + per_patch - 1) / per_patch;
  return uint32_t(std::clamp<uint64_t>(patches, 1, budget.max_patches));
}

}  // namespace qemflow::nodes::pipeline
