// "cost_base_acceleration": the integral of |r''/g|^2 (weight w_lin) and of |e''|^2 in (rad/s^2)^2
// (weight w_ang) over every segment. The base's accelerations are linear in a cubic segment, so
// the integral is exact (linear_integral_residuals). Why: with a zero objective the first feasible
// point let the demo's base back up, weave 86 mm and dip 2-3 cm at every step; a calm base is what
// a controller tracks well, and it costs little (the dynamics need little acceleration at a crawl).
#include "costs.hpp"
#include "../constraints/spline_variables.hpp"

namespace terrastride::planner {

void add_base_acceleration_cost(SrbdProblem& problem, double linear_weight, double angular_weight) {
  const Layout& L = problem.layout();
  for (int s = 0; s < L.num_segments; ++s) {
    LocalVars lv;
    const HermiteLocal rp = add_base_position(lv, L, s, 0.5, false);
    const HermiteLocal ep = add_base_euler(lv, L, s, 0.5, false);
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    const double wl = linear_weight / (kGravity * kGravity), wa = angular_weight;
    std::vector<double> none(12, 0.0);
    problem.add_cost(make_piece("cost_base_acceleration", lv, none, none,
                                [=](const auto* x, auto* g) {
                                  using T = std::decay_t<decltype(*g)>;
                                  const T h = x[dur] * frac;
                                  Vec3<T> a0, a1, e0, e1;
                                  hermite<T>(0.0, h, x, rp, nullptr, nullptr, &a0);
                                  hermite<T>(1.0, h, x, rp, nullptr, nullptr, &a1);
                                  hermite<T>(0.0, h, x, ep, nullptr, nullptr, &e0);
                                  hermite<T>(1.0, h, x, ep, nullptr, nullptr, &e1);
                                  linear_integral_residuals<T>(a0, a1, h, wl, g);
                                  linear_integral_residuals<T>(e0, e1, h, wa, g + 6);
                                }));
  }
}

}  // namespace terrastride::planner
