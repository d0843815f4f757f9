#pragma once
// The fields the in-core report (apps/qemflow/cmd_simplify.cpp) and the out-of-core one
// (nodes/pipeline/ooc_command.cpp) share, each written by one function so the two
// reports name them alike and compare field for field.

#include <string>

#include <nlohmann/json.hpp>

#include "nodes/decimate/cut.hpp"
#include "nodes/decimate/decimator.hpp"

namespace qemflow::nodes {

// The schedule the epochs ran: epoch_rounds, cut_rise, flat_cut_rise, charge_from.
void report_schedule(nlohmann::json& report, const EpochOptions& schedule);

// `prefix` + refreshes, charges, validity_checks.
void report_work(nlohmann::json& report, const std::string& prefix, const DecimatorWork& work);

}  // namespace qemflow::nodes
