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
//
// Epochs: the global decision is taken once per epoch (plan_epoch, from the summary at
// the epoch's start) and covers the epoch's rounds, so an out-of-core run needs one
// pass over the patches per epoch, not two per round. An epoch is either
//   stop, relax (no candidate anywhere: relax the guards once, plan again),
//   exact (one round with the exact_cut of the owned candidate lists), or
//   bin (rounds r = 0.., each: prepare_round, apply_cut(cuts[r])): cuts[0] by the rule
//   above, cuts[r] = cuts[0]'s bin + floor(r * rise) bins, a rise fixed for the epoch
//   below the pace of the round-by-round cut (about one bin per round), so every
//   round removes faces: 0.75 bins, or 0.5 where many candidates are flat (cost 0;
//   flat regions shrink per round, not per bin). Up to epoch_rounds rounds, as long
//   as the first round's removal plus round_fraction of the faces left per later round
//   stays within what is needed (END GAME: fewer rounds, then exact), so the exact
//   target is still hit.
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

struct EpochOptions {
  double round_fraction = 0.1;      // most faces a round may remove
  double candidate_fraction = 0.75;  // most of the candidates' faces a round may remove
  uint32_t epoch_rounds = 4;        // rounds per epoch in the bulk phase (E)
  // Cost bins (4 per octave) the cut rises per round of an epoch: cut_rise where no
  // candidate is flat (cost 0), min(flat_cut_rise, cut_rise) where kFullyFlatShare of the
  // candidates' faces or more are flat, linear in the flat share between (epoch_cut_rise).
  // flat_cut_rise >= cut_rise: the fixed rise cut_rise.
  double cut_rise = 0.75;
  double flat_cut_rise = 0.5;
  // With charge_from > 0 the deviation charge (DecimateParams::deviation_weight) is
  // weighed only in the last stretch: from the summary after an epoch that began with
  // at most charge_from x the target faces (the first summary: the input's count);
  // before it, an edge costs its quadric part alone. 0 (the default): charged from the
  // start. A speed option: at 2, 33-53% less CPU in core for RMS 1.5-11% higher, but
  // thin tips that the quadric alone cuts off before the charge starts are lost
  // (nodes/decimate/README.md, "The charge in the last stretch").
  double charge_from = 0.0;
};

struct EpochPlan {
  enum class Kind { stop, relax, bin_cut, exact_cut } kind = Kind::stop;
  std::vector<RoundCut> cuts;  // bin_cut: the cut of each round of the epoch (rising)
  uint64_t needed = 0;         // exact_cut: faces still to remove
};

// The flat share of the candidates' faces at which an epoch's cut rises at flat_cut_rise.
inline constexpr double kFullyFlatShare = 0.1;

// The epoch's rise in bins per round (EpochOptions::cut_rise), from the share of the
// summary's candidate faces that are flat (bin 0): a pure function of the summed sums.
double epoch_cut_rise(const RoundSummary& total, const EpochOptions& options);

// `total`: the summed summaries of the epoch's first round; `faces`: the global face
// count; `relaxed`: the guards were relaxed already (relax is offered once).
EpochPlan plan_epoch(const RoundSummary& total, uint64_t faces, uint64_t target_faces,
                     bool relaxed, const EpochOptions& options);

// The params of the summary that follows an epoch begun with `epoch_start_faces` faces
// (for the first summary: the input's count), and of the rounds planned from it:
// `params` (with the run's deviation weight) with the charge off (weight 0) while
// epoch_start_faces > charge_from x target_faces. A pure function of global counts,
// so in core and out of core weigh the charge from the same summary on: out of core a
// pass's summary follows the rounds of the epoch its state began, so the count the
// rule reads is the one the pass starts from (nodes/pipeline/epochs.hpp).
DecimateParams summary_params(const DecimateParams& params, uint64_t epoch_start_faces,
                              uint64_t target_faces, const EpochOptions& options);

// The relaxed geometric guards (normals may turn up to 90 degrees, faces may get thin
// but not degenerate) used once no candidate is left above the target.
DecimateParams relaxed_params(const DecimateParams& params);

// The cut removing as many faces as possible but no more than `needed`, taking
// candidates in key order from the patches' sorted lists; nullopt when none fits.
std::optional<RoundCut> exact_cut(std::span<const std::span<const Candidate>> sorted_lists,
                                  uint64_t needed);

// What of one patch's sorted candidate list an exact cut can use, so a patch sends
// only that: the prefix removing at most `needed` faces, the candidate after it (the
// merge stops there at the latest, since the other patches only add to what is taken
// before it), and the cheapest single-face candidate after that (the fallback).
// exact_cut of every patch's share equals exact_cut of the whole lists.
std::vector<Candidate> exact_cut_share(std::vector<Candidate> sorted, uint64_t needed);

}  // namespace qemflow::nodes
