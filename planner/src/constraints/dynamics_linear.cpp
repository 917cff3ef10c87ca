// "dynamics_linear" (baseline): the base's linear dynamics, m r'' = sum f - m g, at both ends of
// each segment. Inside a segment the base acceleration (cubic Hermite) and the sum of the forces
// (linear force pieces) are both linear in time, so holding at both ends it holds at every instant
// (see nlp.hpp). One row per free linear direction of the base, in body weights.
#include <array>
#include <vector>

#include "spline_variables.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void add_dynamics_linear(SrbdProblem& problem, int s) {
  const Layout& L = problem.layout();
  const robot::RobotModel& robot = problem.robot();
  const int nf = static_cast<int>(robot.legs.size());
  const double m = robot.mass, mg = m * kGravity;
  std::vector<int> lin_rows;
  for (int d = 0; d < 3; ++d)
    if (robot.base_dof_free[d]) lin_rows.push_back(d);
  if (lin_rows.empty()) return;
  const double frac = L.seg_fraction[s];
  for (int side = 0; side < 2; ++side) {
    LocalVars lv;
    const double sigma = side;
    const HermiteLocal rp = add_base_position(lv, L, s, sigma, false);
    const int dur = add_segment_duration(lv, L, s);
    std::vector<std::array<int, 3>> fl;
    for (int f = 0; f < nf; ++f)
      if (L.force[f][s][side] >= 0) fl.push_back(lv.add3(L.force[f][s][side]));
    std::vector<double> z(lin_rows.size(), 0.0);
    problem.add_piece(make_piece("dynamics_linear", lv, z, z, [=](const auto* x, auto* g) {
      using T = std::decay_t<decltype(*g)>;
      const T h = x[dur] * frac;
      Vec3<T> a;
      hermite<T>(sigma, h, x, rp, nullptr, nullptr, &a);
      Vec3<T> r = m * a;
      r[2] += mg;
      for (const auto& fi : fl) r -= gather3(x, fi);
      for (std::size_t i = 0; i < lin_rows.size(); ++i) g[i] = r[lin_rows[i]] / mg;
    }));
  }
}

}  // namespace terrastride::planner
