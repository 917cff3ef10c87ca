// "swing_clearance" (baseline): at `clearance_points` per segment of a swing, the foot at least
// h_min times the clearance profile above the terrain under it AND above the terrain probed at
// +-clearance_probe in x and y around it. Probing makes the bound conservative: between the
// points the foot moves less than the probe radius, and a smoothed planning terrain
// underestimates a sharp step only near its edge. Rows in m.
#include <algorithm>
#include <cmath>
#include <vector>

#include "spline_variables.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {

// The fraction of h_min demanded at time t into a swing of duration T. 0 at lift-off and
// touch-down (the foot must be allowed to leave and reach the ground), 1 from `ramp` after
// lift-off to `ramp` before touch-down, sin^2 in between so that the lower bound it puts on the
// foot height has a bounded second derivative.
double clearance_profile(double t, double T, double ramp) {
  const double edge = std::min(t, T - t);
  const double tau = std::min(ramp, 0.5 * T);
  if (!(tau > 0.0)) return edge > 0.0 ? 1.0 : 0.0;
  const double s = std::sin(0.5 * M_PI * std::clamp(edge / tau, 0.0, 1.0));
  return s * s;
}

}  // namespace

void add_swing_clearance(SrbdProblem& problem) {
  const Layout& L = problem.layout();
  const ProblemOptions& options = problem.options();
  const terrain::HeightField* field = &problem.terrain();
  const double hmin = options.swing_clearance, probe = options.clearance_probe;
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int np = std::max(1, options.clearance_points);
    // Nominal times: with optimised timing the profile keeps its shape in swing fraction. A swing
    // under way at the start of a re-plan lifted off swing_elapsed before it.
    const double t0 =
        L.nominal_knot_time[sw.first_seg] -
        (sw.first_seg == 0 ? problem.timeline().swing_elapsed_of(static_cast<std::size_t>(f))
                           : 0.0);
    const double swing_T = L.nominal_knot_time[sw.last_seg + 1] - t0;
    for (int s = sw.first_seg; s <= sw.last_seg; ++s)
      for (const double sigma : L.segment_points(s, np, false)) {
        if (s == sw.first_seg && sigma == 0.0) continue;  // lift-off knot
        const double t = L.nominal_knot_time[s] +
                         sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]) - t0;
        const double w = clearance_profile(t, swing_T, options.clearance_ramp);
        LocalVars lv;
        const HermiteLocal fpl = add_foot_position(lv, L, f, s, sigma, true);
        const int dur = fpl.needs_duration ? add_segment_duration(lv, L, s) : -1;
        const double frac = L.seg_fraction[s];
        const int nrow = probe > 0.0 ? 5 : 1;
        const double d = probe;
        std::vector<double> lo(nrow, hmin * w), hi(nrow, kInf);
        problem.add_piece(make_piece("swing_clearance", lv, lo, hi, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
          Vec3<T> p;
          hermite<T>(sigma, h, x, fpl, &p, nullptr, nullptr);
          static const double ox[5] = {0, 1, -1, 0, 0}, oy[5] = {0, 0, 0, 1, -1};
          for (int i = 0; i < nrow; ++i)
            g[i] = p[2] - terrain_height(*field, p[0] + d * ox[i], p[1] + d * oy[i]);
        }));
      }
  }
}

}  // namespace terrastride::planner
