// A re-plan from a measured state that already lies outside a row's bound (issue #22: after a push
// a joint 0.08-0.38 rad past its range, a foot 8 cm outside its range-of-motion box). Its knot 0
// is pinned to the measurement, so the rows there are constants; SrbdProblem::add_piece leaves the
// violated ones out and reports them. The same family's rows at the next knots would still ask for
// an instant recovery (a joint back within its range 0.03-0.1 s later), so they get room: the
// start's excess e over the bound, shrinking linearly to nothing over the start-return span,
// bound + e max(0, 1 - t / span) at nominal time t (as lateral_corridor.cpp's return into its
// corridor). A start within the bounds has e = 0: rows as before, so do cold plans.
#pragma once

#include <algorithm>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// The weight of the start's excess at nominal time t of a re-plan: 1 at the start, 0 from `span`.
inline double start_return_weight(double t, double span) {
  if (!(span > 0.0)) return 0.0;
  return std::max(0.0, 1.0 - t / span);
}

// Whether every variable of `vars` is fixed in `problem` and the problem starts from a given
// state (only a re-plan from a measured state gets room).
inline bool fixed_measured_start(const SrbdProblem& problem, const std::vector<int>& vars) {
  if (problem.starts_at_rest()) return false;
  for (int v : vars)
    if (v < 0 || problem.lower()[v] < problem.upper()[v]) return false;
  return true;
}

// The nominal time of the point at fraction sigma of segment s.
inline double nominal_point_time(const Layout& L, int s, double sigma) {
  return L.nominal_knot_time[s] + sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]);
}

}  // namespace terrastride::planner
