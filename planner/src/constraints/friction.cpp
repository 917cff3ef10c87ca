// "friction" (baseline): every contact force knot in the friction pyramid of the terrain under
// its foothold, 0 <= f_n <= f_max and |f_t1|, |f_t2| <= mu f_n (terrain normal frame). The rows
// are linear in f for the stance's fixed foothold, so holding at the knots they hold along the
// whole linear force segment. Rows in body weights.
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

void add_friction(SrbdProblem& problem) {
  const Layout& L = problem.layout();
  const robot::RobotModel& robot = problem.robot();
  const terrain::HeightField* field = &problem.terrain();
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot.legs.size());
  const double mg = robot.mass * kGravity;
  const double mu = problem.options().friction;
  const double fmax = problem.options().max_normal_force_factor * mg;
  for (int f = 0; f < nf; ++f) {
    int last = -1;
    for (int s = 0; s < S; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0 || fv == last) continue;  // a knot shared by two segments: once
        last = fv;
        LocalVars lv;
        const auto p = lv.add3(L.foot_pos[f][s]);
        const auto fi = lv.add3(fv);
        problem.add_piece(make_piece("friction", lv, {0.0, -kInf, -kInf, -kInf, -kInf},
                                     {fmax / mg, 0.0, 0.0, 0.0, 0.0}, [=](const auto* x, auto* g) {
                                       using T = std::decay_t<decltype(*g)>;
                                       Vec3<T> n, t1, t2;
                                       terrain_frame(*field, x[p[0]], x[p[1]], &n, &t1, &t2);
                                       const Vec3<T> force = gather3(x, fi) / mg;
                                       const T fn = n.dot(force), a = t1.dot(force),
                                               c = t2.dot(force);
                                       g[0] = fn;
                                       g[1] = a - mu * fn;
                                       g[2] = -a - mu * fn;
                                       g[3] = c - mu * fn;
                                       g[4] = -c - mu * fn;
                                     }));
      }
  }
}

}  // namespace terrastride::planner
