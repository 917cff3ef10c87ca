// plan.json: reading and writing a Trajectory (format in DESIGN.md, "The terrastride command
// line").
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

// A malformed plan file; the message names the file and the field ("plan.json: samples[3].t: ...").
class PlanFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

nlohmann::json plan_to_json(const Trajectory& trajectory);

// Validates every field it reads: types, vector sizes, finite numbers, increasing times, one foot
// entry per named foot. Keys it does not know are kept in Trajectory::extra.
Trajectory plan_from_json(const nlohmann::json& json, const std::string& source);

// Writes atomically (temporary file, then rename), so a failed run leaves no half-written plan.
void write_plan_file(const std::string& path, const Trajectory& trajectory);
Trajectory read_plan_file(const std::string& path);

}  // namespace terrastride::planner
