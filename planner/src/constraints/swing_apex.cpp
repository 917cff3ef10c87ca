// "swing_apex" (in "all", on when `swing_apex_rise` = h > 0): a swing foot rises at
// most h above the higher of its lift-off and touch-down points. The swing clearance rows bound
// the foot from below only, and the zero-objective solve's first feasible point lifted feet
// 103-302 mm above both ends of their swings: wasted time and torque, and a leg a controller
// tracks badly.
// Exact along the whole swing: per segment of duration h the foot is a cubic Bezier curve, whose
// height never exceeds its highest control point's. The hull of the segment's own control points
// (p0, p0 + h v0 / 3, p1 - h v1 / 3, p1) overshoots the apex by up to h |v| / 3 where the foot
// turns from rising to falling; measured on pallet_15 `all` with corridor and apex rows, that
// slack (the plan's highest foot 94.6 mm above its ends for a 100 mm bound) made the rows fight
// the swing-acceleration and clearance rows: 33 feasibility iterations against 10 with a 12 cm
// bound. So each segment is split at its middle (de Casteljau) and the rows bound the two halves'
// control points, four times closer to the curve: the halves' inner control points
// p0 + h v0 / 6, pm - h vm / 6, pm, pm + h vm / 6, p1 - h v1 / 6 (pm, vm the value and rate at
// the middle) and the inner knots. Rows (m), each <= rise: those heights minus z_ref, the height
// of one of the swing's two end points. max(z_lift-off, z_touch-down) is not smooth; z_ref is the
// end that is higher in the initial guess (the terrain under the guessed footholds), never above
// the true maximum, so the rows are conservative and linear (with fixed timing). The end points
// and control points equal to them (zero velocity at lift-off and touch-down) need no row.
// A swing that passes beside or over terrain higher than its ends must rise over it: the
// swing_clearance rows hold the foot h_min above the terrain probed around it. Bounded by its
// ends alone, such a swing had to move its footholds until its path avoided that terrain (the
// pallet_15 crawl turning to 1, 0.3, 0.5 rad with all three path-shape families: 83 iterations,
// and the pallet_10 one exit 3). So where the terrain under the guess's swing path (at the
// clearance rows' probe points) is higher than z_ref, z_ref is that height, a constant: the foot
// rises at most `rise` above the highest terrain it passes (12 and 74 iterations; `rise` must
// exceed h_min for such a swing to be feasible). On flat ground nothing changes.
#include <algorithm>
#include <stdexcept>
#include <vector>

#include "base_line.hpp"  // all_fixed, fixed_control_point
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {

// The highest terrain under foot f's swing from knot k0 to k1 along the initial guess's path: at
// the guess's knots and at the clearance rows' probes around them (as swing_clearance.cpp probes).
double highest_terrain_passed(SrbdProblem& problem, int f, int k0, int k1) {
  const Layout& L = problem.layout();
  const auto& guess = problem.initial_guess();
  const ProblemOptions& o = problem.options();
  static const double ox[5] = {0, 1, -1, 0, 0}, oy[5] = {0, 0, 0, 1, -1};
  const int probes = o.clearance_probe > 0.0 ? 5 : 1;
  double need = -kInf;
  for (int k = k0; k <= k1; ++k) {
    const double x = guess[L.foot_pos[f][k]], y = guess[L.foot_pos[f][k] + 1];
    for (int i = 0; i < probes; ++i)
      need = std::max(need, terrain_height(problem.terrain(), x + o.clearance_probe * ox[i],
                                           y + o.clearance_probe * oy[i]));
  }
  return need;
}

}  // namespace

void build_swing_apex_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  if (!(options.swing_apex_rise >= 0.0))
    throw std::invalid_argument("swing_apex_rise must be >= 0 m");
  if (options.swing_apex_rise == 0.0) return;
  if (!path_shape_applies(problem, options)) return;
  const Layout& L = problem.layout();
  const auto& guess = problem.initial_guess();
  const auto& lo = problem.lower();
  const auto& hi = problem.upper();
  const double rise = options.swing_apex_rise;
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int k0 = sw.first_seg, k1 = sw.last_seg + 1;
    const int ref = guess[L.foot_pos[f][k0] + 2] >= guess[L.foot_pos[f][k1] + 2]
                        ? L.foot_pos[f][k0] + 2
                        : L.foot_pos[f][k1] + 2;
    const double terrain_need = highest_terrain_passed(problem, f, k0, k1);
    const bool terrain_ref = terrain_need > guess[ref];
    for (int s = k0; s < k1; ++s) {
      const int z0 = L.foot_pos[f][s] + 2, z1 = L.foot_pos[f][s + 1] + 2;
      const int vz0 = L.foot_vel[f][s] < 0 ? -1 : L.foot_vel[f][s] + 2;
      const int vz1 = L.foot_vel[f][s + 1] < 0 ? -1 : L.foot_vel[f][s + 1] + 2;
      // The halves' control points: A = p0 + h v0 / 6 (unless v0 is zero: A = p0), B, C, D (always
      // move), E = p1 - h v1 / 6 (unless v1 is zero), F = p1 (inner knots only).
      // Rows on fixed variables only are left out (a re-plan's swing under way at its start).
      const int dv = L.interval_var[L.seg_interval[s]];
      // The reference's variable (none for the terrain's demand, a constant).
      const std::vector<int> refs = terrain_ref ? std::vector<int>{} : std::vector<int>{ref};
      auto with_ref = [&](std::vector<int> v) {
        v.insert(v.end(), refs.begin(), refs.end());
        return v;
      };
      const bool rA = vz0 >= 0 && !fixed_control_point(with_ref({z0}), {vz0}, dv, lo, hi);
      const bool rE = vz1 >= 0 && !fixed_control_point(with_ref({z1}), {vz1}, dv, lo, hi);
      const bool rF = s + 1 < k1 && !all_fixed(with_ref({z1}), lo, hi);
      std::vector<int> rates;
      if (vz0 >= 0) rates.push_back(vz0);
      if (vz1 >= 0) rates.push_back(vz1);
      const bool rBCD = !fixed_control_point(with_ref({z0, z1}), rates, dv, lo, hi);
      const int rows = 3 * rBCD + rA + rE + rF;
      if (rows == 0) continue;
      LocalVars lv;
      const int zr = terrain_ref ? -1 : lv.add(ref), a0 = lv.add(z0), a1 = lv.add(z1);
      const int b0 = vz0 >= 0 ? lv.add(vz0) : -1, b1 = vz1 >= 0 ? lv.add(vz1) : -1;
      const int dur = add_segment_duration(lv, L, s);
      const double frac = L.seg_fraction[s];
      problem.add_piece(make_piece(
          "swing_apex", lv, std::vector<double>(rows, -kInf), std::vector<double>(rows, rise),
          [=](const auto* x, auto* g) {
            using T = std::decay_t<decltype(*g)>;
            const T h = x[dur] * frac;
            const T v0 = b0 >= 0 ? x[b0] : T(0.0), v1 = b1 >= 0 ? x[b1] : T(0.0);
            const T p0 = x[a0], p1 = x[a1];
            const HalfControlPoints<T> c = half_control_points(h, p0, v0, p1, v1);
            const T z_ref = zr >= 0 ? T(x[zr]) : T(terrain_need);
            int r = 0;
            if (rA) g[r++] = c.a - z_ref;
            if (rBCD) {
              g[r++] = c.b - z_ref;
              g[r++] = c.c - z_ref;
              g[r++] = c.d - z_ref;
            }
            if (rE) g[r++] = c.e - z_ref;
            if (rF) g[r++] = x[a1] - z_ref;
          }));
    }
  }
}

}  // namespace terrastride::planner
