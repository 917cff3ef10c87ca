// plan_motion: the problem for a request, its solve, the plan sampled from the solution and its
// dense checks; and the limits every plan request meets (request_limits.hpp).
#include "terrastride/planner/planner.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <sstream>

#include "terrastride/planner/before_solve.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/quality.hpp"
#include "terrastride/planner/reachability.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/planner/violation_report.hpp"

namespace terrastride::planner {

namespace {

constexpr double kDenseDt = 0.002;  // docs/design.md §6.8: dense checks every 2 ms

// The most iterations a solve with the path-shape rows gets before it is solved again without them.
// Measured (docs/results/2026-11-28-measurements.md): the clean shaped plans of the off-path suite
// and the scenes took 6-74 iterations; the failing ones ended infeasible after 45-99 or stalled
// after 234-825 (the flat 2.4 s `all` crawl: 825, 41 s, then 86 without the rows).
constexpr int kShapedMaxIterations = 150;

// The path-shape families whose rows `problem` carries, in the order of `all`.
std::vector<std::string> path_shape_kinds(const SrbdProblem& problem) {
  std::vector<std::string> kinds;
  for (const char* kind : {"monotone_progress", "lateral_corridor", "swing_apex"})
    for (const auto& piece : problem.pieces())
      if (piece->kind == kind) {
        kinds.push_back(kind);
        break;
      }
  return kinds;
}

// The timeline a request plans over and the start it plans from: a re-plan continues its
// previous plan's timeline from `warm.shift` (from the measured start, else the plan's state
// there); a fresh plan makes one from the gait, with a lead-in long enough for the force ramps.
struct PlanSetup {
  PhaseTimeline timeline;
  nlohmann::json rest_lead_in;  // the lead-in a plan from rest was given (with_rest_lead_in)
  SrbdProblem::StartState start;
  bool has_start = false;
  const SrbdProblem::StartState* start_ptr() const { return has_start ? &start : nullptr; }
};

PlanSetup replan_setup(const robot::RobotModel& robot, const std::vector<std::string>& feet,
                       const WarmStart& warm) {
  PlanSetup setup;
  const Trajectory& prev = *warm.previous;
  if (prev.feet != feet)
    throw RequestError("init.feet", "the plan's feet differ from robot " + robot.name + "'s");
  check_plan_horizon(prev.duration, "init.duration");
  if (!(warm.shift >= 0.0 && warm.shift < prev.duration))
    throw RequestError("start_time", "must be within [0, " + std::to_string(prev.duration) +
                                         ") s, the duration of the plan it continues");
  setup.timeline = timeline_of(prev);
  if (warm.shift > 0.0) setup.timeline = setup.timeline.cropped(warm.shift);
  if (warm.start) {
    if (warm.start->foot_position.size() != feet.size() ||
        warm.start->foot_velocity.size() != feet.size())
      throw std::invalid_argument(
          "warm-start state has " + std::to_string(warm.start->foot_position.size()) +
          " feet, robot " + robot.name + " has " + std::to_string(feet.size()));
    setup.start = *warm.start;
  } else {
    setup.start = start_state_of(prev, warm.shift);
  }
  setup.has_start = true;
  return setup;
}

PlanSetup fresh_setup(const robot::RobotModel& robot, const std::vector<std::string>& feet,
                      const PlannerOptions& options) {
  PlanSetup setup;
  Gait gait = gait_for_robot(options.gait, robot);  // timed to its size, its weight borne
  // A plan from rest with force ramps: the second foot to lift off may carry half the weight W
  // at the start (statics puts the crawl's LF on the loaded diagonal once LH has shed its load)
  // and sheds it at force_rate_max r at most, in W / (2 r); its lift-off comes no earlier than
  // twice that, W / r (0.41 s for HyQ at 2000 N/s), the gait's lead-in lengthened and the
  // duration kept. The flat 2.4 s `all` crawl lifted LF off at 0.22 s: LF shed its load at
  // nearly the full rate onto the right feet alone while LH swung, which threw the base 26.6 cm
  // to the left, and the path-shape rows could not be met (docs/design.md §6.4 "Path shape").
  // The robot's feasibility defaults only when force_ramp is asked for: computing them can
  // throw for a robot whose limits a `baseline` plan never reads.
  if (options.rest_boundaries && requests_constraint_set(options.constraints, "force_ramp")) {
    const FeasibilityOptions feasibility = feasibility_options(robot, options.feasibility_settings);
    if (feasibility.force_rate_max > 0.0) {
      const Gait led = with_rest_lead_in(gait, feet, options.cycles, options.duration,
                                         robot.mass * kGravity / feasibility.force_rate_max);
      if (led.lead_in != gait.lead_in)
        setup.rest_lead_in = {{"gait_lead_in", gait.lead_in}, {"lead_in", led.lead_in}};
      gait = led;
    }
  }
  setup.timeline = make_timeline(gait, feet, options.cycles, options.duration);
  // Without a duration the horizon is the gait's period times its cycles (plus lead-in/out).
  check_plan_horizon(setup.timeline.duration(), options.duration > 0.0 ? "duration" : "cycles");
  if (options.has_goal)
    require_joint_speeds_reachable(setup.timeline, gait.name, robot,
                                   (options.goal - options.start).head<2>().norm());
  return setup;
}

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// What a solve of `problem` starts with: a re-plan's Ipopt options and first-feasible stop.
std::vector<std::pair<std::string, std::string>> warm_ipopt_options(bool warm) {
  if (!warm) return {};
  // The shifted previous plan is feasible already when the start lies on it: its knots are
  // kept (PhaseTimeline::first_interval_elapsed) and so are its constraint points
  // (Layout::segment_points), so the check at iteration 0 returns it verified (pallet_15
  // shifted by 0.1, 0.37 or 2.5 s: 0 iterations; by 1 s: 2). Ipopt's defaults would push the
  // slacks 1 % away from their bounds and start the barrier at mu = 0.1; a small barrier and
  // push keep the warm start when it needs iterations. The barrier stays adaptive: a monotone
  // one, from a measured start 1 cm beside the plan and 0.05 m/s faster, ended infeasible after
  // 102 iterations (6.7 s); adaptive: optimal in 3 (offsets of 3 mm to 4 cm: 3-5).
  return {{"mu_init", "1e-4"}, {"bound_push", "1e-5"}, {"bound_frac", "1e-5"}};
}

// A plan's iterations and solver time count every solve it took: `from`'s are added to `to`'s.
void add_solve_effort(const SolveResult& from, SolveResult* to) {
  to->iterations += from.iterations;
  to->feasibility_iterations += from.feasibility_iterations;
  to->objective_iterations += from.objective_iterations;
  to->polish_iterations += from.polish_iterations;
  to->wall_s += from.wall_s;
}

// The solve, and when it fails with the path-shape rows (monotone_progress, lateral_corridor,
// swing_apex: preferences on the plan's shape, not feasibility; infeasible, stalled, or past
// kShapedMaxIterations) once more without them, within what is left of max_time; `problem` is
// then the unshaped one. Returns plan.json's "path_shape_fallback" (null: none). Not after a
// cancellation, nor when the time limit is spent.
nlohmann::json solve_with_shape_fallback(
    std::unique_ptr<SrbdProblem>* problem, const robot::RobotModel& robot,
    const terrain::HeightField& plan_terrain, const PlanSetup& setup,
    const PlannerOptions& problem_options, const PlannerOptions& options, const WarmStart& warm,
    std::chrono::steady_clock::time_point t_start, SolveResult* result) {
  const auto ipopt_options = warm_ipopt_options(warm.previous != nullptr);
  SolverOptions solver_options = options;
  // A warm start continues a plan that was optimised already: stop at its first verified
  // feasible iterate, as without an objective (a start on the plan re-verifies in 0 iterations).
  if (warm.previous) solver_options.stop_at_first_feasible = true;
  const std::vector<std::string> shape_kinds = path_shape_kinds(**problem);
  const int max_iterations = solver_options.max_iterations;
  if (!shape_kinds.empty())
    solver_options.max_iterations = std::min(max_iterations, kShapedMaxIterations);
  *result = solve(**problem, solver_options, ipopt_options);
  solver_options.max_iterations = max_iterations;
  auto time_left = [&] {
    return options.max_time > 0.0 ? options.max_time - seconds_since(t_start) : 1.0;
  };
  if (result->success || shape_kinds.empty() || result->status == "stopped" ||
      result->status == "time_limit" || time_left() <= 0.0 ||
      (options.should_stop && options.should_stop()))
    return nullptr;
  const SolveResult shaped = *result;
  nlohmann::json shape_fallback = {{"dropped", shape_kinds},
                                   {"shaped_status", shaped.status},
                                   {"shaped_iterations", shaped.iterations},
                                   {"shaped_max_violation", shaped.max_violation}};
  const auto left = violated_families(**problem, shaped.x, options.tolerance);
  if (!left.empty()) shape_fallback["shaped_violated"] = describe_violations(left);
  if (options.verbose)
    std::fprintf(stderr,
                 "plan: the solve with the path-shape rows ended '%s' after %d iterations; "
                 "solving again without them\n",
                 shaped.status.c_str(), shaped.iterations);
  PlannerOptions unshaped = problem_options;
  for (const char* name : {"monotone_progress", "lateral_corridor", "swing_apex_rise"})
    unshaped.feasibility_settings.emplace_back(name, 0.0);
  *problem = std::make_unique<SrbdProblem>(robot, plan_terrain, setup.timeline, unshaped,
                                           setup.start_ptr());
  if (warm.previous) (*problem)->warm_start_from(*warm.previous, warm.shift);
  // What is left after the rebuild too (a second problem of an 11 s plan takes tens of ms).
  if (options.max_time > 0.0) solver_options.max_time = std::max(time_left(), 1e-3);
  *result = solve(**problem, solver_options, ipopt_options);
  add_solve_effort(shaped, result);
  return shape_fallback;
}

// The joint-point refinement's dense check: every segment at steps of at most 1 ms (the finest
// --sample-dt a plan takes, request_limits.hpp), so that the post-hoc check at any sample step
// finds no instant this one missed by more than the motion within half a millisecond.
constexpr double kJointCheckDt = 0.001;
// The most iterations one refinement re-solve gets: it starts from a solution that the new rows
// alone cut off, a few points of a few legs.
constexpr int kRefinementMaxIterations = 150;

nlohmann::json joint_check_json(const JointDenseCheck& check, const robot::RobotModel& robot) {
  static const char* kJoints[3] = {"HAA", "HFE", "KFE"};
  auto worst = [&](int foot, int joint, double t) -> nlohmann::json {
    return {{"foot", robot.legs[foot].name}, {"joint", kJoints[joint]}, {"t", t}};
  };
  nlohmann::json j = {{"range_excess_rad", check.range_excess_rad},
                      {"intervals", check.violations.size()}};
  if (check.range_foot >= 0 && check.range_excess_rad > 0.0)
    j["range_worst"] = worst(check.range_foot, check.range_joint, check.range_t);
  if (has_velocity_limits(robot)) {
    j["velocity_ratio"] = check.velocity_ratio;
    if (check.velocity_foot >= 0)
      j["velocity_worst"] = worst(check.velocity_foot, check.velocity_joint, check.velocity_t);
  }
  if (has_torque_limits(robot)) {
    j["torque_ratio"] = check.torque_ratio;
    if (check.torque_foot >= 0)
      j["torque_worst"] = worst(check.torque_foot, check.torque_joint, check.torque_t);
  }
  return j;
}

// The check's points reduced to the rows the problem has: joint angles and velocities with
// "joints", torques (force polytope rows) with "polytope"; a point left with none is dropped.
void keep_rows_the_problem_has(JointDenseCheck* check, bool joints, bool polytopes) {
  auto& points = check->violations;
  for (JointPoint& point : points) {
    point.range = point.range && joints;
    point.velocity = point.velocity && joints;
    point.torque = point.torque && polytopes;
  }
  points.erase(std::remove_if(points.begin(), points.end(),
                              [](const JointPoint& p) { return !p.range && !p.velocity && !p.torque; }),
               points.end());
}

// Constraint-point refinement (as in direct collocation's mesh refinement): the joint rows hold
// at the knots and at points inside swings, and a joint may pass its range or velocity limit
// between them (Go2 with 8 rad/s knees, a 1.4 s trot: 1.009x in a swing; 1 rad/s knees, the
// default crawl: 1.415x in a stance leaving rest); likewise the force polytope rows (the torques)
// hold at a stance segment's knots and inner points only. After a successful solve of a problem
// with "joints" or "polytope" rows the solution is checked densely (dense_joint_check); where a
// joint exceeds its range or velocity limit ("joints") or its torque limit in stance
// ("polytope") the problem is built again with those rows at the worst instant of each such
// (segment, foot) as well, and solved from the solution to its first feasible point.
// At most options.joint_refinement_rounds times, within options.max_time; a re-solve that fails
// leaves the previous solution (and its problem) as the plan, which the post-hoc checks then
// judge as before. Rows are added only where a limit is exceeded, so a plan inside its limits is
// solved exactly as without refinement. Returns plan.json's "joint_refinement" (null: the check
// found nothing, or the problem has no joint rows).
nlohmann::json refine_joint_points(std::unique_ptr<SrbdProblem>* problem,
                                   const robot::RobotModel& robot,
                                   const terrain::HeightField& plan_terrain, const PlanSetup& setup,
                                   const PlannerOptions& options, const WarmStart& warm,
                                   std::chrono::steady_clock::time_point t_start,
                                   SolveResult* result) {
  const auto& sets = (*problem)->options().constraints;
  const bool joints = requests_constraint_set(sets, "joints"),
             polytopes = requests_constraint_set(sets, "polytope");
  if (options.joint_refinement_rounds <= 0 || !result->success || (!joints && !polytopes))
    return nullptr;
  auto check_solution = [&] {
    JointDenseCheck c = dense_joint_check(**problem, result->x, kJointCheckDt);
    keep_rows_the_problem_has(&c, joints, polytopes);
    return c;
  };
  JointDenseCheck check = check_solution();
  if (check.violations.empty()) return nullptr;
  nlohmann::json record = {{"before", joint_check_json(check, robot)}};
  nlohmann::json rounds = nlohmann::json::array();
  std::vector<JointPoint> points;  // every point added so far
  auto time_left = [&] {
    return options.max_time > 0.0 ? options.max_time - seconds_since(t_start) : 1.0;
  };
  SolverOptions solver_options = options;
  solver_options.stop_at_first_feasible = true;  // the solution was optimised already
  solver_options.max_iterations = std::min(options.max_iterations, kRefinementMaxIterations);
  std::string ended;
  while (!check.violations.empty()) {
    if (static_cast<int>(rounds.size()) >= options.joint_refinement_rounds) {
      ended = "rounds";
      break;
    }
    if (time_left() <= 0.0 || (options.should_stop && options.should_stop())) {
      ended = "time";
      break;
    }
    if (options.verbose)
      std::fprintf(stderr,
                   "plan: joints past their limits between the constraint points in %zu "
                   "intervals (velocity %.4g x its limit, torque %.4g x its limit, %.4g rad "
                   "beyond a range); solving again with joint rows there\n",
                   check.violations.size(), check.velocity_ratio, check.torque_ratio,
                   check.range_excess_rad);
    const std::size_t before = points.size();
    points.insert(points.end(), check.violations.begin(), check.violations.end());
    auto refined = std::make_unique<SrbdProblem>(robot, plan_terrain, setup.timeline,
                                                 (*problem)->options(), setup.start_ptr());
    if (warm.previous) refined->warm_start_from(*warm.previous, warm.shift);
    add_joint_range_points(*refined, points);
    add_joint_velocity_points(*refined, points);
    add_polytope_points(*refined, points);
    // The rows at a measured start's instants are widened (joints.cpp): there they may hold
    // already, and a re-solve would return the same solution.
    if (refined->max_violation(result->x) <= options.tolerance) {
      ended = "rows_hold";
      break;
    }
    refined->initial_guess() = result->x;
    if (options.max_time > 0.0) solver_options.max_time = std::max(time_left(), 1e-3);
    const SolveResult again = solve(*refined, solver_options, warm_ipopt_options(true));
    rounds.push_back({{"points", points.size() - before},
                      {"status", again.status},
                      {"iterations", again.iterations}});
    if (!again.success) {
      add_solve_effort(again, result);
      ended = "failed";
      points.resize(before);
      break;
    }
    const SolveResult previous = *result;
    *result = again;
    add_solve_effort(previous, result);
    *problem = std::move(refined);
    check = check_solution();
  }
  record["rounds"] = rounds;
  record["points"] = points.size();
  record["after"] = joint_check_json(check, robot);
  record["held"] = check.violations.empty();
  if (!ended.empty()) record["ended"] = ended;
  return record;
}

// plan.json's solver and request figures (solver, objective and its phases, the request's
// options, the line followed, the fallbacks and the measured start's own violations).
void record_solve(const SrbdProblem& problem, const SolveResult& solve,
                  const PlannerOptions& options, const PlannerOptions& problem_options,
                  const nlohmann::json& shape_fallback, const nlohmann::json& rest_lead_in,
                  Trajectory* traj) {
  auto& st = traj->solver;
  st.status = solve.status;
  st.iterations = solve.iterations;
  st.wall_s = solve.wall_s;
  st.n_variables = problem.num_free_variables();
  st.n_constraints = problem.num_constraints();
  auto& extra = traj->extra;
  extra["solver_max_violation"] = solve.max_violation;
  extra["solver_termination"] = solve.termination;
  if (problem.has_objective()) {
    extra["objective"] = problem.eval_objective(solve.x.data());
    // The two phases of the solve (SolverOptions::objective_max_iterations).
    extra["solver_phases"] = {{"feasibility_iterations", solve.feasibility_iterations},
                              {"objective_iterations", solve.objective_iterations},
                              {"polish_iterations", solve.polish_iterations},
                              {"objective_at_feasible_point", solve.objective_start}};
  }
  extra["cycles"] = options.cycles;
  extra["optimize_timing"] = options.optimize_timing;
  extra["constraints"] = options.constraints;
  // A re-plan records the line it followed, so that a re-plan of it follows the same one.
  if (problem_options.has_path_line) extra["path_line"] = path_line_json(problem_options);
  if (!options.feasibility_settings.empty()) {
    nlohmann::json fs = nlohmann::json::object();
    for (const auto& [k, v] : options.feasibility_settings) fs[k] = v;
    extra["feasibility_settings"] = fs;
  }
  if (!shape_fallback.is_null()) extra["path_shape_fallback"] = shape_fallback;
  if (!rest_lead_in.is_null()) extra["rest_lead_in"] = rest_lead_in;
  // A measured start's own violations (rows on it alone, left out of the solve).
  if (!problem.start_excess().empty()) extra["start_excess"] = problem.start_excess();
}

// A failed solve's message (status, iterations, the shaped attempt, the largest violation and
// which constraints stay violated, on which feet and when: what a user can change — the goal,
// the duration, the gait, a constraint set — depends on it); plan.json keeps what is the plan's
// (no wall-clock figure): the status and what is violated.
void record_failure(const SrbdProblem& problem, const PlannerOptions& options,
                    const nlohmann::json& shape_fallback, PlanOutcome* out) {
  std::ostringstream m;
  m << "the optimiser ended with status '" << out->solve.status << "' after "
    << out->solve.iterations << " iterations (" << out->solve.wall_s << " s)";
  if (!shape_fallback.is_null())
    m << ", solved again without the path-shape rows after "
      << shape_fallback["shaped_iterations"].get<int>() << " with them ended '"
      << shape_fallback["shaped_status"].get<std::string>() << "'";
  m << "; largest constraint violation " << out->solve.max_violation;
  if (out->solve.status == "stalled")
    m << ", no 1 % reduction of it in the last " << options.stall_iterations << " iterations";
  const std::vector<FamilyViolation> left =
      violated_families(problem, out->solve.x, options.tolerance);
  const std::string violated = left.empty() ? "" : "still violated: " + describe_violations(left);
  if (!left.empty()) m << "; " << violated;
  out->message = m.str();
  out->trajectory.extra["failure"] =
      "status '" + out->solve.status + "'" + (violated.empty() ? "" : "; " + violated);
}

}  // namespace

std::string joint_refinement_stop_clause(const nlohmann::json& refinement) {
  if (!refinement.is_object() || !refinement.contains("ended")) return "";
  const std::string ended = refinement["ended"].get<std::string>();
  const nlohmann::json rounds = refinement.value("rounds", nlohmann::json::array());
  const nlohmann::json after = refinement.value("after", nlohmann::json::object());
  auto figure = [](const char* fmt, double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, fmt, v);
    return std::string(buf);
  };
  const std::string n = std::to_string(rounds.size()) + (rounds.size() == 1 ? " round" : " rounds");
  std::string why = "stopped after " + n;
  if (ended == "time") why = "ran out of time after " + n;
  if (ended == "rows_hold")
    why += ": the rows at the worst instants hold already (the force polytope only approximates "
           "the torque limits; joint rows near a measured start are widened)";
  if (ended == "failed" && !rounds.empty())
    why += ": its re-solve ended " + rounds.back().value("status", std::string("?")) +
           ", the previous solution kept";
  std::string left;
  auto add = [&](const std::string& part) { left += (left.empty() ? "" : ", ") + part; };
  if (after.value("velocity_ratio", 0.0) > 1.0)
    add("velocity " + figure("%.3g", after["velocity_ratio"].get<double>()) + "x its limit");
  if (after.value("torque_ratio", 0.0) > 1.0)
    add("torque " + figure("%.3g", after["torque_ratio"].get<double>()) + "x its limit");
  if (after.value("range_excess_rad", 0.0) > 0.0)
    add(figure("%.3g", after["range_excess_rad"].get<double>()) + " rad beyond a range");
  return "refinement of the joint rows " + why +
         (left.empty() ? std::string()
                       : " with joints still past their limits between the constraint points (" +
                             left + ")");
}

void check_before_solve(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                        const PlannerOptions& options) {
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  const PlanSetup setup = fresh_setup(robot, feet, options);
  // The problem's construction refuses a trunk that cannot pass under an overhang (trunk.cpp).
  const SrbdProblem problem(robot, plan_terrain, setup.timeline, options, setup.start_ptr());
  require_reachable(problem);
}

PlanOutcome plan_motion(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                        const terrain::HeightField& check_terrain, const PlannerOptions& options,
                        double sample_dt, const WarmStart& warm) {
  check_plan_request(options, sample_dt);
  const auto t_start = std::chrono::steady_clock::now();
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  const PlanSetup setup =
      warm.previous ? replan_setup(robot, feet, warm) : fresh_setup(robot, feet, options);
  // A re-plan follows the line of the plan it continues (ProblemOptions::path_line).
  PlannerOptions problem_options = options;
  if (warm.previous && !problem_options.has_path_line)
    set_path_line_of(*warm.previous, &problem_options);
  // A measured start ahead of the plan may return to it (monotone_progress).
  if (warm.previous && warm.start)
    set_start_lead_of(*warm.previous, warm.shift, setup.start, &problem_options);
  auto problem = std::make_unique<SrbdProblem>(robot, plan_terrain, setup.timeline, problem_options,
                                               setup.start_ptr());
  // An unreachable goal stance otherwise costs seconds of iterations before "infeasible".
  const auto t_reach = std::chrono::steady_clock::now();
  require_reachable(*problem);
  const double reachability_s = seconds_since(t_reach);
  if (warm.previous) problem->warm_start_from(*warm.previous, warm.shift);
  const double build_s = seconds_since(t_start);
  PlanOutcome out;
  const nlohmann::json shape_fallback = solve_with_shape_fallback(
      &problem, robot, plan_terrain, setup, problem_options, options, warm, t_start, &out.solve);
  const auto t_refine = std::chrono::steady_clock::now();
  const nlohmann::json joint_refinement =
      refine_joint_points(&problem, robot, plan_terrain, setup, options, warm, t_start, &out.solve);
  const double refinement_s = seconds_since(t_refine);
  const auto t_after_solve = std::chrono::steady_clock::now();
  out.success = out.solve.success;
  if (std::getenv("TERRASTRIDE_DEBUG_CHECKS"))
    for (const auto& [k, v] : problem->violation_by_kind(out.solve.x))
      std::fprintf(stderr, "final violation %s %g\n", k.c_str(), v);
  out.trajectory = sample_solution(*problem, out.solve.x, sample_dt);
  record_solve(*problem, out.solve, options, problem_options, shape_fallback, setup.rest_lead_in,
               &out.trajectory);
  if (!joint_refinement.is_null()) out.trajectory.extra["joint_refinement"] = joint_refinement;
  DenseCheckLimits lim;
  lim.friction = options.friction;
  lim.max_normal_force = options.max_normal_force_factor * robot.mass * kGravity;
  const Trajectory dense = sample_solution(*problem, out.solve.x, kDenseDt);
  out.trajectory.checks = dense_checks(robot, check_terrain, dense, lim);
  out.trajectory.extra["checks_dt"] = kDenseDt;
  out.trajectory.extra["quality"] =
      quality_to_json(plan_quality(out.trajectory), out.trajectory.feet);
  // Where the planner's time went (the solve is solver.wall_s): problem construction (with the
  // reachability check), and the sampling plus dense checks after it.
  out.trajectory.extra["timings"] = {{"build_s", build_s},
                                     {"reachability_check_s", reachability_s},
                                     {"solve_s", out.solve.wall_s},
                                     {"joint_refinement_s", refinement_s},
                                     {"sample_and_checks_s", seconds_since(t_after_solve)},
                                     {"total_s", seconds_since(t_start)}};
  if (!out.success) record_failure(*problem, options, shape_fallback, &out);
  return out;
}

int default_cycles(const robot::RobotModel& robot, const Eigen::Vector3d& start,
                   const Eigen::Vector3d& goal) {
  const int gait_default = ProblemOptions{}.cycles;
  double stride = std::numeric_limits<double>::infinity();
  for (const auto& leg : robot.legs) stride = std::min(stride, 2.0 * leg.range_of_motion.x());
  const double distance = (goal.head<2>() - start.head<2>()).norm();
  if (!(stride > 0.0) || !std::isfinite(distance)) return gait_default;
  // 1e-9: a goal exactly a whole number of strides away (HyQ's 1.5 m, 3 x 0.5 m) takes that many.
  const double needed = std::ceil(distance / stride - 1e-9);
  return static_cast<int>(std::clamp<double>(needed, gait_default, PlanLimits::kMaxCycles));
}

void check_plan_horizon(double duration, const std::string& field) {
  if (!(duration > 0.0) || duration > PlanLimits::kMaxDuration) {
    std::ostringstream m;
    m << "the plan would last " << duration << " s; plans last at most " << PlanLimits::kMaxDuration
      << " s (plan a long route in parts, re-planning from the previous plan)";
    throw RequestError(field, m.str());
  }
}

void check_plan_request(const PlannerOptions& options, double sample_dt) {
  auto fail = [](const std::string& field, double got, const std::string& rule) {
    std::ostringstream m;
    m << rule << ", got " << got;
    throw RequestError(field, m.str());
  };
  // Written so that NaN fails every test.
  if (!(options.duration >= 0.0)) fail("duration", options.duration, "must be > 0 s");
  if (options.duration > 0.0) check_plan_horizon(options.duration, "duration");
  if (!(options.cycles >= PlanLimits::kMinCycles && options.cycles <= PlanLimits::kMaxCycles))
    fail("cycles", options.cycles, "must be an integer within [1, 50]");
  if (!(sample_dt >= PlanLimits::kMinSampleDt && sample_dt <= PlanLimits::kMaxSampleDt))
    fail("sample_dt", sample_dt, "must be within [0.001, 1] s");
  if (!(options.max_time >= 0.0) || std::isinf(options.max_time))
    fail("max_time", options.max_time, "must be a finite number of seconds >= 0 (0 = no limit)");
  if (!options.goal.allFinite()) throw RequestError("goal", "must be three finite numbers");
  if (!options.start.allFinite()) throw RequestError("start", "must be three finite numbers");
  const double reach = (options.goal.head<2>() - options.start.head<2>()).norm();
  if (options.has_goal && reach > PlanLimits::kMaxGoalDistance)
    fail("goal", reach, "must lie within 1000 m of the start (distance from the start in m shown)");
}

}  // namespace terrastride::planner
