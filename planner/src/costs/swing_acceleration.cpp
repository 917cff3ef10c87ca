// "cost_swing_acceleration": the integral over every swing of |p''/g|^2, the swing foot's
// acceleration (linear in a cubic segment, so exact). A swing then bends no more than its
// clearance rows and its footholds make it: the lowest, smoothest arc they allow. Why: with a zero
// objective, hind feet of the demo rose 16-17 cm on flat ground before a 10 cm step.
#include "costs.hpp"
#include "../constraints/spline_variables.hpp"

namespace terrastride::planner {

void add_swing_acceleration_cost(SrbdProblem& problem, double weight) {
  const Layout& L = problem.layout();
  const double w = weight / (kGravity * kGravity);
  for (const auto& sw : L.swings)
    for (int s = sw.first_seg; s <= sw.last_seg; ++s) {
      LocalVars lv;
      const HermiteLocal foot = add_foot_position(lv, L, sw.foot, s, 0.5, false);
      const int dur = add_segment_duration(lv, L, s);
      const double frac = L.seg_fraction[s];
      std::vector<double> none(6, 0.0);
      problem.add_cost(make_piece("cost_swing_acceleration", lv, none, none,
                                  [=](const auto* x, auto* g) {
                                    using T = std::decay_t<decltype(*g)>;
                                    const T h = x[dur] * frac;
                                    Vec3<T> a0, a1;
                                    hermite<T>(0.0, h, x, foot, nullptr, nullptr, &a0);
                                    hermite<T>(1.0, h, x, foot, nullptr, nullptr, &a1);
                                    linear_integral_residuals<T>(a0, a1, h, w, g);
                                  }));
    }
}

}  // namespace terrastride::planner
