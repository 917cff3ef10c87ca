// The planner's settings, in two parts (as ifopt and Ceres keep them apart): what problem to build
// (ProblemOptions: the motion asked for, its discretisation, the physical limits and the constraint
// sets) and how to solve it (SolverOptions: time and iteration limits, tolerances, cancellation).
// SrbdProblem sees only the first, solve() only the second. PlannerOptions is both, so that a
// caller fills one object (po.gait, po.max_time, ...) and hands it to plan_motion.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

namespace terrastride::planner {

// The terms of the objective and their weights (each term is dimensionless; see
// planner/src/costs/). Every term is a sum of squares, integrated over the plan's time. The
// defaults here are the tuned weights; ProblemOptions::objective starts from none().
struct ObjectiveWeights {
  double base_acceleration = 1.0;          // integral of |r''/g|^2
  double base_angular_acceleration = 0.1;  // integral of |e''|^2 (rad/s^2)^2
  double force_rate = 0.01;                // integral of |f'/(m g)|^2 over stances
  double swing_acceleration = 0.01;        // integral of |p''/g|^2 over swings
  double body_height = 1.0;                // integral of ((z - z_nominal) / 0.05 m)^2 / T
  double heading = 1.0;                    // integral of |(yaw, pitch, roll) - nominal|^2 (rad) / T
  double lateral = 1.0;                    // integral of (lateral offset / 0.05 m)^2 / T
  double progress = 0.1;  // integral of (offset along the line from the nominal / 0.05 m)^2 / T
  double base_jerk = 0.01;  // integral of |jerk/g|^2, knot jumps of the acceleration included
  // Every weight zero: the feasibility problem of the original design.
  static ObjectiveWeights none() {
    ObjectiveWeights w;
    w.scale(0.0);
    return w;
  }
  void scale(double k) {
    for (double* v : {&base_acceleration, &base_angular_acceleration, &force_rate,
                      &swing_acceleration, &body_height, &heading, &lateral, &progress, &base_jerk})
      *v *= k;
  }
  bool any() const {
    return base_acceleration > 0 || base_angular_acceleration > 0 || force_rate > 0 ||
           swing_acceleration > 0 || body_height > 0 || heading > 0 || lateral > 0 ||
           progress > 0 || base_jerk > 0;
  }
};

// The constraint sets of a plan request that names none (`terrastride plan`, the socket's `plan`
// and `plan.session.open`, the demo): every feasibility set, so a plan made with the defaults
// keeps the hardware-feasibility promise (`baseline` alone leaves joint ranges, torques and leg
// collisions to the post-hoc checks: pallet_10's plan has 74 samples outside a joint range, flat
// ground's a hind HFE past its range). `--constraints baseline` gives the paper's comparison.
inline const std::vector<std::string> kDefaultRequestConstraints{"all"};

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
  // The library's default is the paper's formulation ("baseline"), which callers extend set by
  // set (the Jacobian tests, the paper's comparisons, the benchmarks); a plan request that names
  // no sets gets kDefaultRequestConstraints instead.
  std::vector<std::string> constraints{"baseline"};
  // NAME=VALUE settings of the constraint sets' FeasibilityOptions (feasibility.hpp), applied in
  // order over the defaults; feasibility_options() validates them.
  std::vector<std::pair<std::string, double>> feasibility_settings;
  // The straight line the base path is shaped along (monotone_progress, lateral_corridor and the
  // objective's lateral/progress terms): (x, y) of its start and of its end. Unset:
  // the plan's own start-to-goal line (its cold guess's first and last base knots). A re-plan of
  // a motion sets it to the motion's line (planning sessions, warm re-plans: the plan they
  // continue, from its first base position to its goal), so every step follows one line; drawn
  // from each measured start instead, the corridor moved with the robot's tracking error.
  bool has_path_line = false;
  Eigen::Vector2d path_line_start = Eigen::Vector2d::Zero();
  Eigen::Vector2d path_line_end = Eigen::Vector2d::Zero();
  // How far (m) a re-plan's start lies ahead, along the path line, of the motion it re-plans at
  // that time (a measured state ahead of the plan; set_start_lead_of). monotone_progress lets the
  // base give back at most this much over its first second, so that a re-plan pushed ahead can
  // return to its motion (a session's pinned horizon end, the stances it planned) instead of
  // standing still ahead of its feet. 0 (cold plans, starts on the plan): never back.
  double start_lead = 0.0;

  // ---- Boundary conditions and the objective ----
  // A plan that starts from rest (no start state given: the nominal stance) and every plan's end
  // (velocities zero there already) also has zero base linear and Euler accelerations there, so
  // the forces balance gravity at both ends (constraints/rest_boundary.cpp). A re-plan from a
  // state keeps that state's motion: its start is not constrained beyond the state itself.
  bool rest_boundaries = true;
  // The objective's weights (planner/src/costs/); 0 leaves a term out, all 0 (the default) gives
  // the zero-objective feasibility problem of the original design. ObjectiveWeights{} are the
  // tuned weights. Off by default because the optimum lies on the constraints'
  // boundaries, which hold at the constraint points only: on pallet_15 "all" the HyQ shin capsule
  // then touched the pallet edge between knots (7 samples, -10.8 mm, post-hoc check), where the
  // feasibility point kept 1.8 mm. The shin_ik margin (or its points) must cover that first.
  ObjectiveWeights objective = ObjectiveWeights::none();
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
  // With an objective (ObjectiveWeights) the solve has two phases (solver.cpp): the feasibility
  // phase with a zero objective, stopping at its first verified feasible point as without one,
  // then at most objective_max_iterations (0 = none) of improvement from there, which end at a
  // verified feasible iterate whose objective fell by at most objective_stop_tolerance (relative)
  // since the previous, also feasible, iterate: feasible and good enough.
  double objective_stop_tolerance = 0.01;
  int objective_max_iterations = 40;
  // The improvement phase judges iterates whose largest violation is at most this (rows' units);
  // the polish then takes the best of them to feasibility_stop_tolerance (solver.cpp, improve()).
  double objective_near_feasible_tolerance = 1e-3;
  // Stop at the first verified feasible iterate even with an objective (plan_motion sets it for
  // warm starts: the previous plan was optimised already, and a start on it re-verifies in 0
  // iterations).
  bool stop_at_first_feasible = false;
  // plan_motion's joint-point refinement (planner.cpp), for problems with "joints" or "polytope"
  // rows: after a successful solve a dense check (dense_joint_check) looks for joints beyond their
  // ranges, velocity or torque limits between the constraint points; where it finds some, the
  // problem gets joint or polytope rows at the worst instants and is solved again from the
  // solution, at most this many times.
  // 0: never. Planning-session steps call solve() and never refine (they have a deadline).
  int joint_refinement_rounds = 3;
};

// Both parts in one object: every field is reachable by its own name (options.gait,
// options.max_time), and the object converts to either part.
struct PlannerOptions : ProblemOptions, SolverOptions {};

}  // namespace terrastride::planner
