// plan.json: reading and writing a Trajectory (format in docs/formats.md,
// "plan.json"), and reading a measured start state in the same conventions.
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {

// A malformed plan or start-state file; the message names the file and the field
// ("plan.json: samples[3].t: ...").
class PlanFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

nlohmann::json plan_to_json(const Trajectory& trajectory);
// The "samples" array of plan.json.
nlohmann::json samples_to_json(const std::vector<TrajectorySample>& samples);

// Most of plan.json is its samples (1.4 of 2.1 MB for an 11 s plan), and they are final once the
// planner returns, while the post-hoc checks still add keys to the rest. serialise_samples()
// turns them into text ahead, e.g. on the second core while the checks run (`terrastride plan`),
// and plan_text() joins that text with the rest of the document: the same text, byte for byte,
// as plan_to_json(t).dump(1) plus a newline. Samples serialised from another plan are refused
// (std::logic_error).
struct SerialisedSamples {
  std::string text;  // the array as the document writes it, at its indentation
  std::size_t count = 0;
  double first_t = 0.0, last_t = 0.0;  // which samples they were
};
SerialisedSamples serialise_samples(const std::vector<TrajectorySample>& samples);
std::string plan_text(const Trajectory& trajectory, const SerialisedSamples* samples = nullptr);

// Validates every field it reads: types, vector sizes, finite numbers, increasing times, one foot
// entry per named foot. Keys it does not know are kept in Trajectory::extra.
Trajectory plan_from_json(const nlohmann::json& json, const std::string& source);

// Writes atomically (temporary file, then rename), so a failed run leaves no half-written plan.
// `samples`: the trajectory's samples serialised ahead (plan_text), or null.
void write_plan_file(const std::string& path, const Trajectory& trajectory,
                     const SerialisedSamples* samples = nullptr);
Trajectory read_plan_file(const std::string& path);

// The robot a plan was made with: the definition it carries ("robot_file"), or, for a plan that
// carries none (written before plans carried their robot), the shipped robot it names (hyq when
// it names none). A carried definition is never looked up by name, so two robots of one name are
// never confused. Throws PlanFileError (a carried definition that is not a valid robot file, or
// whose name differs from "robot") or robot::RobotFileError (an unknown name); `source` names the
// plan in messages.
robot::RobotModel robot_of_plan(const Trajectory& trajectory, const std::string& source);

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
