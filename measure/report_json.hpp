#pragma once
// JSON forms of the measure reports, as `qemflow compare --json` and `info --json`
// print them. Field names are part of the CLI contract (README).
#include <nlohmann/json.hpp>

#include "measure/distance.hpp"
#include "measure/topology.hpp"

namespace qemflow::measure {

nlohmann::json to_json(const BoundingBox& box);
nlohmann::json to_json(const DirectedDistance& distance, double bbox_diagonal);
// {distances:{a_to_b, b_to_a, symmetric: {absolute:{hausdorff,mean,rms}, relative:{...}}},
//  bbox_diagonal, sample_density, samples:{a_to_b:{vertex,face}, b_to_a:{...}}, flipped_faces}
nlohmann::json to_json(const DistanceReport& report);
// Counters present in `stats` only (optional ones are omitted when not computed).
nlohmann::json to_json(const TopologyStats& stats);

}  // namespace qemflow::measure
