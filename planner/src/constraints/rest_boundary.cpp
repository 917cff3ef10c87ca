// "rest_boundary" (baseline): a plan at rest at its ends is at rest in its accelerations too. The
// velocities there are fixed at zero already (the initial guess's bounds); without these rows the
// base could still accelerate at t = 0 and t = T (measured before them: the flat 2.4 s "all"
// crawl ended with the forces summing to 1.6 m g, the base accelerating up at 5.8 m/s^2; the demo
// started at 4.8 m/s^2). With zero base linear and Euler accelerations the dynamics rows at those
// segment ends (exact there) make the forces balance gravity and their moments cancel: static
// equilibrium. Imposed at the end unless a horizon step pins it in motion, and at the start when
// the plan starts from rest (no start state: a re-plan from a measured or planned state keeps
// that state's motion).
// Rows: the linear acceleration in g per free linear direction, the Euler accelerations in rad/s^2
// per free rotational direction.
#include <vector>

#include "spline_variables.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void add_rest_boundary(SrbdProblem& problem) {
  const Layout& L = problem.layout();
  const robot::RobotModel& robot = problem.robot();
  const int S = L.num_segments;
  std::vector<int> lin, ang;  // free directions: x y z, and yaw pitch roll
  for (int d = 0; d < 3; ++d) {
    if (robot.base_dof_free[d]) lin.push_back(d);
    if (robot.base_dof_free[3 + d]) ang.push_back(d);
  }
  const int rows = static_cast<int>(lin.size() + ang.size());
  if (rows == 0) return;
  auto add = [&](int s, double sigma) {
    LocalVars lv;
    const HermiteLocal rp = add_base_position(lv, L, s, sigma, false);
    const HermiteLocal ep = add_base_euler(lv, L, s, sigma, false);
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    std::vector<double> z(rows, 0.0);
    problem.add_piece(make_piece("rest_boundary", lv, z, z, [=](const auto* x, auto* g) {
      using T = std::decay_t<decltype(*g)>;
      const T h = x[dur] * frac;
      Vec3<T> a, edd;
      hermite<T>(sigma, h, x, rp, nullptr, nullptr, &a);
      hermite<T>(sigma, h, x, ep, nullptr, nullptr, &edd);
      int i = 0;
      for (int d : lin) g[i++] = a[d] / kGravity;
      for (int d : ang) g[i++] = edd[d];
    }));
  };
  if (problem.starts_at_rest()) add(0, 0.0);
  // A receding-horizon step pinned in motion (SrbdProblem's end_state) is not at rest at its end.
  if (problem.ends_at_rest()) add(S - 1, 1.0);
}

}  // namespace terrastride::planner
