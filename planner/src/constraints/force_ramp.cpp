// "force_ramp" (in "all"; beyond the paper): contact forces that load and unload continuously.
// A zero-objective solve picks any feasible force profile, and the first feasible one let feet
// lift off and touch down carrying their full share: every lift-off and touch-down of the demo
// jumped 135-193 N between two 10 ms samples, the flat 2.4 s crawl lifted LH off at 366 N. A real
// leg cannot unload in no time, and a controller tracking the step kicks the body.
// Two parts:
//  - the layout has no force variable at a touch-down or lift-off knot when this set is
//    requested (Layout, make_layout): the force is identically zero there, so it rises from zero
//    after touch-down and falls to zero before lift-off along the linear force pieces;
//  - here, per stance segment, |f1 - f0| <= force_rate_max * h (one row, squared and in units
//    of the bound: |f1 - f0|^2 / (force_rate_max h)^2 <= 1), so no segment loads or unloads
//    faster than the bound. The force is linear in a segment, so the bound holds at every instant.
// Not in the first segment of a re-plan from a given start (a session step, plan --init): the
// measured state has no contact forces, so that row bounds the start's force, a free value,
// against the next knot's; where a lift-off ends a cropped first segment (0.01-0.02 s long) the
// next knot's force is zero and the row held the start's to force_rate_max h (20-40 N) while the
// pushed base needed the foot loaded: infeasible by construction (the pallet_15 closed loop's
// steps after a push stopped at their 20-iteration cap with this row violated). From the end of
// the first segment on the ramps hold; a plan from rest (every cold plan) keeps every row.
#include <stdexcept>

#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_force_ramp_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  if (!(options.force_rate_max >= 0.0))
    throw std::invalid_argument("force_rate_max must be >= 0 N/s");
  if (options.force_rate_max == 0.0) return;  // the ramps of the layout alone
  const Layout& L = problem.layout();
  const int nf = static_cast<int>(problem.robot().legs.size());
  const double rate = options.force_rate_max;
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s]) continue;
      if (s == 0 && !problem.starts_at_rest()) continue;  // see above
      if (L.force[f][s][0] < 0 && L.force[f][s][1] < 0) continue;  // zero all along
      LocalVars lv;
      const auto f0 = lv.add3(L.force[f][s][0]);
      const auto f1 = lv.add3(L.force[f][s][1]);
      const int dur = add_segment_duration(lv, L, s);
      const double frac = L.seg_fraction[s];
      problem.add_piece(
          make_piece("force_ramp", lv, {-kInf}, {1.0}, [=](const auto* x, auto* g) {
            using T = std::decay_t<decltype(*g)>;
            const T h = x[dur] * frac;
            const Vec3<T> df = gather3(x, f1) - gather3(x, f0);
            const T bound = rate * h;
            g[0] = df.squaredNorm() / (bound * bound);
          }));
    }
}

}  // namespace terrastride::planner
