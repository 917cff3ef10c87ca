// The planner's settings, in two parts (as ifopt and Ceres keep them apart): what problem to build
// (ProblemOptions: the motion asked for, its discretisation, the physical limits and the constraint
// sets) and how to solve it (SolverOptions: time and iteration limits, tolerances, cancellation).
// SrbdProblem sees only the first, solve() only the second. PlannerOptions is both, so that a
// caller fills one object (po.gait, po.max_time, ...) and hands it to plan_motion.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace terrastride::planner {

struct ProblemOptions {
  // ---- The motion asked for ----
  std::string gait = "crawl";
  int cycles = 3;
  double duration = 0.0;  // <= 0: gait default
  bool has_goal = false;
  Eigen::Vector3d goal = Eigen::Vector3d::Zero();   // x, y, yaw
  Eigen::Vector3d start = Eigen::Vector3d::Zero();  // x, y, yaw
  bool optimize_timing = false;
  double interval_min_scale = 0.5, interval_max_scale = 2.0;  // bounds on interval durations
  double min_interval = 0.04;                                 // s

  // ---- Discretisation: segments and the constraint points in them (see nlp.hpp) ----
  double segment_dt = 0.1;
  int angular_points = 3;    // angular dynamics points per segment
  int rom_points = 2;        // range-of-motion points per segment
  int clearance_points = 4;  // swing-clearance points per segment

  // ---- Physical limits and margins of the baseline constraints ----
  double friction = 0.5;
  double max_normal_force_factor = 2.0;  // f_max = factor * m * g
  double swing_clearance = 0.05;         // h_min (m)
  double clearance_probe = 0.05;         // terrain probed this far around a swing foot (m)
  // The clearance demanded of a swing foot rises from 0 at lift-off to h_min over this time (s),
  // smoothly (sin^2), and falls likewise before touch-down; a swing shorter than twice this
  // spends all of it rising and falling. A ramp in time rather than in swing fraction keeps the
  // foot acceleration it implies bounded on short swings (2 h_min pi^2 / (2 ramp)^2).
  double clearance_ramp = 0.1;
  // Footholds where the terrain is planar within clearance_probe (to this tolerance, m): a foot
  // lifting off at the foot of a step would otherwise cut its corner between constraint points.
  double foothold_planarity = 0.01;
  // Angular dynamics hold exactly at the segment ends and within +-angular_band (N m, per axis) at
  // the interior points. At the ends of a segment the residual is zero, so at an interior point
  // it is second order in the segment length, and that row's Jacobian nearly equals the average
  // of the end rows' (the forces enter linearly). Demanding it exactly made Ipopt take steps of
  // O(residual / h^2) that the fraction-to-boundary rule cut to 2-10 % for the first 5 iterations
  // (flat 2.4 s crawl: 8-10 iterations over 15 nearby goals and durations; with the band, 3-5).
  // 0.5 N m is 5 % of the dense angular-residual target.
  double angular_band = 0.5;

  // ---- Constraint sets (`--constraints`; constraint_set_names()) ----
  std::vector<std::string> constraints{"baseline"};
  // NAME=VALUE settings of the constraint sets' FeasibilityOptions (feasibility.hpp), applied in
  // order over the defaults; feasibility_options() validates them.
  std::vector<std::pair<std::string, double>> feasibility_settings;
};

struct SolverOptions {
  double max_time = 0.0;  // s per solve, 0 = none
  // Polled once per solver iteration; returning true stops the solve (status "stopped"). The
  // socket service uses it to cancel a plan request. Must be cheap and thread-safe.
  std::function<bool()> should_stop;
  int max_iterations = 3000;
  // The solve stops with status "stalled" when the largest constraint violation has not fallen
  // 1 % below its best for this many iterations (0 = never). An unreachable request otherwise
  // runs to max_iterations: the 1 m flat crawl in 1.6 s with "polytope" reached its least
  // violation (5e-3) at iteration 560 and then wandered in and out of restoration for 2400 more
  // (62 s). Every solvable scenario measured converges in under 20 iterations.
  int stall_iterations = 200;
  bool verbose = false;
  double tolerance = 1e-4;
  // The solve stops at the first iterate whose largest constraint or bound violation (rows in
  // their scaled units: forces / m g, lengths in m) is at most this; 0 = wait for Ipopt's own
  // convergence test, which also converges the multipliers.
  double feasibility_stop_tolerance = 1e-6;
};

// Both parts in one object: every field is reachable by its own name (options.gait,
// options.max_time), and the object converts to either part.
struct PlannerOptions : ProblemOptions, SolverOptions {};

}  // namespace terrastride::planner
