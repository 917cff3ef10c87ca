// Plan samples as one float32 table (docs/protocol.md, plan's `samples`: "attachment"): plan and
// plan.session.step replies carry it instead of a JSON tree of samples, which costs tens of
// milliseconds to build, print and parse for a thousand samples.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "terrastride/planner/trajectory.hpp"
#include "terrastride/service/protocol.hpp"

namespace terrastride::service {

// An attachment named "samples", one row per sample; the column names go into
// result["samples"] = {"attachment", "columns", "rows"}.
protocol::Attachment samples_table(const std::vector<planner::TrajectorySample>& samples,
                                   const std::vector<std::string>& feet, nlohmann::json* result);

}  // namespace terrastride::service
