// Planning sessions: successive re-plans of one motion from measured states (planning_session.hpp).
#include "terrastride/planner/planning_session.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <sstream>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/planner/violation_report.hpp"

namespace terrastride::planner {

namespace {

constexpr double kDenseDt = 0.002;  // as plan_motion: dense checks every 2 ms
constexpr double kEventTol = 1e-6;

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// The previous plan on the session's time axis, continued by the reference after its end: the
// initial guess of the next step, which may reach beyond where the previous step ended.
Trajectory spliced_guess(const Trajectory& previous, double previous_start,
                         const Trajectory& reference) {
  Trajectory g;
  g.feet = reference.feet;
  g.sample_dt = reference.sample_dt;
  const double prev_end = previous_start + previous.duration;
  for (const auto& s : previous.samples) {
    TrajectorySample c = s;
    c.t += previous_start;
    g.samples.push_back(std::move(c));
  }
  for (const auto& s : reference.samples)
    if (s.t > prev_end + kEventTol) g.samples.push_back(s);
  g.duration = std::max(prev_end, reference.duration);
  return g;
}

}  // namespace

PhaseTimeline truncated_timeline(const PhaseTimeline& timeline, double end) {
  PhaseTimeline out = timeline;
  out.events.clear();
  for (auto& c : out.contact) c.clear();
  out.events.push_back(timeline.events.front());
  for (int j = 0; j < timeline.num_intervals(); ++j) {
    if (timeline.events[j] >= end - kEventTol) break;
    out.events.push_back(std::min(timeline.events[j + 1], end));
    for (std::size_t f = 0; f < out.feet.size(); ++f) out.contact[f].push_back(timeline.contact[f][j]);
  }
  return out;
}

PlanningSession::PlanningSession(const robot::RobotModel& robot,
                                 const terrain::HeightField& plan_terrain,
                                 const terrain::HeightField& check_terrain,
                                 const PlannerOptions& options, Trajectory reference,
                                 double horizon, double sample_dt)
    : robot_(robot),
      plan_terrain_(plan_terrain),
      check_terrain_(check_terrain),
      options_(options),
      reference_(std::move(reference)),
      horizon_(horizon),
      sample_dt_(sample_dt) {
  if (!(horizon_ >= 0.0) || !std::isfinite(horizon_))
    throw RequestError("horizon", "must be a finite number of seconds >= 0 (0 = to the goal)");
  if (reference_.samples.empty()) throw RequestError("reference", "the plan has no samples");
  reference_timeline_ = timeline_of(reference_);
  if (options_.optimize_timing)
    throw RequestError("optimize_timing",
                       "a session follows its reference plan's contact schedule; plan the "
                       "reference with optimised timing and open the session without it");
  // A step is one of many a second: one that has not converged in 60 iterations (plausible steps
  // take 0-11 on pallet_15 `all`) or stops improving for 20 is reported as failed rather than
  // left to run for seconds (an unreachable start stalled after 339 iterations, 12 s).
  options_.max_iterations = std::min(options_.max_iterations, 60);
  options_.stall_iterations = 20;
  options_.has_goal = true;
  options_.goal = goal_of(reference_);
  // Every step's base path is shaped along the reference's line (monotone_progress,
  // lateral_corridor), not along one drawn from its measured start.
  set_path_line_of(reference_, &options_);
  previous_ = reference_;
  previous_start_ = 0.0;
}

SrbdProblem::StartState PlanningSession::planned_state(double t) const {
  if (t >= previous_start_ && t <= previous_start_ + previous_.duration)
    return start_state_of(previous_, t - previous_start_);
  return start_state_of(reference_, std::clamp(t, 0.0, reference_.duration));
}

std::size_t PlanningSession::memory_bytes() const {
  auto plan_bytes = [](const Trajectory& p) {
    const std::size_t per_sample = sizeof(TrajectorySample) + p.feet.size() * sizeof(FootState);
    return sizeof(Trajectory) + p.samples.capacity() * per_sample + p.extra.dump().size();
  };
  return sizeof(*this) + plan_bytes(reference_) + plan_bytes(previous_);
}

SessionStep PlanningSession::step(const SrbdProblem::StartState& measured, double t,
                                  const StepLimits& limits) {
  const auto t0 = std::chrono::steady_clock::now();
  const double T = reference_.duration;
  // The last 0.1 s of the plan are its final rest: nothing left to re-plan.
  if (!(t >= 0.0) || !(t < T - 0.1))
    throw RequestError("time", "must be within [0, " + std::to_string(T - 0.1) +
                                   ") s of the session's plan (which lasts " + std::to_string(T) +
                                   " s), got " + std::to_string(t));
  if (measured.foot_position.size() != robot_.legs.size() ||
      measured.foot_velocity.size() != robot_.legs.size())
    throw RequestError("start_state", "has " + std::to_string(measured.foot_position.size()) +
                                          " feet, robot " + robot_.name + " has " +
                                          std::to_string(robot_.legs.size()));
  for (const auto* v : {&measured.position, &measured.euler_zyx, &measured.linear_velocity,
                        &measured.euler_rates})
    if (!v->allFinite()) throw RequestError("start_state", "must hold finite numbers");

  // Where this step ends: the first contact switch at or after t + H with no foot in mid-swing
  // across it (a swing cut at the horizon would lose its touch-down), else the goal.
  const auto& ev = reference_timeline_.events;
  double end = T;
  if (horizon_ > 0.0)
    for (int j = 1; j < reference_timeline_.num_intervals(); ++j) {
      if (ev[j] < t + horizon_ - kEventTol) continue;
      bool swing_across = false;
      for (const auto& c : reference_timeline_.contact) swing_across |= !c[j - 1] && !c[j];
      if (!swing_across) {
        end = ev[j];
        break;
      }
    }
  const bool to_goal = end >= T - kEventTol;
  PhaseTimeline timeline = reference_timeline_.cropped(t);
  if (!to_goal) timeline = truncated_timeline(timeline, end - t);

  // A horizon's end is pinned to the reference as the problem is built, so that the rows of
  // every constraint set see it as fixed (built after, the path-shape rows on it were constants).
  // The feet and their forces are held there too (the reference's), so that the next step's
  // guess, this plan and then the reference, agrees with itself across the splice (a stance
  // spanning it has one foothold variable, a knot one force: free, they cost the horizon-end
  // moves 7-11 iterations instead of 3, docs/design.md §6.7). A step that fails so is solved again
  // with the end's feet and forces free: after a push the recovery may need others.
  SrbdProblem::StartState pinned_end = start_state_of(reference_, end);
  // Its forces there: those just before the end (the end is a contact switch; a foot touching
  // down at it has no force variable at the end knot).
  for (const auto& f : interpolate_plan(reference_, end - kEventTol).feet)
    pinned_end.foot_force.push_back(f.contact ? f.force : Eigen::Vector3d::Zero());
  // A measured state ahead of the reference may return to it (monotone_progress).
  ProblemOptions step_problem_options = options_;
  set_start_lead_of(reference_, t, measured, &step_problem_options);
  SrbdProblem::StartState base_end = pinned_end;
  base_end.foot_position.clear();
  base_end.foot_velocity.clear();
  base_end.foot_force.clear();
  const Trajectory guess = spliced_guess(previous_, previous_start_, reference_);
  auto build = [&](const SrbdProblem::StartState* end_state) {
    auto p = std::make_unique<SrbdProblem>(robot_, plan_terrain_, timeline, step_problem_options,
                                           &measured, end_state);
    p->warm_start_from(guess, t);
    return p;
  };
  std::unique_ptr<SrbdProblem> problem = build(to_goal ? nullptr : &pinned_end);
  SessionStep out;
  out.start_time = t;
  out.end_time = end;
  out.to_goal = to_goal;
  out.build_s = seconds_since(t0);
  // As plan_motion's re-plans: a small barrier and bound push keep the warm start.
  PlanOutcome& o = out.outcome;
  SolverOptions solver_options = options_;
  if (limits.should_stop) solver_options.should_stop = limits.should_stop;
  if (limits.max_time > 0.0) solver_options.max_time = limits.max_time;
  std::vector<std::pair<std::string, std::string>> step_options = {
      {"mu_init", "1e-4"}, {"bound_push", "1e-5"}, {"bound_frac", "1e-5"},
      // A step's constraint Jacobian is rank-deficient (Ipopt's first factorisation of every
      // iteration, without the constraints' regularisation delta_c, failed as singular in MUMPS
      // after its full set-up, until Ipopt had seen three such iterations): the regularisation
      // from the first, and no MUMPS scaling (the forces are already scaled to body weights,
      // SrbdTnlp::get_scaling_parameters), which MUMPS recomputed for every factorisation.
      {"perturb_always_cd", "yes"}, {"mumps_scaling", "0"}};
  // TERRASTRIDE_STEP_IPOPT_OPTIONS adds Ipopt options to session steps only (tuning runs;
  // TERRASTRIDE_IPOPT_OPTIONS would change the reference's cold solve too).
  for (auto& option : ipopt_options_from_env("TERRASTRIDE_STEP_IPOPT_OPTIONS"))
    step_options.push_back(std::move(option));
  o.solve = solve(*problem, solver_options, step_options);
  const bool stopped = o.solve.status == "time_limit" ||
                       (limits.should_stop && limits.should_stop());
  if (!o.solve.success && !to_goal && !stopped) {
    const SolveResult pinned = o.solve;
    out.feet_freed = true;
    out.pinned_feet_status = pinned.status;
    out.pinned_feet_iterations = pinned.iterations;
    problem = build(&base_end);
    if (limits.max_time > 0.0)
      solver_options.max_time = std::max(0.001, limits.max_time - seconds_since(t0));
    o.solve = solve(*problem, solver_options, step_options);
    // The step's solver figures cover both solves.
    o.solve.iterations += pinned.iterations;
    o.solve.wall_s += pinned.wall_s;
  }
  o.success = o.solve.success;
  const auto t_after_solve = std::chrono::steady_clock::now();
  o.trajectory = sample_solution(*problem, o.solve.x, sample_dt_);
  auto& st = o.trajectory.solver;
  st.status = o.solve.status;
  st.iterations = o.solve.iterations;
  st.wall_s = o.solve.wall_s;
  st.n_variables = problem->num_free_variables();
  st.n_constraints = problem->num_constraints();
  auto& ex = o.trajectory.extra;
  ex["solver_max_violation"] = o.solve.max_violation;
  ex["solver_termination"] = o.solve.termination;
  ex["constraints"] = options_.constraints;
  ex["path_line"] = path_line_json(options_);
  ex["start_time"] = t;
  ex["session"] = {{"step", steps_ + 1}, {"end_time", end}, {"to_goal", to_goal},
                   {"horizon", horizon_}};
  // The measured start's own violations (rows on it alone, left out of the solve).
  if (!problem->start_excess().empty()) ex["start_excess"] = problem->start_excess();
  if (!problem->end_excess().empty()) ex["session"]["end_excess"] = problem->end_excess();
  if (out.feet_freed)
    ex["session"]["end_feet_freed"] = {{"pinned_status", out.pinned_feet_status},
                                       {"pinned_iterations", out.pinned_feet_iterations}};
  DenseCheckLimits lim;
  lim.friction = options_.friction;
  lim.max_normal_force = options_.max_normal_force_factor * robot_.mass * kGravity;
  o.trajectory.checks =
      dense_checks(robot_, check_terrain_, sample_solution(*problem, o.solve.x, kDenseDt), lim);
  ex["checks_dt"] = kDenseDt;
  ex["timings"] = {{"build_s", out.build_s},
                   {"solve_s", o.solve.wall_s},
                   {"sample_and_checks_s", seconds_since(t_after_solve)},
                   {"total_s", seconds_since(t0)}};
  ++steps_;
  if (!o.success) {
    std::ostringstream m;
    m << "the re-plan from t = " << t << " s ended with status '" << o.solve.status << "' after "
      << o.solve.iterations << " iterations; largest constraint violation "
      << o.solve.max_violation;
    const auto left = violated_families(*problem, o.solve.x, options_.tolerance);
    if (!left.empty()) m << "; still violated: " << describe_violations(left);
    for (const auto& [kind, excess] : problem->start_excess())
      m << "; the measured start exceeds " << kind << " by " << excess;
    for (const auto& [kind, excess] : problem->end_excess())
      m << "; the pinned end exceeds " << kind << " by " << excess;
    m << " (the session keeps its previous plan)";
    o.message = m.str();
    ex["failure"] = o.message;
    return out;
  }
  previous_ = o.trajectory;
  previous_start_ = t;
  return out;
}

}  // namespace terrastride::planner
