#include "nodes/decimate/report_fields.hpp"

namespace qemflow::nodes {

void report_schedule(nlohmann::json& report, const EpochOptions& schedule) {
  report["epoch_rounds"] = schedule.epoch_rounds;
  report["cut_rise"] = schedule.cut_rise;
  report["flat_cut_rise"] = schedule.flat_cut_rise;
  report["charge_from"] = schedule.charge_from;
}

void report_work(nlohmann::json& report, const std::string& prefix, const DecimatorWork& work) {
  report[prefix + "refreshes"] = work.refreshes;
  report[prefix + "charges"] = work.charges;
  report[prefix + "validity_checks"] = work.validity_checks;
}

}  // namespace qemflow::nodes
