// "lateral_corridor" (in "all", on when `lateral_corridor` = w > 0): the base stays
// within +-w of the straight line from its start to its goal. The zero-objective solve's first
// feasible point swayed the base 48-206 mm off that line on the benchmark scenes; a crawl needs
// its centre of mass inside each support triangle, which a couple of centimetres of sway give.
// The line is the start-to-goal line of the guess (base_line.hpp), so a diagonal goal gets a
// diagonal corridor (a corridor along y = 0 made plan --terrain pallet_15 --goal 1,0.3,0.5
// infeasible by construction).
// Exact along the whole path, not only at knots: per segment of duration h the base position is a
// cubic Bezier curve, which lies in the convex hull of its control points, so in the corridor (a
// slab) when they are. The segment's own control points (x0, x0 + h v0 / 3, x1 - h v1 / 3, x1)
// stray from the curve by up to h |v| / 3 where it bends; the rows bound those of its two halves
// (de Casteljau at the middle), four times closer: x0 + h v0 / 6, xm - h vm / 6, xm,
// xm + h vm / 6, x1 - h v1 / 6 (xm, vm the value and rate at the middle) and the knots (the same
// reason as swing_apex.cpp's, where the segment's own hull cost 3x the iterations). Rows (m): the
// offset across the line of each, in [-w, w]. Linear in the variables with fixed timing
// (bilinear in h and the velocities with optimised timing). Rows on fixed variables only (the
// start, the goal) are left out.
// A re-plan from a measured state may start outside the corridor (a planning session's steps
// start 1 cm beside a plan that may itself run at the corridor's edge). Its start is fixed, so the
// first half-segment's control points would have to come back within 0.05 s: 8 m/s^2 for 1 cm,
// and pallet_15 session steps stalled (6 and 9 of 20 with the session's line and a pinned horizon
// end). So the bound widens by the start's excess e over w (its offset, or the fixed control
// point's after it) and narrows back to w linearly over kCorridorReturn: segment s starting at
// nominal time t_s gets w + e max(0, 1 - t_s / kCorridorReturn) for all its rows (the larger end
// of the segment, so the convex hull still bounds the curve). A start inside the corridor (every
// cold plan) has e = 0: rows as before.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "base_line.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {
// How long (s) a re-plan starting outside the corridor has to return into it.
constexpr double kCorridorReturn = 0.5;
}  // namespace

void build_lateral_corridor_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  if (!(options.lateral_corridor >= 0.0))
    throw std::invalid_argument("lateral_corridor must be >= 0 m");
  if (options.lateral_corridor == 0.0) return;
  if (!path_shape_applies(problem, options)) return;
  const Layout& L = problem.layout();
  const BaseLine line = base_line_of(problem);
  if (!line.defined) return;
  const auto& lo = problem.lower();
  const auto& hi = problem.upper();
  const double w = options.lateral_corridor;
  const Eigen::Vector2d n = line.across, o = line.origin;
  const double offset0 = n.dot(o);
  // The start's excess over w, when the start is fixed (a re-plan from a state): its offset and
  // that of the first control point after it, A = x0 + h v0 / 6, when fixed too.
  double excess = 0.0;
  {
    const auto& x = problem.initial_guess();
    const int p0 = L.base[0], v0 = L.base[0] + 3, dv = L.interval_var[L.seg_interval[0]];
    auto across = [&](double px, double py) { return n.x() * px + n.y() * py - offset0; };
    if (all_fixed({p0, p0 + 1}, lo, hi))
      excess = std::max(excess, std::abs(across(x[p0], x[p0 + 1])) - w);
    if (fixed_control_point({p0, p0 + 1}, {v0, v0 + 1}, dv, lo, hi)) {
      const double h6 = x[dv] * L.seg_fraction[0] / 6.0;
      excess = std::max(excess, std::abs(across(x[p0] + h6 * x[v0], x[p0 + 1] + h6 * x[v0 + 1])) - w);
    }
  }
  for (int s = 0; s < L.num_segments; ++s) {
    const double bound =
        w + excess * std::max(0.0, 1.0 - L.nominal_knot_time[s] / kCorridorReturn);
    const int p0 = L.base[s], v0 = L.base[s] + 3, p1 = L.base[s + 1], v1 = L.base[s + 1] + 3;
    const int dv = L.interval_var[L.seg_interval[s]];
    // Which points get a row (each unless it is fixed): the start knot (first segment only; later
    // knots are the previous segment's end), A = x0 + h v0 / 6, B, C, D (the middle), E =
    // x1 - h v1 / 6, the end knot.
    const bool r0 = s == 0 && !all_fixed({p0, p0 + 1}, lo, hi);
    const bool rA = !fixed_control_point({p0, p0 + 1}, {v0, v0 + 1}, dv, lo, hi);
    const bool rBCD =
        !fixed_control_point({p0, p0 + 1, p1, p1 + 1}, {v0, v0 + 1, v1, v1 + 1}, dv, lo, hi);
    const bool rE = !fixed_control_point({p1, p1 + 1}, {v1, v1 + 1}, dv, lo, hi);
    const bool r3 = !all_fixed({p1, p1 + 1}, lo, hi);
    const int rows = r0 + rA + 3 * rBCD + rE + r3;
    if (rows == 0) continue;
    LocalVars lv;
    const int x0[2] = {lv.add(p0), lv.add(p0 + 1)}, w0[2] = {lv.add(v0), lv.add(v0 + 1)};
    const int x1[2] = {lv.add(p1), lv.add(p1 + 1)}, w1[2] = {lv.add(v1), lv.add(v1 + 1)};
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    problem.add_piece(make_piece(
        "lateral_corridor", lv, std::vector<double>(rows, -bound), std::vector<double>(rows, bound),
        [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = x[dur] * frac;
          // Offsets across the line of the knots, and the rates across it.
          const T a0 = n.x() * x[x0[0]] + n.y() * x[x0[1]] - offset0;
          const T a1 = n.x() * x[x1[0]] + n.y() * x[x1[1]] - offset0;
          const T b0 = n.x() * x[w0[0]] + n.y() * x[w0[1]];
          const T b1 = n.x() * x[w1[0]] + n.y() * x[w1[1]];
          const HalfControlPoints<T> c = half_control_points(h, a0, b0, a1, b1);
          int r = 0;
          if (r0) g[r++] = a0;
          if (rA) g[r++] = c.a;
          if (rBCD) {
            g[r++] = c.b;
            g[r++] = c.c;
            g[r++] = c.d;
          }
          if (rE) g[r++] = c.e;
          if (r3) g[r++] = a1;
        }));
  }
}

}  // namespace terrastride::planner
