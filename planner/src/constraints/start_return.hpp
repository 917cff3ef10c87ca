// A re-plan from a measured state that already lies outside a row's bound (issue #22: after a push
// a joint 0.08-0.38 rad past its range, a foot 8 cm outside its range-of-motion box). Its knot 0
// is pinned to the measurement, so the rows there are constants; SrbdProblem::add_piece leaves the
// violated ones out and reports them. The same family's rows at the next knots would still ask for
// an instant recovery (a joint back within its range 0.03-0.1 s later), so they get room: the
// start's excess e over the bound, shrinking linearly to nothing over the start-return span,
// bound + e max(0, 1 - t / span) at nominal time t (as lateral_corridor.cpp's return into its
// corridor). A start within the bounds has e = 0: rows as before, so do cold plans.
#pragma once

#include <Eigen/Core>
#include <algorithm>

#include "base_line.hpp"  // all_fixed
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// The weight of the start's excess at nominal time t of a re-plan: 1 at the start, 0 from `span`.
inline double start_return_weight(double t, double span) {
  if (!(span > 0.0)) return 0.0;
  return std::max(0.0, 1.0 - t / span);
}

// A re-plan's measured start as the rows after it see it: the base position and Euler angles at
// knot 0 and foot f's position there.
struct MeasuredFootPose {
  Eigen::Vector3d base, euler, foot;
};

// Foot f's measured start pose, when the problem starts from a given state (only a re-plan from a
// measured state gets room) and pins all of it; false otherwise (a cold plan, a foot whose
// position at knot 0 is free).
inline bool measured_foot_pose(const SrbdProblem& problem, int f, MeasuredFootPose* pose) {
  if (problem.starts_at_rest()) return false;
  const Layout& L = problem.layout();
  const int b = L.base[0], p = L.foot_pos[f][0];
  if (p < 0) return false;
  const auto& x = problem.lower();
  if (!all_fixed({b, b + 1, b + 2, b + 6, b + 7, b + 8, p, p + 1, p + 2}, x, problem.upper()))
    return false;
  pose->base = Eigen::Vector3d(x[b], x[b + 1], x[b + 2]);
  pose->euler = Eigen::Vector3d(x[b + 6], x[b + 7], x[b + 8]);
  pose->foot = Eigen::Vector3d(x[p], x[p + 1], x[p + 2]);
  return true;
}

// The nominal time of the point at fraction sigma of segment s.
inline double nominal_point_time(const Layout& L, int s, double sigma) {
  return L.nominal_knot_time[s] + sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]);
}

}  // namespace terrastride::planner
