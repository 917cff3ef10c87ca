// "monotone_progress" (in "all", on when `monotone_progress` = 1): the base never moves
// back along the line from its start to its goal. A zero-objective solve takes the first feasible
// point, and on the pallets that point stepped the base back 28-78 mm (the demo 70 mm) to make
// room for a foot; a robot engineer reads a walk to a goal ahead that backs up as a fault.
// The base position is a cubic Hermite spline, i.e. per segment of duration h the Bezier curve
// with control points P0 = x0, P1 = x0 + h v0 / 3, P2 = x1 - h v1 / 3, P3 = x1. Its derivative is
// the quadratic Bezier curve with control points 3 (P1 - P0) / h, 3 (P2 - P1) / h, 3 (P3 - P2) / h,
// which lies in their convex hull; so when the three differences are >= 0 along the line's
// direction d, the progress d . r(t) is non-decreasing at every instant, not only at the knots:
//   d . v_k >= 0 at every knot (m/s; P1 - P0 and P3 - P2 are h v / 3), and per segment
//   d . (x1 - x0) - h d . (v0 + v1) / 3 >= 0 (m; P2 - P1).
// With fixed timing (the default) every row is linear in the variables; with optimised timing the
// segment rows are bilinear in h and the velocities. Rows on fixed variables only (a start at rest
// or from a measured state, whose velocity may well point back) are left out: no solve can change
// them. No rows when the goal is within 1 cm of the start (no direction).
// A re-plan from a measured state ahead of the motion it re-plans (ProblemOptions::start_lead > 0,
// along the line) may give that lead back: the velocity control points of the segments that
// start within kLeadReturn of the start are bounded by -u instead of 0, u = lead / the end time
// of the last such segment, so the base moves back at most the lead (fixed timing), and never
// behind the motion's own progress. Why: a planning session's steps from states 1 cm aside and
// 0.05 m/s faster than the plan (bench_scenarios' pallet_15 sessions) crept ahead of the
// reference by 3-12 cm; never allowed back, the base had to stand still for the whole 2 s
// horizon (every knot's progress row active) to meet the horizon's end pinned to the reference,
// with its hind legs stretched behind it until joints and range_of_motion failed at the start
// (7 of 20 steps failed with the three path-shape families on, 0 without them). A start on the
// plan (every cold plan, a re-plan from the plan's own state) has no lead: rows as before.
#include <cmath>
#include <stdexcept>
#include <vector>

#include "base_line.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {
// How long (s) a re-plan starting ahead of its motion may take to give its lead back.
// 1 s: with 0.5 s, 5 (to the goal) and 7 (2 s horizon) of 20 pallet_15 session steps failed with
// the three families on main 01d9a91, with 1 s 3 and 4, with 2 s 3 and 4.
constexpr double kLeadReturn = 1.0;
}  // namespace

void build_monotone_progress_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  if (options.monotone_progress == 0) return;
  if (!path_shape_applies(problem, options)) return;
  const Layout& L = problem.layout();
  const BaseLine line = base_line_of(problem);
  if (!line.defined) return;
  const auto& lo = problem.lower();
  const auto& hi = problem.upper();
  const Eigen::Vector2d d = line.along;
  auto free_velocity = [&](int k) {
    const int v = L.base[k] + 3;
    return !all_fixed({v, v + 1}, lo, hi);
  };
  const double lead = problem.options().start_lead;
  if (!(lead >= 0.0) || !std::isfinite(lead))
    throw std::invalid_argument("start_lead must be a finite distance >= 0 m");
  // The segments that start before kLeadReturn give the lead back at up to u (m/s).
  int lead_segments = 0;
  while (lead > 0.0 && lead_segments < L.num_segments &&
         L.nominal_knot_time[lead_segments] < kLeadReturn)
    ++lead_segments;
  const double u = lead_segments > 0 ? lead / L.nominal_knot_time[lead_segments] : 0.0;
  for (int s = 0; s < L.num_segments; ++s) {
    const double us = s < lead_segments ? u : 0.0;         // the segment's middle row
    const double u_end = s + 1 < lead_segments ? u : 0.0;  // its end knot's velocity
    const bool start_row = s == 0 && free_velocity(0), end_row = free_velocity(s + 1);
    const int p0 = L.base[s], v0 = L.base[s] + 3, p1 = L.base[s + 1], v1 = L.base[s + 1] + 3;
    const bool middle_row = !fixed_control_point({p0, p0 + 1, p1, p1 + 1}, {v0, v0 + 1, v1, v1 + 1},
                                                 L.interval_var[L.seg_interval[s]], lo, hi);
    if (!start_row && !middle_row && !end_row) continue;
    LocalVars lv;
    const int x0[2] = {lv.add(p0), lv.add(p0 + 1)}, w0[2] = {lv.add(v0), lv.add(v0 + 1)};
    const int x1[2] = {lv.add(p1), lv.add(p1 + 1)}, w1[2] = {lv.add(v1), lv.add(v1 + 1)};
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    const int rows = start_row + middle_row + end_row;
    std::vector<double> lower;
    if (start_row) lower.push_back(-us);
    if (middle_row) lower.push_back(0.0);
    if (end_row) lower.push_back(-u_end);
    problem.add_piece(make_piece("monotone_progress", lv, lower, std::vector<double>(rows, kInf),
                                 [=](const auto* x, auto* g) {
                                   using T = std::decay_t<decltype(*g)>;
                                   const T h = x[dur] * frac;
                                   const T dv0 = d.x() * x[w0[0]] + d.y() * x[w0[1]];
                                   const T dv1 = d.x() * x[w1[0]] + d.y() * x[w1[1]];
                                   int r = 0;
                                   if (start_row) g[r++] = dv0;
                                   // d . (P2 - P1) + h us / 3 >= 0: the middle velocity
                                   // control point 3 (P2 - P1) / h >= -us.
                                   if (middle_row)
                                     g[r++] = d.x() * (x[x1[0]] - x[x0[0]]) +
                                              d.y() * (x[x1[1]] - x[x0[1]]) -
                                              h * (dv0 + dv1) / 3.0 + h * us / 3.0;
                                   if (end_row) g[r++] = dv1;
                                 }));
  }
}

}  // namespace terrastride::planner
