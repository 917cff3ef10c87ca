// Plan samples as one float32 table (docs/protocol.md, plan's `samples`: "attachment"): plan and
// plan.session.step replies carry it instead of a JSON tree of samples, which costs tens of
// milliseconds to build, print and parse for a thousand samples.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "terrastride/planner/trajectory.hpp"
#include "terrastride/service/protocol.hpp"

namespace terrastride::service {

// An attachment named "samples", one row per sample; the column names go into
// result["samples"] = {"attachment", "columns", "rows"}.
protocol::Attachment samples_table(const std::vector<planner::TrajectorySample>& samples,
                                   const std::vector<std::string>& feet, nlohmann::json* result);

// The result of an op that answers with a plan (plan, plan.session.step): `reply(trajectory)`.
// With `encoding` "attachment" the samples leave the trajectory first and travel as the table,
// appended to `attachments` (the result's "samples" describes it); with "json" they stay in it.
template <class Reply>
nlohmann::json plan_result(planner::Trajectory& trajectory, const std::string& encoding,
                           std::vector<protocol::Attachment>* attachments, const Reply& reply) {
  if (encoding != "attachment") return reply(trajectory);
  const std::vector<planner::TrajectorySample> samples = std::move(trajectory.samples);
  trajectory.samples.clear();
  nlohmann::json result = reply(trajectory);
  attachments->push_back(samples_table(samples, trajectory.feet, &result));
  return result;
}

}  // namespace terrastride::service
