// One plan request, read and validated in one place for `terrastride plan` and the socket's
// `plan`: the socket's JSON fields are the request; the CLI turns the flags it was given into the
// same fields. So both check the same things, with the same limits and defaults, and name the
// same field when something is wrong (docs/protocol.md, "plan").
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::service {

// A field that is malformed or out of range: the planner's RequestError (field() as the socket
// names it: "sample_dt", "goal", "init", "start_state"; problem(); what() "field: problem").
using RequestFieldError = planner::RequestError;

struct PlanRequest {
  std::string terrain = "current";  // a scene name, a terrain directory, or the socket's "current"
  planner::PlannerOptions options;  // gait, cycles, duration, goal, start, sets, settings, timing
  double sample_dt = 0.01;
  std::string samples = "json";  // the socket's sample encoding: "json" or "attachment"
  // A re-plan ("init"): the plan it continues, the time on it to start from, and optionally the
  // robot's measured state there.
  bool replan = false;
  planner::Trajectory previous;
  double start_time = 0.0;
  bool has_start_state = false;
  planner::SrbdProblem::StartState start_state;

  // The planner's warm start, pointing into this request (which must outlive the plan).
  planner::WarmStart warm_start() const;
};

// Reads the fields of a plan request (docs/protocol.md, "plan"): terrain, gait, cycles,
// duration, goal, start, constraints, feasibility, sample_dt, samples, max_time,
// optimize_timing, init, start_time, start_state. Every field is checked before anything is
// loaded or solved: types, the planner's request limits (request_limits.hpp), constraint-set and
// feasibility names, init's robot, feet, timeline and horizon, the start state. A field left out
// takes the default; a re-plan keeps init's gait, goal, constraint sets, feasibility settings and
// timing choice unless the request gives them, and refuses a gait other than init's (its contact
// schedule is what the re-plan continues). Unknown fields are the caller's to refuse (the socket
// lists each operation's fields; the CLI has flags). Throws RequestFieldError.
PlanRequest read_plan_request(const nlohmann::json& fields, const robot::RobotModel& robot);

// A measured start state's stance feet must stand on the terrain the plan uses: a stance foot
// the planner is handed 2 cm above the ground floats there (carrying its share of the weight),
// and 2 cm below, the solve cannot start. Within kStanceTolerance a stance foot is placed on the
// terrain and the correction is returned ([{"foot", "measured_z", "terrain_z"}], recorded in
// plan.json as "start_state_corrections"); farther off, RequestFieldError("start_state", ...)
// names the foot, its height and the terrain's. No-op without a measured state.
constexpr double kStanceTolerance = 0.01;  // m: a legged robot's state estimate is this good
nlohmann::json settle_stance_feet(PlanRequest* request, const terrain::HeightField& terrain);

// A fresh plan's start and goal stances on the terrain it is planned on: the robot's nominal feet
// at `start` (where the plan puts them) must lie on the map, observed and safe for the foot; at
// `goal` (where the planner may still move them) on the map and observed; first, the goal's feet
// on ground reachable from the start's level (planner::check_level_reach: not a ceiling, not a
// cupboard top). Throws
// RequestFieldError("start" or "goal") naming the foot and the place, before any solve (a start
// off the recorded floor used to plan "optimal" with 16 of 16 footholds unsafe). No-op for
// re-plans (their start is the robot's state, and the goal init's).
void check_stances_on_terrain(const PlanRequest& request, const robot::RobotModel& robot,
                              const terrain::HeightField& terrain);

}  // namespace terrastride::service
