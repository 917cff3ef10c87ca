// Planning sessions: successive re-plans of one motion from measured states (planning_session.hpp).
#include "terrastride/planner/planning_session.hpp"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <thread>
#include <utility>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/planner/violation_report.hpp"

#include "convex_hull.hpp"

namespace terrastride::planner {

namespace {

constexpr double kDenseDt = 0.002;  // as plan_motion: dense checks every 2 ms
constexpr double kEventTol = 1e-6;
// A foot measured this high above the terrain where the schedule has it in stance is in the air
// (a push lifted it or it slipped off): the stance would hold its foothold there, in mid-air.
constexpr double kLiftedHeight = 0.03;
// Such a foot becomes a swing that touches down this long after the step's start (a foot some
// 5-10 cm up needs 0.15-0.2 s to come down), if its stance lasts 0.1 s beyond that; a stance
// ending sooner is left as it is (the foot is about to lift off anyway).
constexpr double kTouchdownAfter = 0.2;
// A push that carries the capture point (x + v / omega, omega = sqrt(g / h)) this far out of the
// support polygon of the feet standing at the step's start, and this much further out than the
// plan's own capture point there (a crawl's swing may leave it slightly outside by design), gets a
// step: the swing under way touches down by kCaptureTouchdown (or, with every foot standing, the
// stance foot nearest the capture point lifts and touches down then), its foothold moved towards
// the capture point by how far that lies outside, at most kCaptureShiftMax, on safe terrain.
constexpr double kCaptureOutside = 0.02;
constexpr double kCaptureTouchdown = 0.2;
constexpr double kCaptureShiftMax = 0.15;
// A disturbed step's feet standing at its start stand for its first kLiftoffHold at least: their
// lift-offs wait (hold_liftoffs), and a swing left shorter than kMinHeldSwing is skipped. The
// hold covers a capture step's or a touch-down's kCaptureTouchdown and 0.1 s of its stance.
constexpr double kLiftoffHold = 0.3;
constexpr double kMinHeldSwing = 0.25;
// A measured state whose capture point is this far from the plan's (m), or whose roll or pitch
// is this far from the plan's (rad), is disturbed (a push): the steps from it for
// kRecoveryWindow after the last such state plan over the recovery horizon (kRecoveryHorizon or
// the session's, the longer), which gives the return to the reference twice the time (with it
// the closed loop survived 1.5 x the open loop's push in 10 of the 32 pallet_15 push cells
// instead of 8). The undisturbed closed loops of the six shipped scenes detect none (0 of their
// 648 steps), so their steps are those of the session's horizon alone.
constexpr double kDisturbedCapturePoint = 0.05;
constexpr double kDisturbedTilt = 0.1;
constexpr double kRecoveryWindow = 1.0;
constexpr double kRecoveryHorizon = 2.0;

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
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

// One step's solve with everything it reads copied in, so that it can run on the session's
// worker thread while the session answers without it (and goes on to later steps).
struct StepJob {
  const robot::RobotModel* robot = nullptr;
  const terrain::HeightField* plan_terrain = nullptr;
  const terrain::HeightField* check_terrain = nullptr;
  PlannerOptions options;          // the session's
  ProblemOptions problem_options;  // this step's (its start lead)
  SolverOptions solver_options;
  PhaseTimeline timeline;
  SrbdProblem::StartState measured, pinned_end, base_end;
  Trajectory guess;
  double t = 0.0, end = 0.0, horizon = 0.0, sample_dt = 0.01;
  bool to_goal = false, warm_from_late = false;
  int step_number = 0;
  int iteration_budget = 0;  // StepLimits::iterations (its solve capped at 4 x that)
  std::vector<std::string> touchdowns;  // feet in the air turned from stance to a swing
  CaptureStep capture;                  // a step after a push (foot < 0: none)
  std::vector<int> held_liftoffs;       // feet whose lift-off waits (hold_liftoffs)
  bool skipped_swing = false;           // one of them does not swing within the step
  Disturbance disturbance;
  // > 0: the guess is bridged from the measured state over this span (bridge_span_of).
  double bridge_span = 0.0;
  Clock::time_point t0;
  // Cancels the solve at its next iteration (a newer step needs the worker, or the session ends).
  std::atomic<bool> cancel{false};
  // Its step answered without it (set under StepWorker's mutex, read by the job as it finishes).
  std::atomic<bool> abandoned{false};
  bool done = false;  // under StepWorker's mutex
  SessionStep result;
};

namespace {

// The stance of `foot` that begins at time `from` of problem p's timeline (a capture step's
// touch-down), or null.
const Layout::Stance* stance_from(const SrbdProblem& p, int foot, double from) {
  const Layout& L = p.layout();
  for (const auto& st : L.stances)
    if (st.foot == foot && std::abs(L.nominal_knot_time[st.first_seg] - from) < 1e-6) return &st;
  return nullptr;
}

// The capture step's foothold guess: the warm start's, moved by the step's shift (by less where
// the full shift lands on unsafe terrain; not at all when every fraction does), on the terrain.
void place_capture_foothold(StepJob& job, SrbdProblem* p) {
  CaptureStep& c = job.capture;
  const Layout::Stance* st = stance_from(*p, c.foot, c.touchdown);
  if (!st || !(p->lower()[st->pos_var] < p->upper()[st->pos_var])) return;
  std::vector<double>& x = p->initial_guess();
  const Eigen::Vector2d from(x[st->pos_var], x[st->pos_var + 1]);
  const double radius = job.robot->foot_radius;
  for (const double scale : {1.0, 0.75, 0.5, 0.25}) {
    const Eigen::Vector2d q = from + scale * c.shift;
    if (job.plan_terrain->safety_margin(q.x(), q.y(), radius).margin > 0.0) {
      x[st->pos_var] = q.x();
      x[st->pos_var + 1] = q.y();
      x[st->pos_var + 2] = job.plan_terrain->height(q.x(), q.y());
      c.foothold = Eigen::Vector3d(q.x(), q.y(), x[st->pos_var + 2]);
      c.placed = true;
      return;
    }
  }
}

// How far a step's measured start is from its warm start's: base velocity (m/s) and Euler rates
// (rad/s).
struct StartDisturbance {
  double velocity = 0.0, rates = 0.0;
};
StartDisturbance start_disturbance(const StepJob& job) {
  const SrbdProblem::StartState g = start_state_of(job.guess, job.t);
  return {(job.measured.linear_velocity - g.linear_velocity).norm(),
          (job.measured.euler_rates - g.euler_rates).norm()};
}

// A start this far from its warm start is disturbed (a push): undisturbed closed loops of the six
// `all` scenes stay within 0.26 m/s and 0.42 rad/s of it, the steps after a 1.5x push on pallet_15
// reach 0.7-1.3 m/s and 1-2.6 rad/s. Such a step, and no other (undisturbed steps are solved as
// before), gets a guess bridged from the measured state to the previous plan
// (SrbdProblem::warm_start_from) over the time the velocity offset takes to shed at friction * g
// (the Hermite bridge's peak deceleration is 4 |dv| / span), within [kBridgeSpanMin,
// kBridgeSpanMax], and Ipopt's bound push 1e-2 (solve_job). Room on the first dynamics rows (an
// unplanned start wrench of 1 body weight decaying over 0.3 s) made more post-push steps converge
// (86-94 of some 195 at the iteration cap instead of 103-109) but none within its budget, and
// fewer pushed closed loops stood, so a step's dynamics rows stay exact (docs/sessions.md).
constexpr double kDisturbedVelocity = 0.3;  // m/s
constexpr double kDisturbedRates = 0.6;     // rad/s
constexpr double kBridgeSpanMin = 0.2, kBridgeSpanMax = 0.4;  // s

bool disturbed(const StartDisturbance& d) {
  return d.velocity > kDisturbedVelocity || d.rates > kDisturbedRates;
}

// The span of a step's bridged guess, 0 for none: a step is bridged when its start is off its
// warm start, or when the session found its measured state disturbed (prepare: off the plan's
// capture point or tilt, a lifted foot, a capture step).
double bridge_span_of(const StepJob& job) {
  const StartDisturbance d = start_disturbance(job);
  if (!disturbed(d) && !job.disturbance.detected) return 0.0;
  return std::clamp(4.0 * d.velocity / (job.options.friction * kGravity), kBridgeSpanMin,
                    kBridgeSpanMax);
}

std::unique_ptr<SrbdProblem> build_problem(StepJob& job, const SrbdProblem::StartState* end_state) {
  auto p = std::make_unique<SrbdProblem>(*job.robot, *job.plan_terrain, job.timeline,
                                         job.problem_options, &job.measured, end_state);
  p->warm_start_from(job.guess, job.t, job.bridge_span);
  if (job.capture.foot >= 0) place_capture_foothold(job, p.get());
  return p;
}

// The solve of a step: pinned end first, then (it failed, and neither its time nor a stop ended
// it) with the end's feet free.
std::unique_ptr<SrbdProblem> solve_job(StepJob& job) {
  SessionStep& out = job.result;
  std::unique_ptr<SrbdProblem> problem = build_problem(job, job.to_goal ? nullptr : &job.pinned_end);
  out.build_s = seconds_since(job.t0);
  PlanOutcome& o = out.outcome;
  SolverOptions solver_options = job.solver_options;
  const auto external_stop = solver_options.should_stop;
  solver_options.should_stop = [&job, external_stop] {
    return job.cancel.load() || (external_stop && external_stop());
  };
  // As plan_motion's re-plans: a small barrier and bound push keep the warm start. A disturbed
  // start's guess (kDisturbedVelocity) is far from its solution anyway: its inequalities' slacks
  // start 1e-2 inside their bounds instead, so that its first steps are cut less by the
  // fraction-to-boundary rule.
  const std::string push = job.bridge_span > 0.0 ? "1e-2" : "1e-5";
  std::vector<std::pair<std::string, std::string>> step_options = {
      {"mu_init", "1e-4"}, {"bound_push", push}, {"bound_frac", push},
      // A step's constraint Jacobian is rank-deficient (Ipopt's first factorisation of every
      // iteration, without the constraints' regularisation delta_c, failed as singular in MUMPS
      // after its full set-up, until Ipopt had seen three such iterations): the regularisation
      // from the first, and no MUMPS scaling (the forces are already scaled to body weights,
      // SrbdTnlp::get_scaling_parameters), which MUMPS recomputed for every factorisation.
      {"perturb_always_cd", "yes"}, {"mumps_scaling", "0"},
      // Mehrotra's probing for the barrier parameter instead of the quality-function search:
      // the adaptive quality function raised mu from mu_init to 1e-2..1e-2.5 at the first
      // iteration and took 3-5 iterations back down, and 9-75 (two failed at 120) where the
      // horizon's end moves onto the pallet. With probing 40 steps of pallet_15 `all`
      // (bench_service --mode replan) took 169 iterations instead of 330, at most 7, none
      // failed; a monotone barrier, or LOQO's rule, took 277-563 with failures
      // (docs/results/2026-11-28-measurements.md).
      {"mu_oracle", "probing"}};
  // TERRASTRIDE_STEP_IPOPT_OPTIONS adds Ipopt options to session steps only (tuning runs;
  // TERRASTRIDE_IPOPT_OPTIONS would change the reference's cold solve too).
  for (auto& option : ipopt_options_from_env("TERRASTRIDE_STEP_IPOPT_OPTIONS"))
    step_options.push_back(std::move(option));
  const double cap = solver_options.max_time;
  o.solve = solve(*problem, solver_options, step_options);
  // A solve ended by its time, a stop, or an iteration budget's cap is not retried: the retry
  // is for a problem the pinned end makes infeasible, not for one out of budget.
  const bool stopped = o.solve.status == "time_limit" || solver_options.should_stop() ||
                       (job.iteration_budget > 0 && o.solve.status == "max_iterations");
  if (!o.solve.success && !job.to_goal && !stopped) {
    const SolveResult pinned = o.solve;
    out.feet_freed = true;
    out.pinned_feet_status = pinned.status;
    out.pinned_feet_iterations = pinned.iterations;
    problem = build_problem(job, &job.base_end);
    if (cap > 0.0) solver_options.max_time = std::max(0.001, cap - seconds_since(job.t0));
    o.solve = solve(*problem, solver_options, step_options);
    // The step's solver figures cover both solves.
    o.solve.iterations += pinned.iterations;
    o.solve.wall_s += pinned.wall_s;
  }
  o.success = o.solve.success;
  return problem;
}

nlohmann::json capture_step_json(const StepJob& job) {
  const CaptureStep& c = job.capture;
  nlohmann::json j = {{"foot", job.robot->legs[c.foot].name},
                      {"touchdown_after_s", c.touchdown},
                      {"touchdown_moved_from_s", c.scheduled_touchdown},
                      {"added_swing", c.added_swing},
                      {"capture_point", {c.point.x(), c.point.y()}},
                      {"outside_m", c.outside},
                      {"foothold_shift", {c.shift.x(), c.shift.y()}}};
  if (c.placed) j["foothold_guess"] = {c.foothold.x(), c.foothold.y(), c.foothold.z()};
  return j;
}

// The schedule a step adapted to its measured state (touch-downs, a capture step), into its
// plan's "session" report.
void write_schedule_adaptation(const StepJob& job, nlohmann::json* session) {
  if (!job.touchdowns.empty())
    (*session)["touchdowns"] = {{"feet", job.touchdowns}, {"after_s", kTouchdownAfter}};
  if (job.capture.foot >= 0) (*session)["capture_step"] = capture_step_json(job);
  if (!job.held_liftoffs.empty()) {
    nlohmann::json feet = nlohmann::json::array();
    for (int f : job.held_liftoffs) feet.push_back(job.robot->legs[f].name);
    (*session)["held_liftoffs"] = feet;
  }
}

// The solved step as a plan: samples, solver figures, dense checks, and why it failed.
void run_job(StepJob& job) {
  const std::unique_ptr<SrbdProblem> problem = solve_job(job);
  SessionStep& out = job.result;
  out.start_time = job.t;
  out.end_time = job.end;
  out.to_goal = job.to_goal;
  out.warm_from_late_solve = job.warm_from_late;
  PlanOutcome& o = out.outcome;
  // A cancelled solve is of no use to anyone: no samples, no checks (their CPU would be taken
  // from the step that cancelled it).
  if (job.cancel.load() && !o.success) return;
  const auto t_after_solve = Clock::now();
  o.trajectory = sample_solution(*problem, o.solve.x, job.sample_dt);
  auto& st = o.trajectory.solver;
  st.status = o.solve.status;
  st.iterations = o.solve.iterations;
  st.wall_s = o.solve.wall_s;
  st.n_variables = problem->num_free_variables();
  st.n_constraints = problem->num_constraints();
  auto& ex = o.trajectory.extra;
  ex["solver_max_violation"] = o.solve.max_violation;
  ex["solver_termination"] = o.solve.termination;
  ex["constraints"] = job.options.constraints;
  ex["path_line"] = path_line_json(job.options);
  ex["start_time"] = job.t;
  ex["session"] = {{"step", job.step_number}, {"end_time", job.end}, {"to_goal", job.to_goal},
                   {"horizon", job.horizon}};
  out.touchdowns = job.touchdowns;
  out.capture = job.capture;
  write_schedule_adaptation(job, &ex["session"]);
  // The measured start's own violations (rows on it alone, left out of the solve).
  if (!problem->start_excess().empty()) ex["start_excess"] = problem->start_excess();
  if (!problem->end_excess().empty()) ex["session"]["end_excess"] = problem->end_excess();
  if (out.feet_freed)
    ex["session"]["end_feet_freed"] = {{"pinned_status", out.pinned_feet_status},
                                       {"pinned_iterations", out.pinned_feet_iterations}};
  // A plan whose step has answered without it is only a warm start: no dense checks.
  if (!job.abandoned.load()) {
    DenseCheckLimits lim;
    lim.friction = job.options.friction;
    lim.max_normal_force = job.options.max_normal_force_factor * job.robot->mass * kGravity;
    o.trajectory.checks = dense_checks(*job.robot, *job.check_terrain,
                                       sample_solution(*problem, o.solve.x, kDenseDt), lim);
    ex["checks_dt"] = kDenseDt;
  }
  ex["timings"] = {{"build_s", out.build_s},
                   {"solve_s", o.solve.wall_s},
                   {"sample_and_checks_s", seconds_since(t_after_solve)},
                   {"total_s", seconds_since(job.t0)}};
  if (o.success) return;
  std::ostringstream m;
  m << "the re-plan from t = " << job.t << " s ended with status '" << o.solve.status
    << "' after " << o.solve.iterations << " iterations; largest constraint violation "
    << o.solve.max_violation;
  const auto left = violated_families(*problem, o.solve.x, job.options.tolerance);
  if (!left.empty()) m << "; still violated: " << describe_violations(left);
  for (const auto& [kind, excess] : problem->start_excess())
    m << "; the measured start exceeds " << kind << " by " << excess;
  for (const auto& [kind, excess] : problem->end_excess())
    m << "; the pinned end exceeds " << kind << " by " << excess;
  m << " (the session keeps its previous plan)";
  o.message = m.str();
  ex["failure"] = o.message;
}

// The distance from q to the convex polygon of `points` (0 inside; to a segment or a point for
// two or one), and the nearest point of it.
double outside_support(const std::vector<Eigen::Vector2d>& points, const Eigen::Vector2d& q,
                       Eigen::Vector2d* nearest) {
  const std::vector<Eigen::Vector2d> h = convex_hull_2d(points);
  bool inside = h.size() >= 3;
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < h.size(); ++i) {
    const Eigen::Vector2d a = h[i], b = h[(i + 1) % h.size()];
    if (h.size() >= 3 && cross_2d(a, b, q) < 0) inside = false;
    const Eigen::Vector2d ab = b - a;
    const double u =
        ab.squaredNorm() > 0 ? std::clamp((q - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
    const Eigen::Vector2d c = a + u * ab;
    if ((q - c).norm() < best) {
      best = (q - c).norm();
      *nearest = c;
    }
  }
  if (inside) {
    *nearest = q;
    return 0.0;
  }
  return best;
}

// The index of the event of `tl` at td: an existing one within 0.03 s of it, else one inserted
// there (the interval it splits duplicated); -1 when td lies beyond the timeline's last event.
int event_at(double td, PhaseTimeline* tl) {
  int e = 1;
  while (e <= tl->num_intervals() && !(tl->events[e] > td - 0.03)) ++e;
  if (e > tl->num_intervals()) return -1;
  if (std::abs(tl->events[e] - td) <= 0.03) return e;
  tl->events.insert(tl->events.begin() + e, td);
  for (auto& c : tl->contact) c.insert(c.begin() + (e - 1), static_cast<bool>(c[e - 1]));
  return e;
}

// Foot f of `tl` (a step's timeline, from 0) touching down at td instead of later in its swing
// under way (at `scheduled`): an event added at td unless one is within 0.03 s, the foot in
// stance from there.
void touch_down_earlier(int f, double td, double scheduled, PhaseTimeline* tl) {
  const int e = event_at(td, tl);
  if (e < 0) return;
  for (int j = e; j < tl->num_intervals() && tl->events[j] < scheduled - 1e-9; ++j)
    tl->contact[f][j] = true;
}

// `tl` (a step's timeline, from 0) with each foot of `lifted` (in stance in its first interval)
// swinging until kTouchdownAfter, an event added there if none is within 0.03 s. Returns the
// feet it changed.
std::vector<int> add_touchdowns(const std::vector<int>& lifted, PhaseTimeline* tl,
                                double td = kTouchdownAfter) {
  std::vector<int> changed;
  if (tl->duration() < td + 0.1) return changed;
  const int e = event_at(td, tl);
  td = tl->events[e];
  for (int f : lifted) {
    // The stance must last past td + 0.1 s.
    bool stance = true;
    for (int j = 0; j < tl->num_intervals() && tl->events[j] < td + 0.1; ++j)
      stance = stance && tl->contact[f][j];
    if (!stance) continue;
    for (int j = 0; j < e; ++j) tl->contact[f][j] = false;
    if (tl->swing_elapsed.size() != tl->feet.size()) tl->swing_elapsed.assign(tl->feet.size(), 0.0);
    tl->swing_elapsed[f] = 0.0;
    changed.push_back(f);
  }
  return changed;
}

// Foot lift-offs of `tl` (a step's timeline, from 0) before `until` wait until then, but for the
// feet of `moving` (those the step touches down or steps with). After a push the crawl went on
// lifting its next foot on schedule: with a capture step or a touch-down in the air that left two
// feet of four standing, after a lateral push often both on the side the base falls towards
// (pallet_15, 712 N to the right at 1.57 s: RF stepped and RH lifted 0.125 s later, and no re-plan
// converged: 600 iterations left force_ramp and the dynamics violated), and standing on all four
// is the most support a push can meet (the robot standing still survives 83-92 % of the
// rigid-body limit, benchmarks.md §12.2). A swing that would keep less than kMinHeldSwing is not
// taken within the step (*skipped): the foot stands through it. Returns the feet it held.
std::vector<int> hold_liftoffs(double until, const std::vector<int>& moving, PhaseTimeline* tl,
                               bool* skipped) {
  const int n = tl->num_intervals();
  const int nf = static_cast<int>(tl->contact.size());
  auto lifts_before = [&](int f) {
    for (int j = 1; j < n && tl->events[j] < until - kEventTol; ++j)
      if (tl->contact[f][j - 1] && !tl->contact[f][j]) return true;
    return false;
  };
  std::vector<int> feet;
  for (int f = 0; f < nf; ++f)
    if (std::find(moving.begin(), moving.end(), f) == moving.end() && lifts_before(f))
      feet.push_back(f);
  if (feet.empty() || until >= tl->duration() - kEventTol) return {};
  const int stop = event_at(until, tl);  // the first interval starting at `until`
  for (int f : feet) {
    auto& c = tl->contact[f];
    for (int j = 1; j < stop; ++j) {
      if (!c[j - 1] || c[j]) continue;
      int land = j;  // the swing's first interval after it (num_intervals: no touch-down)
      while (land < tl->num_intervals() && !c[land]) ++land;
      const double touchdown = tl->events[land];
      const bool skip = touchdown - tl->events[stop] < kMinHeldSwing;
      *skipped = *skipped || skip;
      for (int k = j; k < (skip ? land : stop); ++k) c[k] = true;
    }
  }
  return feet;
}

// When foot f first stands in `tl` (its duration when it never does).
double first_contact(const PhaseTimeline& tl, int f) {
  for (int j = 0; j < tl.num_intervals(); ++j)
    if (tl.contact[f][j]) return tl.events[j];
  return tl.duration();
}

// The step a push calls for (planning_session.hpp, CaptureStep; foot -1 when none): from the
// measured state's capture point against the support polygon of the feet standing at the start
// (`airborne`: feet the step already swings), compared with the planned state's.
CaptureStep plan_capture_step(const robot::RobotModel& robot,
                              const SrbdProblem::StartState& measured,
                              const SrbdProblem::StartState& planned,
                              const std::vector<int>& airborne, PhaseTimeline* tl) {
  CaptureStep c;
  const int nf = static_cast<int>(robot.legs.size());
  std::vector<Eigen::Vector2d> support;
  double ground = 0.0;
  for (int f = 0; f < nf; ++f)
    if (tl->contact[f][0] && std::find(airborne.begin(), airborne.end(), f) == airborne.end()) {
      support.push_back(measured.foot_position[f].head<2>());
      ground += measured.foot_position[f].z();
    }
  if (support.empty()) return c;
  const double h = measured.position.z() - ground / static_cast<double>(support.size());
  if (!(h > 0.05)) return c;
  const double omega = std::sqrt(kGravity / h);
  auto capture_point = [&](const SrbdProblem::StartState& s) -> Eigen::Vector2d {
    return s.position.head<2>() + s.linear_velocity.head<2>() / omega;
  };
  Eigen::Vector2d nearest, nearest_planned;
  const Eigen::Vector2d cp = capture_point(measured);
  const double outside = outside_support(support, cp, &nearest);
  const double planned_outside = outside_support(support, capture_point(planned), &nearest_planned);
  if (!(outside > kCaptureOutside) || !(outside - planned_outside > kCaptureOutside)) return c;
  c.point = cp;
  c.outside = outside;
  c.shift = cp - nearest;
  if (c.shift.norm() > kCaptureShiftMax) c.shift *= kCaptureShiftMax / c.shift.norm();
  // The swing under way (the one landing nearest the capture point), touching down sooner.
  double best = std::numeric_limits<double>::infinity();
  for (int f = 0; f < nf; ++f) {
    if (tl->contact[f][0] || std::find(airborne.begin(), airborne.end(), f) != airborne.end())
      continue;
    const double land = first_contact(*tl, f);
    if (land >= tl->duration() - 1e-9) continue;  // no touch-down within the step
    const double d = (measured.foot_position[f].head<2>() - cp).norm();
    if (d < best) {
      best = d;
      c.foot = f;
      c.scheduled_touchdown = land;
    }
  }
  if (c.foot >= 0) {
    if (c.scheduled_touchdown > kCaptureTouchdown + 0.03)
      touch_down_earlier(c.foot, kCaptureTouchdown, c.scheduled_touchdown, tl);
    c.touchdown = first_contact(*tl, c.foot);
    return c;
  }
  // Every foot stands: the one nearest the capture point steps (if its stance lasts long enough).
  std::vector<std::pair<double, int>> by_distance;
  for (int f = 0; f < nf; ++f)
    if (tl->contact[f][0])
      by_distance.push_back({(measured.foot_position[f].head<2>() - cp).norm(), f});
  std::sort(by_distance.begin(), by_distance.end());
  for (const auto& [d, f] : by_distance) {
    PhaseTimeline stepped = *tl;  // add_touchdowns may add its event even when no foot can step
    if (add_touchdowns({f}, &stepped, kCaptureTouchdown).empty()) continue;
    *tl = std::move(stepped);
    c.foot = f;
    c.added_swing = true;
    c.touchdown = first_contact(*tl, f);
    c.scheduled_touchdown = c.touchdown;
    return c;
  }
  return CaptureStep{};
}

// Whether foot f stands at time u of `tl`.
bool stands_at(const PhaseTimeline& tl, std::size_t f, double u) {
  for (int j = 0; j < tl.num_intervals(); ++j)
    if (u < tl.events[j + 1]) return tl.contact[f][j];
  return tl.contact[f].back();
}

// Whether `a` and `b` (timelines from the same start) have every foot in the same phase up to
// `until`, their events equal to round-off (intervals shorter than 0.1 ms are not compared).
bool same_schedule(const PhaseTimeline& a, const PhaseTimeline& b, double until) {
  std::vector<double> ev;
  for (const PhaseTimeline* tl : {&a, &b})
    for (double e : tl->events)
      if (e < until) ev.push_back(e);
  ev.push_back(until);
  std::sort(ev.begin(), ev.end());
  for (std::size_t k = 0; k + 1 < ev.size(); ++k) {
    if (ev[k + 1] - ev[k] < 1e-4) continue;
    const double mid = 0.5 * (ev[k] + ev[k + 1]);
    for (std::size_t f = 0; f < a.feet.size(); ++f)
      if (stands_at(a, f, mid) != stands_at(b, f, mid)) return false;
  }
  return true;
}

// Where a step from t over `horizon` ends: the first contact switch of `tl` at or after
// t + horizon with no foot in mid-swing across it (a swing cut at the horizon would lose its
// touch-down), else the end of `tl` (the goal).
double horizon_end(const PhaseTimeline& tl, double t, double horizon) {
  const auto& ev = tl.events;
  if (horizon > 0.0)
    for (int j = 1; j < tl.num_intervals(); ++j) {
      if (ev[j] < t + horizon - kEventTol) continue;
      bool swing_across = false;
      for (const auto& c : tl.contact) swing_across |= !c[j - 1] && !c[j];
      if (!swing_across) return ev[j];
    }
  return ev.back();
}

// The feet measured in the air (kLiftedHeight above the terrain) where `tl` (from the step's
// start) has them in stance.
std::vector<int> lifted_feet(const SrbdProblem::StartState& measured, const PhaseTimeline& tl,
                             const terrain::HeightField& terrain) {
  std::vector<int> lifted;
  for (std::size_t f = 0; f < measured.foot_position.size(); ++f) {
    const Eigen::Vector3d& p = measured.foot_position[f];
    Eigen::Vector2d gradient;
    if (tl.contact[f][0] &&
        p.z() - terrain.height_and_gradient(p.x(), p.y(), &gradient) > kLiftedHeight)
      lifted.push_back(static_cast<int>(f));
  }
  return lifted;
}

// The measured state's offset from the planned one (Disturbance): capture points with omega from
// the measured base height above the feet standing at the start of `tl`, and roll/pitch.
Disturbance measure_disturbance(const SrbdProblem::StartState& measured,
                                const SrbdProblem::StartState& planned, const PhaseTimeline& tl) {
  Disturbance d;
  double ground = 0.0;
  int standing = 0;
  for (std::size_t f = 0; f < measured.foot_position.size(); ++f)
    if (tl.contact[f][0]) {
      ground += measured.foot_position[f].z();
      ++standing;
    }
  const double h = standing > 0 ? measured.position.z() - ground / standing : 0.0;
  if (h > 0.05) {
    const double omega = std::sqrt(kGravity / h);
    const Eigen::Vector2d dx = (measured.position - planned.position).head<2>();
    const Eigen::Vector2d dv = (measured.linear_velocity - planned.linear_velocity).head<2>();
    d.capture_point_offset = (dx + dv / omega).norm();
  }
  d.tilt_offset = (measured.euler_zyx - planned.euler_zyx).tail<2>().cwiseAbs().maxCoeff();
  d.detected = d.capture_point_offset > kDisturbedCapturePoint || d.tilt_offset > kDisturbedTilt;
  return d;
}

nlohmann::json disturbance_json(const Disturbance& d) {
  return {{"capture_point_offset_m", d.capture_point_offset},
          {"tilt_offset_rad", d.tilt_offset},
          {"detected", d.detected},
          {"recovering", d.recovering}};
}

// A timeline as plan.json writes it ("timeline") and the per-foot phases it implies ("phases").
void write_timeline(const PhaseTimeline& tl, nlohmann::json* extra) {
  nlohmann::json contact = nlohmann::json::array(), phases = nlohmann::json::object();
  for (std::size_t f = 0; f < tl.feet.size(); ++f) {
    contact.push_back(tl.contact[f]);
    nlohmann::json list = nlohmann::json::array();
    for (const auto& ph : tl.phases(static_cast<int>(f)))
      list.push_back({{"start", ph.start}, {"end", ph.end}, {"contact", ph.contact}});
    phases[tl.feet[f]] = list;
  }
  (*extra)["timeline"] = {{"events", tl.events}, {"contact", contact}};
  if (tl.first_interval_elapsed > 0.0)
    (*extra)["timeline"]["first_interval_elapsed"] = tl.first_interval_elapsed;
  if (!tl.swing_elapsed.empty()) (*extra)["timeline"]["swing_elapsed"] = tl.swing_elapsed;
  (*extra)["phases"] = phases;
}

}  // namespace

// The session's solver thread. One solve at a time: a step submits its job and waits for it
// until its answer is due; a job still running when the next is submitted is cancelled (through
// the solver's per-iteration callback), so a step never queues behind a stale solve for longer
// than that solve's current iteration, and the step's own wait is bounded by its deadline anyway.
// A job that finishes with a plan after its step answered is kept (take_late): the session adopts
// it as its current plan at the next step (the next step's warm start, and its fallback).
class StepWorker {
 public:
  ~StepWorker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
      if (running_) running_->cancel = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  void submit(std::shared_ptr<StepJob> job) {
    std::lock_guard<std::mutex> lock(mu_);
    if (running_) running_->cancel = true;
    pending_ = std::move(job);  // a job not started yet is dropped: its step has answered
    if (!thread_.joinable()) thread_ = std::thread([this] { run(); });
    wake_.notify_all();
  }
  // True when `job` finished by `until`; else it is marked abandoned and runs on.
  bool wait(StepJob& job, Clock::time_point until) {
    std::unique_lock<std::mutex> lock(mu_);
    if (done_.wait_until(lock, until, [&] { return job.done; })) return true;
    job.abandoned = true;
    return false;
  }
  // Cancels the running job and drops a pending one (a step that solves in its own thread).
  void cancel_all() {
    std::lock_guard<std::mutex> lock(mu_);
    if (running_) running_->cancel = true;
    pending_.reset();
  }
  // The newest abandoned job that finished with a plan, once.
  std::shared_ptr<StepJob> take_late() {
    std::lock_guard<std::mutex> lock(mu_);
    return std::move(late_);
  }

 private:
  void run() {
    // The solve at the normal policy whatever its creator's (a server raises a budgeted step's
    // thread to a real-time one, and a thread inherits that): the step must be able to preempt
    // its own solve at the deadline.
    sched_param normal{};
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &normal);
    std::unique_lock<std::mutex> lock(mu_);
    for (;;) {
      wake_.wait(lock, [&] { return stop_ || pending_; });
      if (stop_) return;
      running_ = std::move(pending_);
      const std::shared_ptr<StepJob> job = running_;
      lock.unlock();
      run_job(*job);
      lock.lock();
      job->done = true;
      running_.reset();
      if (job->abandoned && job->result.outcome.success) late_ = job;
      done_.notify_all();
    }
  }
  std::mutex mu_;
  std::condition_variable wake_, done_;
  std::shared_ptr<StepJob> pending_, running_, late_;
  bool stop_ = false;
  std::thread thread_;
};


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

PlanningSession::~PlanningSession() = default;

Trajectory PlanningSession::current_plan_from(double t, double end) const {
  Trajectory out;
  out.robot = reference_.robot;
  out.gait = reference_.gait;
  out.feet = reference_.feet;
  out.sample_dt = sample_dt_;
  const double T = reference_.duration;
  end = std::min(std::max(end, t), T);
  out.duration = end - t;
  const double prev_end = previous_start_ + previous_.duration;
  const int n = static_cast<int>(std::ceil(out.duration / sample_dt_ - 1e-9));
  for (int i = 0; i <= n; ++i) {
    const double tau = std::min(t + i * sample_dt_, end);
    TrajectorySample s = tau >= previous_start_ && tau <= prev_end
                             ? interpolate_plan(previous_, tau - previous_start_)
                             : interpolate_plan(reference_, tau);
    s.t = tau - t;
    out.samples.push_back(std::move(s));
  }
  // The schedule of the plans the samples come from: the last plan's (it may have added a
  // touch-down) up to its end, which is an event of the reference's, then the reference's.
  PhaseTimeline tl;
  if (t >= previous_start_ && t < prev_end - kEventTol && previous_.extra.contains("timeline")) {
    tl = timeline_of(previous_).cropped(t - previous_start_);
    if (end < prev_end - kEventTol) {
      tl = truncated_timeline(tl, end - t);
    } else if (end > prev_end + kEventTol) {
      const PhaseTimeline rest =
          truncated_timeline(reference_timeline_.cropped(prev_end), end - prev_end);
      for (int j = 0; j < rest.num_intervals(); ++j) {
        tl.events.push_back(prev_end - t + rest.events[j + 1]);
        for (std::size_t f = 0; f < tl.feet.size(); ++f) tl.contact[f].push_back(rest.contact[f][j]);
      }
    }
  } else {
    tl = reference_timeline_.cropped(std::min(t, T - kEventTol));
    if (end < T - kEventTol) tl = truncated_timeline(tl, end - t);
  }
  write_timeline(tl, &out.extra);
  out.extra["start_time"] = t;
  return out;
}

SessionStep PlanningSession::fallback_step(const StepJob& job, const std::string& reason,
                                           const std::string& message) const {
  SessionStep out;
  out.start_time = job.t;
  out.end_time = job.end;
  out.to_goal = job.to_goal;
  out.fallback = true;
  out.fallback_reason = reason;
  out.warm_from_late_solve = job.warm_from_late;
  PlanOutcome& o = out.outcome;
  o.success = true;
  o.message = message;
  o.trajectory = current_plan_from(job.t, job.end);
  o.trajectory.solver.status = "fallback";
  auto& ex = o.trajectory.extra;
  ex["constraints"] = options_.constraints;
  ex["path_line"] = path_line_json(options_);
  ex["session"] = {{"step", job.step_number}, {"end_time", job.end}, {"to_goal", job.to_goal},
                   {"horizon", horizon_},     {"fallback", true},      {"fallback_reason", reason},
                   {"fallback_message", message}};
  return out;
}

SessionStep PlanningSession::fallback_after_solve(const StepJob& job, const std::string& reason,
                                                  const std::string& message) const {
  SessionStep out = fallback_step(job, reason, message);
  // What the step tried, though its plan is not the answer: the schedule it adapted.
  write_schedule_adaptation(job, &out.outcome.trajectory.extra["session"]);
  out.outcome.solve = job.result.outcome.solve;
  out.outcome.trajectory.solver.iterations = job.result.outcome.solve.iterations;
  out.outcome.trajectory.solver.wall_s = job.result.outcome.solve.wall_s;
  return out;
}

SessionStep PlanningSession::step_with_iteration_budget(const std::shared_ptr<StepJob>& job,
                                                        int iterations) {
  if (worker_) worker_->cancel_all();
  // The solve may go on past the budget (as a wall-clock step's solve runs on after its answer)
  // for a plan the next step starts from.
  int& cap = job->solver_options.max_iterations;
  cap = std::min(cap, 4 * iterations);
  job->iteration_budget = iterations;
  run_job(*job);
  const PlanOutcome& o = job->result.outcome;
  const bool capped = o.solve.status == "max_iterations";  // at the cap above
  if (!o.success && !capped) return fallback_after_solve(*job, "solve_failed", o.message);
  if (o.success && o.solve.iterations <= iterations) return std::move(job->result);
  std::ostringstream m;
  m << "the re-plan from t = " << job->t << " s " << (o.success ? "took " : "had not converged in ")
    << o.solve.iterations << " solver iterations, over its budget of " << iterations
    << "; the session's current plan from t stands"
    << (o.success ? " (the solve's plan is the next step's warm start)" : "");
  // Why it had not converged: the families still violated at the cap (run_job's message).
  if (!o.success && !o.message.empty()) m << "; " << o.message;
  SessionStep out = fallback_after_solve(*job, "iterations", m.str());
  if (o.success) late_by_iterations_ = job;
  return out;
}

void PlanningSession::adopt_late_solve() {
  std::shared_ptr<StepJob> job = std::move(late_by_iterations_);
  late_by_iterations_.reset();
  if (worker_)
    if (auto from_worker = worker_->take_late(); from_worker && (!job || from_worker->t > job->t))
      job = std::move(from_worker);
  if (!job || job->t <= previous_start_) return;
  previous_ = std::move(job->result.outcome.trajectory);
  previous_start_ = job->t;
  adopted_late_ = true;
}

std::shared_ptr<StepJob> PlanningSession::prepare(const SrbdProblem::StartState& measured,
                                                  double t, const StepLimits& limits) {
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
  auto job = std::make_shared<StepJob>();
  job->t0 = Clock::now();
  job->robot = &robot_;
  job->plan_terrain = &plan_terrain_;
  job->check_terrain = &check_terrain_;
  job->options = options_;
  job->measured = measured;
  job->t = t;
  job->sample_dt = sample_dt_;
  job->step_number = steps_ + 1;
  // The schedule from t (the last plan's where it adapted the reference's: a capture step is kept
  // until that plan's end), adapted to the measured state (touch-downs, a capture step) before
  // it is cut at the horizon, whose length depends on whether the state is disturbed. A foot
  // measured in the air where the schedule has a stance swings and touches down.
  job->timeline = schedule_from(t);
  const SrbdProblem::StartState planned = planned_state(t);
  job->disturbance = measure_disturbance(measured, planned, job->timeline);
  std::vector<int> airborne;
  if (const auto lifted = lifted_feet(measured, job->timeline, plan_terrain_); !lifted.empty())
    for (int f : add_touchdowns(lifted, &job->timeline)) {
      job->touchdowns.push_back(robot_.legs[f].name);
      airborne.push_back(f);
    }
  // A push that carries the capture point out of the support gets a step (CaptureStep), its
  // foothold placed as the problem is built; the end's feet are then free (the step's foothold
  // may be the one the end would pin).
  job->capture = plan_capture_step(robot_, measured, planned, airborne, &job->timeline);
  Disturbance& d = job->disturbance;
  d.detected = d.detected || !airborne.empty() || job->capture.foot >= 0;
  // While the robot recovers, the feet standing keep standing (hold_liftoffs).
  if (d.detected && job->capture.foot < 0)
    job->held_liftoffs = hold_liftoffs(kLiftoffHold, airborne, &job->timeline, &job->skipped_swing);
  if (d.detected) recovery_until_ = std::max(recovery_until_, t + kRecoveryWindow);
  d.recovering = t < recovery_until_ - kEventTol;
  job->horizon = d.recovering ? recovery_horizon() : horizon_;
  const double end = horizon_end(reference_timeline_, t, job->horizon);
  job->end = end;
  job->to_goal = end >= T - kEventTol;
  if (!job->to_goal) job->timeline = truncated_timeline(job->timeline, end - t);

  // A horizon's end is pinned to the reference as the problem is built, so that the rows of
  // every constraint set see it as fixed (built after, the path-shape rows on it were constants).
  // The feet and their forces are held there too (the reference's), so that the next step's
  // guess, this plan and then the reference, agrees with itself across the splice (a stance
  // spanning it has one foothold variable, a knot one force: free, they cost the horizon-end
  // moves 7-11 iterations instead of 3, docs/design.md §6.7). A step that fails so is solved again
  // with the end's feet and forces free: after a push the recovery may need others.
  job->pinned_end = start_state_of(reference_, end);
  // Its forces there: those just before the end (the end is a contact switch; a foot touching
  // down at it has no force variable at the end knot).
  for (const auto& f : interpolate_plan(reference_, end - kEventTol).feet)
    job->pinned_end.foot_force.push_back(f.contact ? f.force : Eigen::Vector3d::Zero());
  // A measured state ahead of the reference may return to it (monotone_progress).
  job->problem_options = options_;
  set_start_lead_of(reference_, t, measured, &job->problem_options);
  job->base_end = job->pinned_end;
  job->base_end.foot_position.clear();
  job->base_end.foot_velocity.clear();
  job->base_end.foot_force.clear();
  // A capture step's foothold, or a swing the hold skipped, is not the reference's at the end.
  if (job->capture.foot >= 0 || job->skipped_swing) job->pinned_end = job->base_end;
  job->warm_from_late = std::exchange(adopted_late_, false);
  job->guess = spliced_guess(previous_, previous_start_, reference_);
  job->bridge_span = bridge_span_of(*job);
  job->solver_options = options_;
  if (limits.should_stop) job->solver_options.should_stop = limits.should_stop;
  if (limits.max_time > 0.0) job->solver_options.max_time = limits.max_time;
  // With a budget the solve may run on past the step's answer, up to four budgets in all, for a late
  // plan the next step can start from; the next step's job cancels it sooner.
  if (limits.budget > 0.0) {
    const double cap = 4.0 * limits.budget;
    const double& m = job->solver_options.max_time;
    job->solver_options.max_time = m > 0.0 ? std::min(m, cap) : cap;
  }
  return job;
}

SessionStep PlanningSession::step(const SrbdProblem::StartState& measured, double t,
                                  const StepLimits& limits) {
  SessionStep out = answer_step(measured, t, limits);
  out.disturbance = last_disturbance_;
  if (out.disturbance.detected || out.disturbance.recovering)
    out.outcome.trajectory.extra["session"]["disturbance"] = disturbance_json(out.disturbance);
  return out;
}

SessionStep PlanningSession::answer_step(const SrbdProblem::StartState& measured, double t,
                                         const StepLimits& limits) {
  const auto t0 = Clock::now();
  if (!(limits.budget >= 0.0) || !(limits.reserve >= 0.0) || !std::isfinite(limits.budget))
    throw RequestError("budget", "must be a finite number of seconds >= 0 (0 = none)");
  adopt_late_solve();
  const std::shared_ptr<StepJob> job = prepare(measured, t, limits);
  last_disturbance_ = job->disturbance;
  ++steps_;
  SessionStep out;
  if (limits.budget > 0.0) {
    if (!worker_) worker_ = std::make_unique<StepWorker>();
    // The step answers its own measured lateness early (how long after its answer was due it
    // returned, a decaying maximum: on a loaded machine the scheduler's), as well as the
    // caller's reserve, but gives the solve at least 40 % of the budget.
    const double answer_in =
        std::max(0.4 * limits.budget, limits.budget - limits.reserve - late_s_);
    worker_->submit(job);
    // The fallback is made while the solve runs (the other core), so that at the deadline the
    // step only has to return: on a loaded machine even a millisecond of work at the deadline
    // becomes several.
    out = fallback_step(*job, "deadline", "");
    const Clock::time_point due =
        t0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(answer_in));
    if (!worker_->wait(*job, due)) {
      std::ostringstream m;
      m << "the re-plan from t = " << t << " s had not finished " << 1e3 * answer_in
        << " ms into its " << 1e3 * limits.budget << " ms budget; the session's current plan "
        << "from t stands (the solve runs on until the next step as its warm start)";
      out.outcome.message = m.str();
      out.outcome.trajectory.extra["session"]["fallback_message"] = out.outcome.message;
      out.wall_s = seconds_since(t0);
      out.answer_late_s = out.wall_s - answer_in;
      late_s_ = std::max(0.9 * late_s_, out.answer_late_s);
      return out;
    }
    if (!job->result.outcome.success) {
      // The fallback made above, its reason and the failed solve's figures set in place.
      out.fallback_reason = "solve_failed";
      out.outcome.message = job->result.outcome.message;
      auto& session_json = out.outcome.trajectory.extra["session"];
      session_json["fallback_reason"] = out.fallback_reason;
      session_json["fallback_message"] = out.outcome.message;
      out.outcome.solve = job->result.outcome.solve;
      out.outcome.trajectory.solver.iterations = job->result.outcome.solve.iterations;
      out.outcome.trajectory.solver.wall_s = job->result.outcome.solve.wall_s;
      out.wall_s = seconds_since(t0);
      out.answer_late_s = out.wall_s - answer_in;
      return out;
    }
    out = std::move(job->result);
    out.answer_late_s = seconds_since(t0) - answer_in;
  } else if (limits.iterations > 0) {
    out = step_with_iteration_budget(job, limits.iterations);
    out.wall_s = seconds_since(t0);
    if (out.fallback) return out;
  } else {
    if (worker_) worker_->cancel_all();
    run_job(*job);
    out = std::move(job->result);
  }
  if (out.outcome.success) {
    previous_ = out.outcome.trajectory;
    previous_start_ = t;
  }
  out.wall_s = seconds_since(t0);
  return out;
}

PhaseTimeline PlanningSession::schedule_from(double t) const {
  PhaseTimeline reference = reference_timeline_.cropped(t);
  const double prev_end = previous_start_ + previous_.duration;
  if (!(t >= previous_start_ && t < prev_end - kEventTol) || !previous_.extra.contains("timeline"))
    return reference;
  PhaseTimeline carried = timeline_of(previous_).cropped(t - previous_start_);
  if (same_schedule(carried, reference, prev_end - t)) return reference;
  // The adapted schedule up to the last plan's end (an event of the reference's), then the
  // reference's.
  if (prev_end < reference_timeline_.duration() - kEventTol) {
    const PhaseTimeline rest = reference_timeline_.cropped(prev_end);
    for (int j = 0; j < rest.num_intervals(); ++j) {
      carried.events.push_back(prev_end - t + rest.events[j + 1]);
      for (std::size_t f = 0; f < carried.feet.size(); ++f)
        carried.contact[f].push_back(rest.contact[f][j]);
    }
  }
  return carried;
}

double PlanningSession::recovery_horizon() const {
  return horizon_ > 0.0 ? std::max(horizon_, kRecoveryHorizon) : 0.0;
}

}  // namespace terrastride::planner
