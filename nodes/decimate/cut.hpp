#pragma once
// The global step of a round: from the summed per-patch summaries, choose the cut
// (cost threshold) every patch applies. Pure functions of small inputs, so in core
// (one summary) and out of core (summed summaries) choose the same cut.
//
// Rule (greedy-level quality): a round removes at most `round_fraction` of the current
// faces and at most `candidate_fraction` of what all candidates would remove, taking
// the cheapest candidates by whole cost bins; this keeps expensive local
// minima for later rounds, when cheaper edges have appeared, as greedy QEM would.
// When the remaining excess fits in one round, the cut is exact instead: candidates
// in the global total order, as long a prefix as removes no more than needed
// (exact_cut merges the patches' sorted candidate lists).
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "nodes/decimate/decimator.hpp"

namespace qemflow::nodes {

struct RoundPlan {
  enum class Kind { stop, bin_cut, exact_cut } kind = Kind::stop;
  RoundCut cut;          // for bin_cut
  uint64_t needed = 0;   // for exact_cut: faces still to remove
};

RoundPlan plan_round(const RoundSummary& total, uint64_t faces, uint64_t target_faces,
                     double round_fraction, double candidate_fraction = 1.0);

// The cut removing as many faces as possible but no more than `needed`, taking
// candidates in key order from the patches' sorted lists; nullopt when none fits.
std::optional<RoundCut> exact_cut(std::span<const std::span<const Candidate>> sorted_lists,
                                  uint64_t needed);

}  // namespace qemflow::nodes
