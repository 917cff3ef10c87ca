// Top level of the planner: build the SRBD problem for a robot, gait and terrain, solve it with
// Ipopt, sample the solution and check it densely against the exact terrain.
#pragma once

#include <string>
#include <vector>

#include "terrastride/planner/dense_checks.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/solver.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

struct PlanOutcome {
  Trajectory trajectory;  // samples every sample_dt, solver stats and dense checks
  SolveResult solve;
  bool success = false;  // solver optimal/acceptable
  std::string message;   // why not, when !success
};

// Warm start: a previous plan whose state at `shift` seconds becomes the new start; its contact
// schedule (plan.json "timeline") is reused from that instant on.
struct WarmStart {
  const Trajectory* previous = nullptr;
  double shift = 0.0;
  // The state to re-plan from (a robot's measured state); default: the previous plan at `shift`.
  const SrbdProblem::StartState* start = nullptr;
};

// `plan_terrain` is what the optimiser sees (smooth, C2); `check_terrain` the exact one the
// dense checks use (may be the same object).
PlanOutcome plan_motion(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                        const terrain::HeightField& check_terrain, const PlannerOptions& options,
                        double sample_dt, const WarmStart& warm = {});

// The number of gait cycles for a request that names none (`plan` and the socket's plan without
// "cycles"): ProblemOptions' 3, or more when the goal lies farther from the start than 3 strides
// of the robot, a stride being the length of its range-of-motion box along x (2 b_x, the least
// over the legs): every gait moves each foot once a cycle, and a foot cannot travel further
// relative to the base than its box. Go2 (box 0.31 m) asked for 1 m in 3 cycles reached with the
// base (18 deg of roll and pitch at pallet_14's edge, a shin 1 mm into it); it gets 4. HyQ (box
// 0.5 m) keeps 3 up to 1.5 m.
int default_cycles(const robot::RobotModel& robot, const Eigen::Vector3d& start,
                   const Eigen::Vector3d& goal);

// The timeline of a plan: its stored "timeline" key, or rebuilt from gait/cycles/duration.
PhaseTimeline timeline_of(const Trajectory& plan);

// State of a plan at time t (positions and their rates by cubic Hermite interpolation between
// samples, exact within one cubic spline segment; accelerations and forces linear; contact from the
// sample at or before t).
TrajectorySample interpolate_plan(const Trajectory& plan, double t);

// The goal a re-plan of `plan` keeps: x, y and yaw of the base at its last sample.
Eigen::Vector3d goal_of(const Trajectory& plan);

// The line a re-plan of `plan` shapes its base path along (ProblemOptions::path_line): the one
// `plan` recorded ("path_line", a re-plan's), else from its first base position to its goal.
void set_path_line_of(const Trajectory& plan, ProblemOptions* options);
// ProblemOptions::start_lead of a re-plan of `plan` from `start` at time t: how far `start` lies
// ahead of `plan`'s state at t along the options' path line (set first), 0 when behind or on it.
void set_start_lead_of(const Trajectory& plan, double t, const SrbdProblem::StartState& start,
                       ProblemOptions* options);
// plan.json's "path_line": [x0, y0, x1, y1] of the options' path line.
nlohmann::json path_line_json(const ProblemOptions& options);

// The start state a re-plan from `plan` at time t begins with (base pose and rates, feet).
SrbdProblem::StartState start_state_of(const Trajectory& plan, double t);
// The same from one state (a plan sample, or a measured state in plan.json's terms).
SrbdProblem::StartState start_state_of(const TrajectorySample& state);

// The ZYX Euler-angle rates (yaw, pitch, roll rates, as in SrbdProblem::StartState) of a base at
// orientation `euler_zyx` turning with the world-frame `angular_velocity` (plan.json's): solves
// w = E(e) e', the convention the planner's splines use. E is singular at pitch = +-90 deg.
Eigen::Vector3d euler_rates_of(const Eigen::Vector3d& euler_zyx,
                               const Eigen::Vector3d& angular_velocity);

// Samples the solution x every dt (and at its end) into a Trajectory (without solver/checks).
Trajectory sample_solution(const SrbdProblem& problem, const std::vector<double>& x, double dt);

}  // namespace terrastride::planner
