// The straight line the base path is shaped along (monotone_progress, lateral_corridor, the
// objective's nominal pose): ProblemOptions' path line when set (a re-plan of a motion: that
// motion's line), else the plan's own start-to-goal line as the cold initial guess draws it
// (initialization/base_guess.cpp: the base's first and last knots).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct BaseLine {
  bool defined = false;       // false when the goal is within 1 cm of the start: no direction
  Eigen::Vector2d origin{0, 0};  // the start's (x, y)
  Eigen::Vector2d along{0, 0};   // unit, start -> goal
  Eigen::Vector2d across{0, 0};  // unit, along turned +90 degrees
};

// From the options' path line or the guess (SrbdProblem::initial_guess() before any warm start
// overwrites it).
inline BaseLine base_line_of(SrbdProblem& problem) {
  BaseLine line;
  const ProblemOptions& o = problem.options();
  Eigen::Vector2d end;
  if (o.has_path_line) {
    line.origin = o.path_line_start;
    end = o.path_line_end;
  } else {
    const Layout& L = problem.layout();
    const std::vector<double>& guess = problem.initial_guess();
    const int b0 = L.base[0], bS = L.base[L.num_segments];
    line.origin = Eigen::Vector2d(guess[b0], guess[b0 + 1]);
    end = Eigen::Vector2d(guess[bS], guess[bS + 1]);
  }
  const Eigen::Vector2d d = end - line.origin;
  if (!(d.norm() >= 0.01)) return line;
  line.defined = true;
  line.along = d.normalized();
  line.across = Eigen::Vector2d(-line.along.y(), line.along.x());
  return line;
}

// Whether the path-shape families (monotone_progress, lateral_corridor, swing_apex) shape this
// problem: a plan from rest always; a problem from a given start state (a re-plan) only with
// `replan_path_shape` = 1. The rows are preferences on the shape of a cold plan; a re-plan follows
// a plan that has that shape already, pinned at its end, and its measured start may lie ahead of or
// beside it, where rows shaped for the cold plan cannot hold. Measured (see
// docs/results/2026-11-28-measurements.md): pallet_15 sessions with the families on failed 3 (to
// the goal) and 6 (2 s horizon) of 20 steps with them in every step, 0 and 0 with them in the
// reference only.
inline bool path_shape_applies(const SrbdProblem& problem, const FeasibilityOptions& options) {
  return problem.starts_at_rest() || options.replan_path_shape != 0;
}

// Whether every variable of `vars` is fixed (equal bounds): a row on them alone is a constant,
// which no solve can change (e.g. the start knot of a plan from rest or from a measured state).
inline bool all_fixed(const std::vector<int>& vars, const std::vector<double>& lower,
                      const std::vector<double>& upper) {
  for (int v : vars)
    if (lower[v] < upper[v]) return false;
  return true;
}

// Whether p + c h v (a Bezier control point: p and v knot values and rates, h the segment's
// duration variable `duration`, c a constant) is a constant: p and v fixed, and h fixed or v fixed
// at zero (a knot at rest: then the point is the knot, whatever the duration).
inline bool fixed_control_point(const std::vector<int>& p, const std::vector<int>& v, int duration,
                                const std::vector<double>& lower,
                                const std::vector<double>& upper) {
  if (!all_fixed(p, lower, upper) || !all_fixed(v, lower, upper)) return false;
  if (lower[duration] == upper[duration]) return true;
  for (int i : v)
    if (lower[i] != 0.0) return false;
  return true;
}

}  // namespace terrastride::planner
