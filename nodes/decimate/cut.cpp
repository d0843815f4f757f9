#include "nodes/decimate/cut.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace qemflow::nodes {

RoundPlan plan_round(const RoundSummary& total, uint64_t faces, uint64_t target_faces,
                     double round_fraction, double candidate_fraction) {
  RoundPlan plan;
  if (faces <= target_faces || total.candidate_faces == 0) return plan;
  const uint64_t needed = faces - target_faces;
  const uint64_t budget = std::max<uint64_t>(
      1, static_cast<uint64_t>(std::floor(std::min(round_fraction * double(faces),
                                                   candidate_fraction * double(total.candidate_faces)))));
  // Largest bin whose cumulative count stays within the budget (at least the first
  // non-empty bin, so every round makes progress).
  uint64_t cumulative = 0;
  size_t chosen = kCostBins;
  for (size_t bin = 0; bin < kCostBins; ++bin) {
    const uint64_t n = total.faces_per_bin[bin];
    if (n == 0) continue;
    if (chosen != kCostBins && cumulative + n > budget) break;
    cumulative += n;
    chosen = bin;
  }
  if (cumulative >= needed) {
    plan.kind = RoundPlan::Kind::exact_cut;
    plan.needed = needed;
    return plan;
  }
  plan.kind = RoundPlan::Kind::bin_cut;
  plan.cut.key = EdgeKey::above_all_of(cost_bin_upper(chosen));
  return plan;
}

double epoch_cut_rise(const RoundSummary& total, const EpochOptions& options) {
  // Flat regions (zero-cost candidates, bin 0) lose about the same share of their faces
  // every round whatever the cut, since equal costs leave only the local minima of the
  // tie order independent; the curved regions follow the cut. Fewer rounds for the same
  // removal leave the flat regions dense and take the faces from the curved ones (the
  // generated terrain's slab at rise 0.75: 2084 of its 10000 faces on the flat sides and
  // bottom instead of 1070, RMS +36%), so where candidates are flat the epoch keeps
  // the slow rise and its rounds.
  const double slow = std::min(options.flat_cut_rise, options.cut_rise);
  if (total.candidate_faces == 0) return slow;
  const double flat_share = double(total.faces_per_bin[0]) / double(total.candidate_faces);
  return slow + (options.cut_rise - slow) * std::max(0.0, 1.0 - flat_share / kFullyFlatShare);
}

EpochPlan plan_epoch(const RoundSummary& total, uint64_t faces, uint64_t target_faces,
                     bool relaxed, const EpochOptions& options) {
  EpochPlan plan;
  if (faces <= target_faces) return plan;
  if (total.candidate_faces == 0) {
    if (!relaxed) plan.kind = EpochPlan::Kind::relax;
    return plan;
  }
  const RoundPlan round = plan_round(total, faces, target_faces, options.round_fraction,
                                     options.candidate_fraction);
  const uint64_t needed = faces - target_faces;
  if (round.kind == RoundPlan::Kind::exact_cut) {
    plan.kind = EpochPlan::Kind::exact_cut;
    plan.needed = needed;
    return plan;
  }
  const size_t first_bin = cost_bin(round.cut.key.cost);
  uint64_t first_round = 0;
  for (size_t bin = 0; bin <= first_bin; ++bin) first_round += total.faces_per_bin[bin];
  plan.kind = EpochPlan::Kind::bin_cut;
  // Rounds: as many as E while the faces they may remove stay within what is needed:
  // the first round removes what its cut takes of the candidates (known), every later
  // round is taken to remove round_fraction of the faces left (its cut is higher and
  // its candidates are not known yet; the bulk rounds remove 3-6%).
  const uint32_t most = std::max<uint32_t>(1, options.epoch_rounds);
  uint32_t rounds = 1;
  double left = double(faces - first_round);
  while (rounds < most) {
    left *= 1.0 - options.round_fraction;
    if (double(faces) - left >= double(needed)) break;
    ++rounds;
  }
  // Round r's cut (r = 0, 1, ...): the first round's bin raised by floor(r * rise)
  // bins, a schedule fixed in advance that follows (below) the pace at which the
  // round-by-round cut rises (about one bin per round), so no round takes much more
  // of its candidates than the first one does.
  plan.cuts.push_back(round.cut);
  const double rise = epoch_cut_rise(total, options);
  for (uint32_t r = 1; r < rounds; ++r) {
    const size_t bin = std::min<size_t>(kCostBins - 1, first_bin + size_t(std::floor(r * rise)));
    plan.cuts.push_back({EdgeKey::above_all_of(cost_bin_upper(bin)), false});
  }
  return plan;
}

DecimateParams summary_params(const DecimateParams& params, uint64_t epoch_start_faces,
                              uint64_t target_faces, const EpochOptions& options) {
  DecimateParams summary = params;
  if (options.charge_from > 0.0 && double(epoch_start_faces) > options.charge_from * double(target_faces))
    summary.deviation_weight = 0.0;
  return summary;
}

DecimateParams relaxed_params(const DecimateParams& params) {
  DecimateParams relaxed = params;
  relaxed.min_normal_cos = std::min(relaxed.min_normal_cos, 0.0);
  relaxed.min_face_quality = std::min(relaxed.min_face_quality, 1e-9);
  return relaxed;
}

std::optional<RoundCut> exact_cut(std::span<const std::span<const Candidate>> lists,
                                  uint64_t needed) {
  std::vector<size_t> at(lists.size(), 0);
  uint64_t removed = 0;
  std::optional<RoundCut> cut;
  for (;;) {
    size_t best = lists.size();
    for (size_t i = 0; i < lists.size(); ++i)
      if (at[i] < lists[i].size() &&
          (best == lists.size() || lists[i][at[i]].key < lists[best][at[best]].key))
        best = i;
    if (best == lists.size()) break;
    const Candidate& c = lists[best][at[best]];
    if (removed + c.faces_removed > needed) break;
    removed += c.faces_removed;
    cut = RoundCut{c.key, false};
    ++at[best];
    if (removed == needed) break;
  }
  if (cut) return cut;
  // Nothing fits as a prefix (one face left, the cheapest candidate removes two):
  // take the cheapest candidate that removes exactly one face, if any.
  std::optional<RoundCut> single;
  for (const auto& list : lists)
    for (const auto& c : list)
      if (c.faces_removed == 1 && (!single || c.key < single->key)) single = RoundCut{c.key, true};
  return single;
}

std::vector<Candidate> exact_cut_share(std::vector<Candidate> sorted, uint64_t needed) {
  uint64_t removed = 0;
  size_t keep = 0;
  while (keep < sorted.size() && removed + sorted[keep].faces_removed <= needed)
    removed += sorted[keep++].faces_removed;
  if (keep == sorted.size()) return sorted;
  // The candidate that ends the prefix stays: without it, a single-face candidate
  // further on would look like the next in order, and a cut at its key would take
  // every candidate before it.
  size_t size = keep + 1;
  if (sorted[keep].faces_removed != 1) {
    const auto single = std::find_if(sorted.begin() + ptrdiff_t(size), sorted.end(),
                                     [](const Candidate& c) { return c.faces_removed == 1; });
    if (single != sorted.end()) sorted[size++] = *single;
  }
  sorted.resize(size);
  return sorted;
}

}  // namespace qemflow::nodes
