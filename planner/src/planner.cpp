#include "terrastride/planner/planner.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/reachability.hpp"
#include "terrastride/planner/request_limits.hpp"

namespace terrastride::planner {

namespace {

constexpr double kDenseDt = 0.002;  // DESIGN.md: dense checks every 2 ms

Eigen::Matrix3d euler_rate_matrix(const Eigen::Vector3d& e) {
  const double cy = std::cos(e[0]), sy = std::sin(e[0]), cp = std::cos(e[1]), sp = std::sin(e[1]);
  Eigen::Matrix3d E;
  E << 0, -sy, cy * cp, 0, cy, sy * cp, 1, 0, -sp;
  return E;
}

}  // namespace

Eigen::Vector3d euler_rates_of(const Eigen::Vector3d& euler_zyx,
                               const Eigen::Vector3d& angular_velocity) {
  return euler_rate_matrix(euler_zyx).fullPivLu().solve(angular_velocity);
}

namespace {

// The Euler-angle rates of a sample (from its angular velocity).
Eigen::Vector3d euler_rates(const TrajectorySample& s) {
  return euler_rates_of(s.base.euler_zyx, s.base.angular_velocity);
}

nlohmann::json timeline_json(const PhaseTimeline& tl, const std::vector<double>& events) {
  nlohmann::json c = nlohmann::json::array();
  for (const auto& foot : tl.contact) c.push_back(foot);
  nlohmann::json j = {{"events", events}, {"contact", c}};
  // Scaled like the first interval when the timing was optimised.
  if (tl.first_interval_elapsed > 0.0 && tl.num_intervals() > 0)
    j["first_interval_elapsed"] =
        tl.first_interval_elapsed * (events[1] - events[0]) / (tl.events[1] - tl.events[0]);
  bool swinging = false;
  for (double e : tl.swing_elapsed) swinging |= e > 0.0;
  if (swinging) j["swing_elapsed"] = tl.swing_elapsed;  // nominal times, as the clearance uses
  return j;
}

}  // namespace

Trajectory sample_solution(const SrbdProblem& problem, const std::vector<double>& x, double dt) {
  Trajectory tr;
  const auto& robot = problem.robot();
  tr.robot = robot.name;
  tr.gait = problem.options().gait;
  tr.duration = problem.duration(x);
  tr.sample_dt = dt;
  for (const auto& leg : robot.legs) tr.feet.push_back(leg.name);
  const int n = static_cast<int>(std::floor(tr.duration / dt + 1e-9));
  for (int i = 0; i <= n + 1; ++i) {
    double t = std::min(i * dt, tr.duration);
    if (i == n + 1 && tr.duration - n * dt < 1e-9) break;
    const auto st = problem.evaluate(x, t);
    TrajectorySample s;
    s.t = t;
    s.base.position = st.pos;
    s.base.euler_zyx = st.euler;
    s.base.linear_velocity = st.vel;
    s.base.linear_acceleration = st.acc;
    euler_to_angular<double>(st.euler, st.euler_rate, st.euler_acc, &s.base.angular_velocity,
                             &s.base.angular_acceleration);
    for (std::size_t f = 0; f < st.foot_pos.size(); ++f) {
      FootState fs;
      fs.position = st.foot_pos[f];
      fs.velocity = st.foot_vel[f];
      fs.force = st.force[f];
      fs.contact = st.contact[f];
      s.feet.push_back(fs);
    }
    tr.samples.push_back(std::move(s));
  }
  // Phases per foot, at the solution's (possibly optimised) event times.
  const auto ev = problem.event_times(x);
  const auto& tl = problem.timeline();
  nlohmann::json phases = nlohmann::json::object();
  for (std::size_t f = 0; f < tl.feet.size(); ++f) {
    nlohmann::json list = nlohmann::json::array();
    for (int j = 0; j < tl.num_intervals(); ++j) {
      const bool c = tl.contact[f][j];
      if (!list.empty() && list.back()["contact"].get<bool>() == c)
        list.back()["end"] = ev[j + 1];
      else
        list.push_back({{"start", ev[j]}, {"end", ev[j + 1]}, {"contact", c}});
    }
    phases[tl.feet[f]] = list;
  }
  tr.extra["phases"] = phases;
  tr.extra["timeline"] = timeline_json(tl, ev);
  return tr;
}

namespace {

// The state at t on the cubic through samples a and b (t may lie outside [a.t, b.t]): positions
// and their rates by cubic Hermite interpolation with the samples' velocities, exact when both
// samples lie on one cubic spline segment (the planner's splines are cubic); accelerations and
// forces linear (forces are linear within a segment).
TrajectorySample hermite_between(const TrajectorySample& a, const TrajectorySample& b, double t) {
  const double h = b.t - a.t;
  const double u = (t - a.t) / std::max(1e-12, h);
  TrajectorySample s = a;
  s.t = t;
  auto mix = [u](const Eigen::Vector3d& p, const Eigen::Vector3d& q) {
    return (1 - u) * p + u * q;
  };
  hermite<double>(u, h, a.base.position, a.base.linear_velocity, b.base.position,
                  b.base.linear_velocity, &s.base.position, &s.base.linear_velocity, nullptr);
  Eigen::Vector3d euler_rate;
  hermite<double>(u, h, a.base.euler_zyx, euler_rates(a), b.base.euler_zyx, euler_rates(b),
                  &s.base.euler_zyx, &euler_rate, nullptr);
  s.base.angular_velocity = euler_rate_matrix(s.base.euler_zyx) * euler_rate;
  s.base.linear_acceleration = mix(a.base.linear_acceleration, b.base.linear_acceleration);
  s.base.angular_acceleration = mix(a.base.angular_acceleration, b.base.angular_acceleration);
  for (std::size_t f = 0; f < s.feet.size() && f < b.feet.size(); ++f) {
    hermite<double>(u, h, a.feet[f].position, a.feet[f].velocity, b.feet[f].position,
                    b.feet[f].velocity, &s.feet[f].position, &s.feet[f].velocity, nullptr);
    // Forces jump at contact switches: blend only inside one contact state.
    if (a.feet[f].contact == b.feet[f].contact)
      s.feet[f].force = mix(a.feet[f].force, b.feet[f].force);
  }
  return s;
}

// The state at t of the plan's spline segment [lo, hi], from the two samples inside it nearest t
// (exact even at the segment's ends, where interpolating across the knot would mix two cubics).
TrajectorySample segment_state(const Trajectory& plan, double t, double lo, double hi) {
  const auto& S = plan.samples;
  if (S.empty()) throw std::invalid_argument("plan has no samples");
  const double tol = 1e-9;
  auto first = std::lower_bound(S.begin(), S.end(), lo - tol,
                                [](const TrajectorySample& s, double v) { return s.t < v; });
  auto last = std::upper_bound(S.begin(), S.end(), hi + tol,
                               [](double v, const TrajectorySample& s) { return v < s.t; });
  if (last - first < 2) return interpolate_plan(plan, t);
  // A sample at the segment's end belongs to the next segment (plans are sampled right-continuous):
  // its forces, contact flags and accelerations are the next segment's, and a foot that lifts off
  // there shows no force. Two samples inside the segment determine its cubics and linear forces,
  // so the end is extrapolated from them when there are two. (Missed before: on the flat 2.4 s
  // crawl, whose switch times fall on the 0.01 s sample grid, a re-plan started 0.1 m g and
  // 30 N m out of balance and ended infeasible; on pallet_15 no switch falls on a sample.)
  if (last - first >= 3 && std::abs((last - 1)->t - hi) <= tol) --last;
  // The pair of samples in [lo, hi] around t (or the end pair when t is at an end).
  auto b =
      std::lower_bound(first, last, t, [](const TrajectorySample& s, double v) { return s.t < v; });
  b = std::clamp(b, first + 1, last - 1);
  return hermite_between(*(b - 1), *b, t);
}

}  // namespace

TrajectorySample interpolate_plan(const Trajectory& plan, double t) {
  const auto& S = plan.samples;
  if (S.empty()) throw std::invalid_argument("plan has no samples");
  if (t <= S.front().t) return S.front();
  if (t >= S.back().t) return S.back();
  const auto it = std::upper_bound(S.begin(), S.end(), t,
                                   [](double v, const TrajectorySample& s) { return v < s.t; });
  return hermite_between(*(it - 1), *it, t);
}

PhaseTimeline timeline_of(const Trajectory& plan) {
  const auto& ex = plan.extra;
  if (!ex.contains("timeline"))
    throw std::invalid_argument("plan has no \"timeline\" (not written by terrastride plan)");
  PhaseTimeline tl;
  tl.feet = plan.feet;
  try {
    tl.events = ex["timeline"]["events"].get<std::vector<double>>();
    for (const auto& c : ex["timeline"]["contact"])
      tl.contact.push_back(c.get<std::vector<bool>>());
    tl.first_interval_elapsed = ex["timeline"].value("first_interval_elapsed", 0.0);
    if (ex["timeline"].contains("swing_elapsed"))
      tl.swing_elapsed = ex["timeline"]["swing_elapsed"].get<std::vector<double>>();
  } catch (const nlohmann::json::exception& e) {
    throw std::invalid_argument(std::string("plan \"timeline\": ") + e.what());
  }
  if (tl.events.size() < 2 || tl.contact.size() != tl.feet.size())
    throw std::invalid_argument("plan \"timeline\": inconsistent sizes");
  // The events span the plan from 0 to its duration: a timeline that does not would have a
  // re-plan build a problem for a different (possibly enormous) horizon than the samples cover.
  for (std::size_t i = 0; i < tl.events.size(); ++i)
    if (!std::isfinite(tl.events[i]) || (i > 0 && !(tl.events[i] > tl.events[i - 1])))
      throw std::invalid_argument("plan \"timeline\": events must be finite and increasing");
  if (std::abs(tl.events.front()) > 1e-9 || std::abs(tl.events.back() - plan.duration) > 1e-6)
    throw std::invalid_argument("plan \"timeline\": events must run from 0 to the duration " +
                                std::to_string(plan.duration) + " s");
  if (!(tl.first_interval_elapsed >= 0.0) || !std::isfinite(tl.first_interval_elapsed))
    throw std::invalid_argument("plan \"timeline\": first_interval_elapsed must be >= 0");
  if (!tl.swing_elapsed.empty() && tl.swing_elapsed.size() != tl.feet.size())
    throw std::invalid_argument("plan \"timeline\": swing_elapsed must have one entry per foot");
  for (double e : tl.swing_elapsed)
    if (!(e >= 0.0) || !std::isfinite(e))
      throw std::invalid_argument("plan \"timeline\": swing_elapsed entries must be >= 0");
  for (const auto& c : tl.contact)
    if (static_cast<int>(c.size()) != tl.num_intervals())
      throw std::invalid_argument(
          "plan \"timeline\": contact lists must have one entry per interval");
  return tl;
}

void SrbdProblem::warm_start_from(const Trajectory& prev, double shift) {
  const Layout& L = layout_;
  const int S = L.num_segments;
  // The previous plan at knot k, from its samples in the segment to the left of the knot (to the
  // right for the first): with aligned knots (PhaseTimeline::first_interval_elapsed) that
  // reproduces the previous splines exactly.
  const auto& kt = L.nominal_knot_time;
  std::vector<TrajectorySample> knot(S + 1);
  for (int k = 0; k <= S; ++k) {
    const int seg = k > 0 ? k - 1 : 0;
    knot[k] = segment_state(prev, kt[k] + shift, kt[seg] + shift, kt[seg + 1] + shift);
  }
  for (int k = 0; k <= S; ++k) {
    const auto& s = knot[k];
    const int b = L.base[k];
    const Eigen::Vector3d rates = euler_rates(s);
    for (int d = 0; d < 3; ++d) {
      auto set = [&](int i, double v) {
        if (variables_.lower[i] < variables_.upper[i])
          variables_.initial[i] = std::clamp(v, variables_.lower[i], variables_.upper[i]);
      };
      set(b + d, s.base.position[d]);
      set(b + 3 + d, s.base.linear_velocity[d]);
      set(b + 6 + d, s.base.euler_zyx[d]);
      set(b + 9 + d, rates[d]);
    }
  }
  const int nf = static_cast<int>(robot_.legs.size());
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k <= S; ++k) {
      const int pv = L.foot_pos[f][k], vv = L.foot_vel[f][k];
      if (pv >= 0 && variables_.lower[pv] < variables_.upper[pv])
        for (int d = 0; d < 3; ++d) variables_.initial[pv + d] = knot[k].feet[f].position[d];
      if (vv >= 0 && variables_.lower[vv] < variables_.upper[vv])
        for (int d = 0; d < 3; ++d) variables_.initial[vv + d] = knot[k].feet[f].velocity[d];
    }
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < S; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0) continue;
        const auto smp =
            segment_state(prev, kt[s + side] + shift, kt[s] + shift, kt[s + 1] + shift);
        if (!smp.feet[f].contact) continue;
        for (int d = 0; d < 3; ++d) variables_.initial[fv + d] = smp.feet[f].force[d];
      }
}

Eigen::Vector3d goal_of(const Trajectory& plan) {
  if (plan.samples.empty()) throw std::invalid_argument("plan has no samples");
  const auto& last = plan.samples.back().base;
  return Eigen::Vector3d(last.position.x(), last.position.y(), last.euler_zyx[0]);
}

SrbdProblem::StartState start_state_of(const Trajectory& plan, double t) {
  return start_state_of(interpolate_plan(plan, t));
}

SrbdProblem::StartState start_state_of(const TrajectorySample& s) {
  SrbdProblem::StartState start;
  start.position = s.base.position;
  start.euler_zyx = s.base.euler_zyx;
  start.linear_velocity = s.base.linear_velocity;
  start.euler_rates = euler_rates(s);
  for (const auto& f : s.feet) {
    start.foot_position.push_back(f.position);
    start.foot_velocity.push_back(f.velocity);
  }
  return start;
}

PlanOutcome plan_motion(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                        const terrain::HeightField& check_terrain, const PlannerOptions& options,
                        double sample_dt, const WarmStart& warm) {
  check_plan_request(options, sample_dt);
  const auto t_start = std::chrono::steady_clock::now();
  auto seconds_since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  PhaseTimeline timeline;
  SrbdProblem::StartState start;
  const SrbdProblem::StartState* start_ptr = nullptr;
  if (warm.previous) {
    const Trajectory& prev = *warm.previous;
    if (prev.feet != feet)
      throw RequestError("init.feet", "the plan's feet differ from robot " + robot.name + "'s");
    check_plan_horizon(prev.duration, "init.duration");
    if (!(warm.shift >= 0.0 && warm.shift < prev.duration))
      throw RequestError("start_time", "must be within [0, " + std::to_string(prev.duration) +
                                           ") s, the duration of the plan it continues");
    timeline = timeline_of(prev);
    if (warm.shift > 0.0) timeline = timeline.cropped(warm.shift);
    if (warm.start) {
      if (warm.start->foot_position.size() != feet.size() ||
          warm.start->foot_velocity.size() != feet.size())
        throw std::invalid_argument(
            "warm-start state has " + std::to_string(warm.start->foot_position.size()) +
            " feet, robot " + robot.name + " has " + std::to_string(feet.size()));
      start = *warm.start;
    } else {
      start = start_state_of(prev, warm.shift);
    }
    start_ptr = &start;
  } else {
    const Gait gait = load_gait(resolve_gait_path(options.gait));
    timeline = make_timeline(gait, feet, options.cycles, options.duration);
    // Without a duration the horizon is the gait's period times its cycles (plus lead-in/out).
    check_plan_horizon(timeline.duration(), options.duration > 0.0 ? "duration" : "cycles");
  }
  SrbdProblem problem(robot, plan_terrain, timeline, options, start_ptr);
  // An unreachable goal stance otherwise costs seconds of iterations before "infeasible".
  const auto t_reach = std::chrono::steady_clock::now();
  require_reachable(problem);
  const double reachability_s = seconds_since(t_reach);
  if (warm.previous) problem.warm_start_from(*warm.previous, warm.shift);
  const double build_s = seconds_since(t_start);
  PlanOutcome out;
  std::vector<std::pair<std::string, std::string>> ipopt_options;
  if (warm.previous) {
    // The shifted previous plan is feasible already when the start lies on it: its knots are
    // kept (PhaseTimeline::first_interval_elapsed) and so are its constraint points
    // (Layout::segment_points), so the check at iteration 0 returns it verified (pallet_15
    // shifted by 0.1, 0.37 or 2.5 s: 0 iterations; by 1 s: 2). Ipopt's defaults would push the
    // slacks 1 % away from their bounds and start the barrier at mu = 0.1; a small barrier and
    // push keep the warm start when it needs iterations. The barrier stays adaptive: a monotone
    // one, from a measured start 1 cm beside the plan and 0.05 m/s faster, ended infeasible after
    // 102 iterations (6.7 s); adaptive: optimal in 3 (offsets of 3 mm to 4 cm: 3-5).
    ipopt_options = {{"mu_init", "1e-4"}, {"bound_push", "1e-5"}, {"bound_frac", "1e-5"}};
  }
  out.solve = solve(problem, options, ipopt_options);
  const auto t_after_solve = std::chrono::steady_clock::now();
  out.success = out.solve.success;
  if (std::getenv("TERRASTRIDE_DEBUG_CHECKS"))
    for (const auto& [k, v] : problem.violation_by_kind(out.solve.x))
      std::fprintf(stderr, "final violation %s %g\n", k.c_str(), v);
  out.trajectory = sample_solution(problem, out.solve.x, sample_dt);
  auto& st = out.trajectory.solver;
  st.status = out.solve.status;
  st.iterations = out.solve.iterations;
  st.wall_s = out.solve.wall_s;
  st.n_variables = problem.num_free_variables();
  st.n_constraints = problem.num_constraints();
  out.trajectory.extra["solver_max_violation"] = out.solve.max_violation;
  out.trajectory.extra["solver_termination"] = out.solve.termination;
  out.trajectory.extra["cycles"] = options.cycles;
  out.trajectory.extra["optimize_timing"] = options.optimize_timing;
  out.trajectory.extra["constraints"] = options.constraints;
  if (!options.feasibility_settings.empty()) {
    nlohmann::json fs = nlohmann::json::object();
    for (const auto& [k, v] : options.feasibility_settings) fs[k] = v;
    out.trajectory.extra["feasibility_settings"] = fs;
  }
  DenseCheckLimits lim;
  lim.friction = options.friction;
  lim.max_normal_force = options.max_normal_force_factor * robot.mass * kGravity;
  const Trajectory dense = sample_solution(problem, out.solve.x, kDenseDt);
  out.trajectory.checks = dense_checks(robot, check_terrain, dense, lim);
  out.trajectory.extra["checks_dt"] = kDenseDt;
  // Where the planner's time went (the solve is solver.wall_s): problem construction (with the
  // reachability check), and the sampling plus dense checks after it.
  out.trajectory.extra["timings"] = {{"build_s", build_s},
                                     {"reachability_check_s", reachability_s},
                                     {"solve_s", out.solve.wall_s},
                                     {"sample_and_checks_s", seconds_since(t_after_solve)},
                                     {"total_s", seconds_since(t_start)}};
  if (!out.success) {
    std::ostringstream m;
    m << "the optimiser ended with status '" << out.solve.status << "' after "
      << out.solve.iterations << " iterations (" << out.solve.wall_s
      << " s); largest constraint violation " << out.solve.max_violation;
    if (out.solve.status == "stalled")
      m << ", no 1 % reduction of it in the last " << options.stall_iterations << " iterations";
    out.message = m.str();
  }
  return out;
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
    fail("goal", reach,
         "must lie within 1000 m of the start (distance from the start in m shown)");
}

}  // namespace terrastride::planner
