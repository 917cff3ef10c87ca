// plan.json: reading and writing a Trajectory (format in docs/design.md
// §3.5), and reading a measured start state in the same conventions.
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

// A malformed plan or start-state file; the message names the file and the field
// ("plan.json: samples[3].t: ...").
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

// A robot's measured state to re-plan from `previous` at `start_time` (`terrastride plan
// --start-state`, the service's "start_state"), in plan.json's conventions (world frame):
//   {"base": {"position": [x,y,z], "euler_zyx": [yaw,pitch,roll], "linear_velocity": [...],
//             "angular_velocity": [...]},
//    "feet": {"LF": {"position": [...], "velocity": [...]}, ...}}   (keyed by previous.feet)
// Every field may be left out and then is the previous plan's at `start_time`, so the state of a
// field that is not measured stays consistent with the plan being continued. The angular velocity
// becomes Euler rates at the resulting orientation (euler_rates_of). Unknown keys are errors, so
// a misspelt field is not silently replaced by the plan's value.
SrbdProblem::StartState start_state_from_json(const nlohmann::json& json, const std::string& source,
                                              const Trajectory& previous, double start_time);
SrbdProblem::StartState read_start_state_file(const std::string& path, const Trajectory& previous,
                                              double start_time);

}  // namespace terrastride::planner
