// "swing": the swing leg's torque budget. The force polytopes bound what a stance leg's motors
// must hold against the ground; a swing leg's motors instead accelerate the leg itself
// (tau = M(q) q'' + ...), which a single-rigid-body plan never sees. With a zero objective nothing
// else stops the solver from whipping a foot at hundreds of m/s^2 through a 0.16 s swing, which
// the post-hoc torque check then finds at 2x the limits. So every world-frame component of a swing
// foot's acceleration is bounded. The bound is exact along the whole swing: a cubic Hermite
// segment's acceleration is linear in time, so its extremes are at the segment's ends. Rows are in
// units of the bound (a / a_max in [-1, 1]).
#include <stdexcept>

#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_swing_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  if (!(options.swing_acceleration > 0.0))
    throw std::invalid_argument("swing acceleration bound must be > 0 m/s^2");
  const Layout& L = problem.layout();
  const double amax = options.swing_acceleration;
  for (const auto& sw : L.swings)
    for (int s = sw.first_seg; s <= sw.last_seg; ++s) {
      LocalVars lv;
      // sigma strictly inside the segment: all four Hermite knots and the duration enter.
      const HermiteLocal foot = add_foot_position(lv, L, sw.foot, s, 0.5, false);
      const int dur = add_segment_duration(lv, L, s);
      const double frac = L.seg_fraction[s];
      problem.add_piece(make_piece("swing", lv, std::vector<double>(6, -1.0),
                                   std::vector<double>(6, 1.0), [=](const auto* x, auto* g) {
                                     using T = std::decay_t<decltype(*g)>;
                                     const T h = x[dur] * frac;
                                     for (int side = 0; side < 2; ++side) {
                                       Vec3<T> a;
                                       hermite<T>(side, h, x, foot, nullptr, nullptr, &a);
                                       for (int i = 0; i < 3; ++i) g[3 * side + i] = a[i] / amax;
                                     }
                                   }));
    }
}

}  // namespace terrastride::planner
