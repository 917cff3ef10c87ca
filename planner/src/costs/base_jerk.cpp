// "cost_base_jerk": the base's jerk. A cubic segment's acceleration is linear, so its jerk is
// constant, (a1 - a0) / h, and the integral of |jerk/g|^2 over it is |a1 - a0|^2 / (g^2 h); at a
// knot the acceleration jumps between the two segments (the spline is only C1), which a
// controller feels as a kick: each interior knot adds |a_right - a_left|^2 / (g^2 h_mean), the
// jump spread over the mean of its two segments. Why: with acceleration terms alone the base's
// acceleration jumped at knots (99th-percentile jerk 440 m/s^3 on the flat 2.4 s crawl against 35
// at the zero objective's point, which follows the minimum-jerk guess).
#include "costs.hpp"
#include "../constraints/spline_variables.hpp"

namespace terrastride::planner {

void add_base_jerk_cost(SrbdProblem& problem, double weight) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const double c = std::sqrt(weight) / kGravity;
  std::vector<double> none(3, 0.0);
  for (int s = 0; s < S; ++s) {  // within segments
    LocalVars lv;
    const HermiteLocal rp = add_base_position(lv, L, s, 0.5, false);
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    problem.add_cost(make_piece("cost_base_jerk", lv, none, none, [=](const auto* x, auto* g) {
      using T = std::decay_t<decltype(*g)>;
      using std::sqrt;
      const T h = x[dur] * frac;
      Vec3<T> a0, a1;
      hermite<T>(0.0, h, x, rp, nullptr, nullptr, &a0);
      hermite<T>(1.0, h, x, rp, nullptr, nullptr, &a1);
      const T k = c / sqrt(h);
      for (int i = 0; i < 3; ++i) g[i] = k * (a1[i] - a0[i]);
    }));
  }
  for (int s = 1; s < S; ++s) {  // jumps at interior knots
    LocalVars lv;
    const HermiteLocal left = add_base_position(lv, L, s - 1, 0.5, false);
    const HermiteLocal right = add_base_position(lv, L, s, 0.5, false);
    const int dl = add_segment_duration(lv, L, s - 1), dr = add_segment_duration(lv, L, s);
    const double fl = L.seg_fraction[s - 1], fr = L.seg_fraction[s];
    problem.add_cost(make_piece("cost_base_jerk", lv, none, none, [=](const auto* x, auto* g) {
      using T = std::decay_t<decltype(*g)>;
      using std::sqrt;
      const T hl = x[dl] * fl, hr = x[dr] * fr;
      Vec3<T> al, ar;
      hermite<T>(1.0, hl, x, left, nullptr, nullptr, &al);
      hermite<T>(0.0, hr, x, right, nullptr, nullptr, &ar);
      const T k = c / sqrt(0.5 * (hl + hr));
      for (int i = 0; i < 3; ++i) g[i] = k * (ar[i] - al[i]);
    }));
  }
}

}  // namespace terrastride::planner
