// "cost_force_rate": the integral over every stance of |f'/(m g)|^2. The forces are linear in a
// segment, so over one segment it is |f1 - f0|^2 / ((m g)^2 h): one residual vector
// (f1 - f0) / (m g sqrt(h)) per stance segment and foot. With force ramps (the "force_ramp" set)
// the touch-down and lift-off knots are zero, so this spreads each foot's loading over its stance
// instead of the last segment before lift-off.
#include "costs.hpp"
#include "../constraints/spline_variables.hpp"

namespace terrastride::planner {

void add_force_rate_cost(SrbdProblem& problem, double weight) {
  const Layout& L = problem.layout();
  const double mg = problem.robot().mass * kGravity;
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (!L.contact[f][s]) continue;
      if (L.force[f][s][0] < 0 && L.force[f][s][1] < 0) continue;
      LocalVars lv;
      const auto f0 = lv.add3(L.force[f][s][0]);
      const auto f1 = lv.add3(L.force[f][s][1]);
      const int dur = add_segment_duration(lv, L, s);
      const double frac = L.seg_fraction[s];
      const double c = std::sqrt(weight) / mg;
      std::vector<double> none(3, 0.0);
      problem.add_cost(make_piece("cost_force_rate", lv, none, none, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        using std::sqrt;
        const T h = x[dur] * frac;
        const Vec3<T> df = gather3(x, f1) - gather3(x, f0);
        const T k = c / sqrt(h);
        for (int i = 0; i < 3; ++i) g[i] = k * df[i];
      }));
    }
}

}  // namespace terrastride::planner
