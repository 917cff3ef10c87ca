// The straight line from the plan's start to its goal in the horizontal plane, as the cold initial
// guess draws it (initialization/base_guess.cpp: the base's first and last knots), for the
// families that shape the base path along it (monotone_progress, lateral_corridor).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "terrastride/planner/layout.hpp"

namespace terrastride::planner {

struct BaseLine {
  bool defined = false;       // false when the goal is within 1 cm of the start: no direction
  Eigen::Vector2d origin{0, 0};  // the start's (x, y)
  Eigen::Vector2d along{0, 0};   // unit, start -> goal
  Eigen::Vector2d across{0, 0};  // unit, along turned +90 degrees
};

// From the guess (SrbdProblem::initial_guess() before any warm start overwrites it).
inline BaseLine base_line_of(const Layout& L, const std::vector<double>& guess) {
  BaseLine line;
  const int b0 = L.base[0], bS = L.base[L.num_segments];
  line.origin = Eigen::Vector2d(guess[b0], guess[b0 + 1]);
  const Eigen::Vector2d d = Eigen::Vector2d(guess[bS], guess[bS + 1]) - line.origin;
  if (d.norm() < 0.01) return line;
  line.defined = true;
  line.along = d.normalized();
  line.across = Eigen::Vector2d(-line.along.y(), line.along.x());
  return line;
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
