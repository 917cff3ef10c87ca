// Planning-session steps under a wall-clock budget (planning_session.hpp, StepLimits::budget):
// the step answers by its budget with its own plan or the session's current plan (the fallback),
// whatever the solve does, and a solve that finishes late warm-starts the next step.
#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>

#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/planning_session.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// The flat 2.4 s crawl to x = 0.3 (a cold solve of some 0.1 s) as a session with a 1 s horizon.
struct FlatSession : ::testing::Test {
  void SetUp() override {
    PlannerOptions o;
    o.has_goal = true;
    o.goal = Eigen::Vector3d(0.3, 0.0, 0.0);
    o.duration = 2.4;
    options = o;
    cold = plan_motion(robot, flat, flat, o, 0.02);
    ASSERT_TRUE(cold.success) << cold.message;
    session = std::make_unique<PlanningSession>(robot, flat, flat, o, cold.trajectory, 1.0, 0.02);
  }
  // The session's plan at t, 1 cm to the left: a measured state the solve has to move.
  SrbdProblem::StartState measured(double t) const {
    SrbdProblem::StartState s = session->planned_state(t);
    s.position.y() += 0.01;
    return s;
  }
  // The session's plan at t with the base moving `vy` m/s faster to the left: a push.
  SrbdProblem::StartState pushed_left(double t, double vy) const {
    SrbdProblem::StartState s = session->planned_state(t);
    s.linear_velocity.y() += vy;
    return s;
  }
  robot::RobotModel robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  testing::FlatField flat;
  PlannerOptions options;
  PlanOutcome cold;
  std::unique_ptr<PlanningSession> session;
};

// Slack for a loaded machine and ASan; the solve below sleeps 0.4 s per iteration, so a step
// that waited for it would take at least that.
constexpr double kSlack = 0.2;

// Each solver iteration of the step takes 0.4 s (a test hook in the solver's per-iteration
// callback, as one long factorisation or restoration phase would): the step still answers within
// its 50 ms budget, with the session's current plan from t marked as the fallback; so does the
// next step, although the stale solve is still in its iteration (it is cancelled, not waited
// for); and a step without a budget afterwards solves as usual.
TEST_F(FlatSession, ASlowSolveStillAnswersWithinItsBudgetWithTheFallback) {
  StepLimits slow;
  slow.budget = 0.05;
  slow.should_stop = [] {
    std::this_thread::sleep_for(std::chrono::milliseconds(400));
    return false;
  };
  const SrbdProblem::StartState planned = session->planned_state(0.2);
  auto t0 = Clock::now();
  const SessionStep a = session->step(measured(0.2), 0.2, slow);
  EXPECT_LT(seconds_since(t0), slow.budget + kSlack);
  EXPECT_TRUE(a.fallback);
  EXPECT_EQ(a.fallback_reason, "deadline");
  EXPECT_TRUE(a.outcome.success) << "a fallback is a plan to follow";
  EXPECT_EQ(a.outcome.trajectory.solver.status, "fallback");
  EXPECT_TRUE(a.outcome.trajectory.extra["session"]["fallback"].get<bool>());
  ASSERT_FALSE(a.outcome.trajectory.samples.empty());
  // The current plan from 0.2 s: it starts where that plan is, not at the measured state.
  EXPECT_NEAR((a.outcome.trajectory.samples.front().base.position - planned.position).norm(), 0.0,
              1e-9);
  EXPECT_NEAR(a.outcome.trajectory.samples.back().t, a.end_time - 0.2, 1e-9);
  EXPECT_TRUE(a.outcome.trajectory.extra.contains("timeline"));

  StepLimits budget;
  budget.budget = 0.05;
  t0 = Clock::now();
  const SessionStep b = session->step(measured(0.3), 0.3, budget);
  EXPECT_LT(seconds_since(t0), budget.budget + kSlack) << "the next step waited for a stale solve";
  EXPECT_TRUE(b.fallback);
  EXPECT_EQ(b.fallback_reason, "deadline");

  const SrbdProblem::StartState m = measured(0.4);
  const SessionStep c = session->step(m, 0.4);
  ASSERT_TRUE(c.outcome.success) << c.outcome.message;
  EXPECT_FALSE(c.fallback);
  EXPECT_NEAR(c.outcome.trajectory.samples.front().base.position.y(), m.position.y(), 1e-9);
}

// A solve that finishes after its step answered (here its first iteration is held up 0.15 s, past
// the 0.1 s budget, and the solve may run on to four budgets) becomes the session's plan when the
// next step begins: that step's warm start, and its fallback.
TEST_F(FlatSession, ASolveThatFinishesLateWarmStartsTheNextStep) {
  StepLimits held;
  held.budget = 0.1;
  auto first = std::make_shared<bool>(true);
  held.should_stop = [first] {
    if (*first) std::this_thread::sleep_for(std::chrono::milliseconds(150));
    *first = false;
    return false;
  };
  const SessionStep a = session->step(measured(0.2), 0.2, held);
  EXPECT_TRUE(a.fallback);
  EXPECT_EQ(session->previous_start_time(), 0.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(800));
  // The next step falls back too (its own solve is held up longer than its budget), but to the
  // late plan from 0.2 s, which is now the session's plan.
  StepLimits slow;
  slow.budget = 0.05;
  slow.should_stop = [] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    return false;
  };
  const SessionStep b = session->step(measured(0.3), 0.3, slow);
  EXPECT_TRUE(b.fallback);
  EXPECT_TRUE(b.warm_from_late_solve);
  EXPECT_DOUBLE_EQ(session->previous_start_time(), 0.2);
  const SessionStep c = session->step(measured(0.4), 0.4);
  ASSERT_TRUE(c.outcome.success) << c.outcome.message;
  EXPECT_FALSE(c.warm_from_late_solve);
}


// A budget in solver iterations (StepLimits::iterations, the simulation's deterministic deadline):
// a step whose solve needs more than its budget answers with the fallback ("iterations"), and the
// solve's plan, which converged after its budget, becomes the session's plan when the next step
// begins; a step within its budget answers with its own plan. The same steps in a second session
// decide the same and answer the same plans (no wall clock involved).
TEST_F(FlatSession, AnIterationBudgetFallsBackAndAdoptsTheSolveAtTheNextStep) {
  auto run = [&](PlanningSession& s) {
    std::vector<SessionStep> steps;
    StepLimits one;
    one.iterations = 1;
    SrbdProblem::StartState m = s.planned_state(0.2);
    m.position.y() += 0.02;
    steps.push_back(s.step(m, 0.2, one));
    EXPECT_TRUE(steps.back().fallback);
    EXPECT_EQ(steps.back().fallback_reason, "iterations");
    EXPECT_GT(steps.back().outcome.solve.iterations, 1);
    EXPECT_TRUE(steps.back().outcome.success) << "a fallback is a plan to follow";
    EXPECT_EQ(s.previous_start_time(), 0.0);
    StepLimits ample;
    ample.iterations = 60;
    steps.push_back(s.step(s.planned_state(0.3), 0.3, ample));
    EXPECT_TRUE(steps.back().warm_from_late_solve);
    EXPECT_FALSE(steps.back().fallback) << steps.back().outcome.message;
    EXPECT_DOUBLE_EQ(s.previous_start_time(), 0.3);
    return steps;
  };
  const std::vector<SessionStep> a = run(*session);
  PlanningSession again(robot, flat, flat, options, cold.trajectory, 1.0, 0.02);
  const std::vector<SessionStep> b = run(again);
  for (std::size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].outcome.solve.iterations, b[k].outcome.solve.iterations);
    ASSERT_EQ(a[k].outcome.trajectory.samples.size(), b[k].outcome.trajectory.samples.size());
    EXPECT_EQ(a[k].outcome.trajectory.samples.back().base.position,
              b[k].outcome.trajectory.samples.back().base.position);
  }
}


// A foot the measured state has 6 cm in the air where the schedule has it in stance (a push
// lifted it): the step swings it and touches it down 0.2 s later on the terrain, and the rest of
// its stance stays as scheduled; the plan holds the planner's constraints (it solved).
TEST_F(FlatSession, AFootMeasuredInTheAirWhereThePlanHasAStanceTouchesDown) {
  // A time at which some foot is in stance for at least the next 0.4 s.
  const PhaseTimeline tl = timeline_of(cold.trajectory);
  double t = -1.0;
  int foot = -1;
  for (double c = 0.2; c < 1.6 && foot < 0; c += 0.1)
    for (std::size_t f = 0; f < tl.feet.size() && foot < 0; ++f) {
      bool stance = true;
      for (double u = c; u <= c + 0.4; u += 0.01)
        stance = stance && interpolate_plan(cold.trajectory, u).feet[f].contact;
      if (stance) {
        t = c;
        foot = static_cast<int>(f);
      }
    }
  ASSERT_GE(foot, 0);
  SrbdProblem::StartState lifted = session->planned_state(t);
  const double ground = lifted.foot_position[foot].z();
  lifted.foot_position[foot].z() += 0.06;
  const SessionStep step = session->step(lifted, t);
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  EXPECT_EQ(step.touchdowns, std::vector<std::string>{tl.feet[foot]});
  const auto& samples = step.outcome.trajectory.samples;
  EXPECT_FALSE(samples.front().feet[foot].contact) << "the lifted foot swings";
  EXPECT_NEAR(samples.front().feet[foot].position.z(), ground + 0.06, 1e-6);
  bool down = false;
  for (const auto& smp : samples)
    if (smp.t >= 0.2 + 1e-9 && smp.t <= 0.3) {
      EXPECT_TRUE(smp.feet[foot].contact) << "at " << smp.t;
      EXPECT_NEAR(smp.feet[foot].position.z(), ground, 0.005) << "at " << smp.t;
      down = true;
    }
  EXPECT_TRUE(down);
  // A step that falls back 0.05 s later keeps that schedule (the last plan's, not the
  // reference's): the foot still swings at its start.
  StepLimits slow;
  slow.budget = 0.05;
  slow.should_stop = [] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    return false;
  };
  const SessionStep fb = session->step(session->planned_state(t + 0.05), t + 0.05, slow);
  ASSERT_TRUE(fb.fallback);
  const PhaseTimeline ftl = timeline_of(fb.outcome.trajectory);
  const auto phases = ftl.phases(foot);
  ASSERT_FALSE(phases.empty());
  EXPECT_FALSE(phases[0].contact);
  EXPECT_NEAR(phases[0].end, 0.15, 0.03 + 1e-6);  // an event within 0.03 s of 0.2 s is reused
}

// A push to the left (the measured base moving at 1.6 m/s sideways) carries the capture point out
// of the support polygon: the step makes a step (session.capture_step), a swing that touches down
// by 0.2 s after the step's start, its foothold moved to the left of the reference's.
TEST_F(FlatSession, APushThatMovesTheCapturePointOutOfSupportMakesAStepTowardsIt) {
  const double t = 0.6;
  const SessionStep step = session->step(pushed_left(t, 1.6), t);
  ASSERT_GE(step.capture.foot, 0) << "a capture step";
  const int f = step.capture.foot;
  EXPECT_GT(step.capture.outside, 0.02);
  EXPECT_GT(step.capture.shift.y(), 0.0) << "towards the push";
  EXPECT_LE(step.capture.touchdown, 0.2 + 0.03 + 1e-9);
  EXPECT_TRUE(step.capture.placed);
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  EXPECT_TRUE(step.outcome.trajectory.extra["session"].contains("capture_step"));
  // The step's foothold against the reference's for the same stance (the first after the
  // touch-down in both).
  const double td = step.capture.touchdown;
  const auto stepped = interpolate_plan(step.outcome.trajectory, td + 0.05).feet[f];
  ASSERT_TRUE(stepped.contact);
  double ref_td = t + td;
  while (!interpolate_plan(cold.trajectory, ref_td).feet[f].contact) ref_td += 0.01;
  const auto reference = interpolate_plan(cold.trajectory, ref_td + 0.05).feet[f];
  EXPECT_GT(stepped.position.y(), reference.position.y() + 0.01)
      << "the touch-down is towards the push";
  // Undisturbed, the same step makes none.
  PlanningSession quiet(robot, flat, flat, options, cold.trajectory, 1.0, 0.02);
  EXPECT_LT(quiet.step(quiet.planned_state(t), t).capture.foot, 0);
}

// A measured state whose capture point is well off the plan's (the base moving 0.6 m/s sideways)
// is a disturbance: that step and the steps of the next second plan over the recovery horizon
// (2 s instead of 1 s), reported as session.disturbance; afterwards, and in an undisturbed
// session, steps keep the session's horizon.
TEST_F(FlatSession, ADisturbedStepPlansOverTheRecoveryHorizonForAWhile) {
  const double t = 0.2;
  PlanningSession quiet(robot, flat, flat, options, cold.trajectory, 1.0, 0.02);
  for (double u : {0.2, 0.3, 0.8}) {
    const SessionStep q = quiet.step(quiet.planned_state(u), u);
    ASSERT_TRUE(q.outcome.success) << q.outcome.message;
    EXPECT_FALSE(q.disturbance.detected) << "at " << u;
    EXPECT_FALSE(q.disturbance.recovering) << "at " << u;
    EXPECT_FALSE(q.outcome.trajectory.extra["session"].contains("disturbance"));
    EXPECT_DOUBLE_EQ(q.outcome.trajectory.extra["session"]["horizon"].get<double>(), 1.0);
  }
  PlanningSession fresh(robot, flat, flat, options, cold.trajectory, 1.0, 0.02);
  const double quiet_end = fresh.step(fresh.planned_state(t), t).end_time;
  EXPECT_LT(quiet_end, t + 2.0 - 1e-6);

  EXPECT_DOUBLE_EQ(session->recovery_horizon(), 2.0);
  const SessionStep step = session->step(pushed_left(t, 0.6), t);
  EXPECT_TRUE(step.disturbance.detected);
  EXPECT_TRUE(step.disturbance.recovering);
  EXPECT_GT(step.disturbance.capture_point_offset, 0.1);
  EXPECT_TRUE(step.outcome.trajectory.extra["session"].contains("disturbance"));
  EXPECT_TRUE(step.to_goal || step.end_time >= t + 2.0 - 1e-6) << step.end_time;
  EXPECT_GT(step.end_time, quiet_end);
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  // On the recovery plan 0.1 s later: not disturbed, still in the window.
  const SessionStep next = session->step(session->planned_state(t + 0.1), t + 0.1);
  EXPECT_FALSE(next.disturbance.detected);
  EXPECT_TRUE(next.disturbance.recovering);
  EXPECT_TRUE(next.to_goal || next.end_time >= t + 0.1 + 2.0 - 1e-6) << next.end_time;
  // A second after the disturbance the window has closed.
  const double later = t + 1.05;
  const SessionStep after = session->step(session->planned_state(later), later);
  EXPECT_FALSE(after.disturbance.detected);
  EXPECT_FALSE(after.disturbance.recovering);
  EXPECT_DOUBLE_EQ(after.outcome.trajectory.extra["session"]["horizon"].get<double>(), 1.0);
}

// The schedule a capture step adapted carries over to the next steps: 0.1 s later, from the
// capture plan's state, the stepping foot is not "lifted" (no touch-down added) and stands from
// the capture step's touch-down on, not from the reference's.
TEST_F(FlatSession, ACaptureStepsScheduleCarriesOverToTheNextStep) {
  const double t = 0.6;
  const SessionStep step = session->step(pushed_left(t, 1.6), t);
  ASSERT_GE(step.capture.foot, 0) << "a capture step";
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  const int f = step.capture.foot;
  const double td = step.capture.touchdown;
  ASSERT_GT(td, 0.1);
  const SessionStep next = session->step(session->planned_state(t + 0.1), t + 0.1);
  ASSERT_TRUE(next.outcome.success) << next.outcome.message;
  EXPECT_TRUE(next.touchdowns.empty());
  const PhaseTimeline tl = timeline_of(next.outcome.trajectory);
  const double landed = td - 0.1;
  for (const auto& ph : tl.phases(f))
    if (ph.start <= landed + 0.03 && ph.end > landed + 0.03) {
      EXPECT_TRUE(ph.contact) << "the stepping foot stands from its capture touch-down";
      EXPECT_NEAR(ph.start, landed, 1e-6);
    }
  // The reference, which the next step followed before, has that foot swinging there (a swing
  // moved earlier) or standing throughout (a swing added): either way not this schedule.
  const PhaseTimeline reference = timeline_of(cold.trajectory).cropped(t + 0.1);
  bool differs = false;
  for (std::size_t k = 0; k < reference.feet.size(); ++k)
    for (const auto& ph : reference.phases(static_cast<int>(k)))
      differs |= static_cast<int>(k) == f && ph.contact != (ph.start >= landed - 1e-6) &&
                 ph.start < landed + 0.3;
  EXPECT_TRUE(differs);
}

// A disturbed step keeps the feet standing at its start on the ground for its first 0.3 s: a
// lift-off the schedule has 0.15 s in waits (a crawl lifting its next foot while the base is
// pushed takes support away when it is needed most), reported as session.held_liftoffs. The
// undisturbed step at the same time lifts that foot on schedule.
TEST_F(FlatSession, ADisturbedStepHoldsTheNextLiftOff) {
  // The first lift-off from 0.45 s on, and the foot lifting there.
  const PhaseTimeline reference = timeline_of(cold.trajectory);
  int foot = -1;
  double lift = 0.0;
  for (int j = 1; j < reference.num_intervals() && foot < 0; ++j)
    for (std::size_t f = 0; f < reference.feet.size() && foot < 0; ++f)
      if (reference.events[j] >= 0.45 && reference.contact[f][j - 1] && !reference.contact[f][j]) {
        foot = static_cast<int>(f);
        lift = reference.events[j];
      }
  ASSERT_GE(foot, 0) << "the crawl lifts a foot after 0.45 s";
  const double t = lift - 0.15;
  auto first_phase = [&](const SessionStep& s) {
    return timeline_of(s.outcome.trajectory).phases(foot).front();
  };
  PlanningSession quiet(robot, flat, flat, options, cold.trajectory, 1.0, 0.02);
  const SessionStep q = quiet.step(quiet.planned_state(t), t);
  ASSERT_TRUE(q.outcome.success) << q.outcome.message;
  EXPECT_TRUE(first_phase(q).contact);
  EXPECT_NEAR(first_phase(q).end, 0.15, 1e-6) << "undisturbed, the foot lifts on schedule";
  EXPECT_FALSE(q.outcome.trajectory.extra["session"].contains("held_liftoffs"));

  // The capture point 7 cm off the plan's, within the support.
  const SessionStep step = session->step(pushed_left(t, 0.3), t);
  ASSERT_TRUE(step.disturbance.detected);
  ASSERT_LT(step.capture.foot, 0) << "no capture step: the hold alone is tested";
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  EXPECT_TRUE(first_phase(step).contact);
  EXPECT_GE(first_phase(step).end, 0.3 - 1e-6) << "the lift-off waits";
  const auto& held = step.outcome.trajectory.extra["session"]["held_liftoffs"];
  ASSERT_TRUE(held.is_array());
  EXPECT_NE(std::find(held.begin(), held.end(), robot.legs[foot].name), held.end());
}

// A step made from a thread at a real-time priority (the service raises a budgeted step's thread
// so that its answer is not delayed by the scheduler) solves at the normal policy: the solver
// thread it starts would otherwise inherit SCHED_FIFO, and the step could not preempt its own
// solve at the deadline (the same priority never preempts under FIFO). The solve's per-iteration
// callback runs on the solver thread and records its policy.
TEST_F(FlatSession, TheSolveRunsAtTheNormalPolicyWhenTheStepIsRealTime) {
  int caller_policy = SCHED_OTHER;
  sched_param caller_param{};
  ASSERT_EQ(pthread_getschedparam(pthread_self(), &caller_policy, &caller_param), 0);
  sched_param rt{};
  rt.sched_priority = 1;
  if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &rt) != 0)
    GTEST_SKIP() << "this process may not use SCHED_FIFO (no CAP_SYS_NICE or rtprio limit)";
  auto solver_policy = std::make_shared<std::atomic<int>>(-1);
  StepLimits limits;
  limits.budget = 5.0;  // ample: the step waits for its solve on the worker thread
  limits.should_stop = [solver_policy] {
    int policy = -1;
    sched_param param{};
    if (pthread_getschedparam(pthread_self(), &policy, &param) == 0) solver_policy->store(policy);
    return false;
  };
  const SessionStep step = session->step(measured(0.2), 0.2, limits);
  pthread_setschedparam(pthread_self(), caller_policy, &caller_param);
  ASSERT_TRUE(step.outcome.success) << step.outcome.message;
  EXPECT_FALSE(step.fallback) << step.fallback_reason;
  EXPECT_EQ(solver_policy->load(), SCHED_OTHER);
  EXPECT_LE(step.answer_late_s, 0.0) << "the solve finished before its answer was due";
}

}  // namespace
}  // namespace terrastride::planner
