// A planning session: re-plans of one motion from a robot's measured states, one after another
// (model-predictive re-planning). The session keeps what a re-plan can reuse from the previous one:
// the reference plan it follows (contact schedule, goal), the terrain, and the previous step's
// solution as the initial guess (time-shifted to the new start, the reference beyond its end).
//
// With a horizon H > 0 a step plans only from its start t to the first contact switch at or after
// t + H at which no foot is in mid-swing, and the base there is held at the reference plan's state
// (pose, velocity and rates) and the feet at its foot positions: the reference is feasible, so the
// horizon problem has a solution whenever the robot can return to it within H, and the next step,
// whose guess continues this plan with the reference beyond its end, starts from a guess that is
// consistent across that splice (a stance spanning it has one foothold variable). Once t + H reaches the reference's end the step
// plans to the goal as the reference did. Ipopt 3.11 keeps nothing between two problems of
// different structure (and a step's structure changes whenever its start crosses a segment
// knot), so the cost of a step is that of its problem: a horizon of 2 s instead of the 11 s of
// pallet_15 makes each step's problem about five times smaller (docs/design.md §6.7).
// After a measured disturbance (Disturbance) the steps of a recovery window plan over
// recovery_horizon() instead, and a schedule a step adapted (a touch-down, a capture step) is the
// next steps' schedule up to that plan's end (schedule_from).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {

// A step after a push (planning_session.cpp, plan_capture_step): the measured capture point
// (x + v / omega, omega = sqrt(g / h), h the base's height above the standing feet) lay `outside`
// m out of the support polygon of the feet standing at the step's start (and that much further
// out than the planned state's), so foot `foot` touches down `touchdown` s after the step's start
// (its swing under way moved earlier from `scheduled_touchdown`, or, every foot standing, a swing
// added: `added_swing`), its foothold guess moved by `shift` (towards the capture point, at most
// 0.15 m, less where that is unsafe terrain) to `foothold` (`placed`), the horizon end's feet free.
struct CaptureStep {
  int foot = -1;
  double touchdown = 0.0, scheduled_touchdown = 0.0;
  bool added_swing = false;
  Eigen::Vector2d point = Eigen::Vector2d::Zero(), shift = Eigen::Vector2d::Zero();
  double outside = 0.0;
  bool placed = false;
  Eigen::Vector3d foothold = Eigen::Vector3d::Zero();
};

// How far a step's measured state is from the session's plan there (planning_session.cpp,
// measure_disturbance): the capture points' distance (x + v / omega, m) and the largest
// roll/pitch error (rad). A step whose measured state is this far off, that lifts a foot or makes
// a capture step opens a recovery window: its steps plan over the recovery horizon.
struct Disturbance {
  double capture_point_offset = 0.0;
  double tilt_offset = 0.0;
  bool detected = false;  // this step's state (or its schedule adaptation) is a disturbance
  bool recovering = false;  // the step plans over the recovery horizon
};

struct SessionStep {
  PlanOutcome outcome;   // the plan from t (its samples start at 0 = the session's time t)
  double start_time = 0.0;  // t on the session's (the reference plan's) time axis
  double end_time = 0.0;    // where this plan ends on that axis
  bool to_goal = false;     // the plan ends at the goal (not at a horizon)
  double build_s = 0.0;     // problem construction and warm start
  // The solve with the end's feet held at the reference's failed, and the step was solved again
  // with them free (outcome.solve's iterations and wall time cover both solves).
  bool feet_freed = false;
  std::string pinned_feet_status;
  int pinned_feet_iterations = 0;
  // The step's own solve was not used (StepLimits::budget): outcome.trajectory is then the
  // session's current plan from t (its samples from 0 = t, up to where the solve would have
  // ended), outcome.success is true (it is a plan the robot can follow), and fallback_reason says
  // why: "deadline" (the solve had not finished by it) or "solve_failed" (outcome.message).
  bool fallback = false;
  std::string fallback_reason;
  // The session's current plan (this step's warm start, and its fallback) came from a solve that
  // finished after its own step had answered with a fallback: verified, and from a later
  // measured state than the plan that step fell back to.
  bool warm_from_late_solve = false;
  double wall_s = 0.0;  // the step call, start to return
  // A budgeted step: how long after its answer was due (start + budget - reserve, less the
  // session's measured lateness) it returned; <= 0 when it returned in time (its solve finished
  // first). What the scheduler adds to a deadline on a loaded machine.
  double answer_late_s = 0.0;
  // Feet measured in the air (3 cm above the terrain) where the schedule had a stance: this plan
  // swings them and touches them down 0.2 s after t (the rest of their stance as scheduled).
  std::vector<std::string> touchdowns;
  // A step the push called for (capture.foot >= 0), reported as session.capture_step.
  CaptureStep capture;
  // The measured offset from the session's plan, and whether the step plans over the recovery
  // horizon (reported as session.disturbance).
  Disturbance disturbance;
};

// What bounds one step. should_stop is polled once per solver iteration (the service's
// cancellation) and max_time caps the solve (0: the session options' max_time); neither bounds
// the step's wall time, since one iteration (a factorisation, a restoration phase) can itself be
// long. A budget does: the solve then runs on the session's worker thread and the step returns
// by start + budget - reserve (less the session's own measured lateness) whatever the solve does, with the solve's plan if it finished and
// succeeded, else the fallback (SessionStep::fallback). reserve is what the caller needs after
// the step (e.g. encoding its reply). budget 0: the step waits for its solve.
// iterations > 0 (with budget 0) is the same deadline counted in solver iterations instead of
// wall-clock time, so that a step's answer does not depend on the machine's load (a simulation's
// closed loop): the step waits for its solve (up to 4 x iterations), answers with its plan if it
// converged within `iterations`, else with the fallback (fallback_reason "iterations"), and a
// solve that converged later becomes the session's plan when the next step begins, as a late
// wall-clock solve does.
struct StepLimits {
  std::function<bool()> should_stop;
  double max_time = 0.0;
  double budget = 0.0;
  double reserve = 0.0;
  int iterations = 0;
};

struct StepJob;
class StepWorker;

class PlanningSession {
 public:
  // `reference` is a plan from plan_motion (with its "timeline"), starting at session time 0.
  // The terrains must outlive the session. horizon <= 0: every step plans to the goal.
  PlanningSession(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                  const terrain::HeightField& check_terrain, const PlannerOptions& options,
                  Trajectory reference, double horizon, double sample_dt);
  ~PlanningSession();
  PlanningSession(const PlanningSession&) = delete;
  PlanningSession& operator=(const PlanningSession&) = delete;

  // A plan from `measured` at session time t. Throws RequestError("time" or "start_state") for a
  // time outside the reference or a state with the wrong feet. Without a budget, a step whose
  // solve fails returns an outcome with success false (and its message); with one it returns the
  // fallback. Either way the session keeps its last good plan, which the next step warm-starts
  // from; a solve that finished with a plan after its step had answered becomes that plan when
  // the next step begins, if it is newer.
  SessionStep step(const SrbdProblem::StartState& measured, double t,
                   const StepLimits& limits = {});

  const Trajectory& reference() const { return reference_; }
  // The last successful plan (its samples from 0 = previous_start_time()); the reference before
  // the first step.
  const Trajectory& previous() const { return previous_; }
  double previous_start_time() const { return previous_start_; }
  double horizon() const { return horizon_; }
  // The horizon of the steps in a recovery window (after a measured disturbance, until the state
  // has stayed near the plan for a while): the longer of 2 s and horizon().
  double recovery_horizon() const;
  int steps() const { return steps_; }
  // Bytes the session holds (reference and previous plans, their samples): for the service's
  // per-session bound.
  std::size_t memory_bytes() const;

  // The state of the last successful plan at session time t (the reference before the first
  // step; beyond the previous plan's end, the reference).
  SrbdProblem::StartState planned_state(double t) const;

  // The session's current plan from session time t up to `end` (> t), resampled at sample_dt:
  // the last successful plan, then the reference beyond its end (a budgeted step's fallback).
  Trajectory current_plan_from(double t, double end) const;

 private:
  // step() but for its disturbance report.
  SessionStep answer_step(const SrbdProblem::StartState& measured, double t,
                          const StepLimits& limits);
  // The schedule a step from t follows (from 0 = t, to the reference's end): the last plan's
  // where it adapted the reference's (a capture step, a touch-down), up to that plan's end, so
  // that the next steps keep the adaptation; else the reference's.
  PhaseTimeline schedule_from(double t) const;
  std::shared_ptr<StepJob> prepare(const SrbdProblem::StartState& measured, double t,
                                   const StepLimits& limits);
  SessionStep fallback_step(const StepJob& job, const std::string& reason,
                            const std::string& message) const;
  // The fallback of a step whose own solve ran but was not used (failed, or over its budget).
  SessionStep fallback_after_solve(const StepJob& job, const std::string& reason,
                                   const std::string& message) const;
  SessionStep step_with_iteration_budget(const std::shared_ptr<StepJob>& job, int iterations);
  void adopt_late_solve();

  const robot::RobotModel& robot_;
  const terrain::HeightField& plan_terrain_;
  const terrain::HeightField& check_terrain_;
  PlannerOptions options_;
  Trajectory reference_;
  PhaseTimeline reference_timeline_;
  double horizon_;
  double sample_dt_;
  Trajectory previous_;
  double previous_start_ = 0.0;
  // previous_ came from a solve that finished after its step had answered with a fallback (it
  // is still a verified plan, and from a later measured state than the one it replaced).
  bool adopted_late_ = false;
  // How late budgeted steps returned after their answer was due (a decaying maximum, s).
  double late_s_ = 0.0;
  int steps_ = 0;
  // Steps before this session time (set by the last disturbance detected) plan over
  // recovery_horizon().
  double recovery_until_ = -1.0;
  Disturbance last_disturbance_;  // the last prepared step's
  std::unique_ptr<StepWorker> worker_;  // made by the first budgeted step
  // A solve over its iteration budget that still converged (StepLimits::iterations): adopted as
  // a late solve when the next step begins.
  std::shared_ptr<StepJob> late_by_iterations_;
};

// The part of `timeline` up to `end` (an event time of it): the horizon of a session step.
PhaseTimeline truncated_timeline(const PhaseTimeline& timeline, double end);

}  // namespace terrastride::planner
