// "dynamics_angular" (baseline): the base's angular dynamics, I w' + w x I w = sum (p - r) x f
// (world frame, I = R I_b R^T), at `angular_points` points of each segment, ends included. The
// ends hold exactly, the interior points within +-angular_band (see ProblemOptions). Rows in
// units of 0.1 m g x 1 m. Only for a base that may rotate.
#include <algorithm>
#include <array>
#include <vector>

#include "spline_variables.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void add_dynamics_angular(SrbdProblem& problem, int s) {
  const Layout& L = problem.layout();
  const robot::RobotModel& robot = problem.robot();
  const ProblemOptions& options = problem.options();
  const bool rot_free = robot.base_dof_free[3] || robot.base_dof_free[4] || robot.base_dof_free[5];
  if (!rot_free) return;
  const int nf = static_cast<int>(robot.legs.size());
  const double mg = robot.mass * kGravity;
  const Eigen::Matrix3d inertia = robot.inertia;
  const double frac = L.seg_fraction[s];
  const int np = std::max(2, options.angular_points);
  for (const double sigma : L.segment_points(s, np - 1, true)) {
    LocalVars lv;
    const HermiteLocal rp = add_base_position(lv, L, s, sigma, true);
    const HermiteLocal ep = add_base_euler(lv, L, s, sigma, false);
    const int dur = add_segment_duration(lv, L, s);
    std::vector<std::array<int, 3>> fp, f0, f1;
    for (int f = 0; f < nf; ++f)
      if (L.contact[f][s]) {
        fp.push_back(lv.add3(L.foot_pos[f][s]));
        f0.push_back(sigma < 1.0 ? lv.add3(L.force[f][s][0]) : std::array<int, 3>{-1, -1, -1});
        f1.push_back(sigma > 0.0 ? lv.add3(L.force[f][s][1]) : std::array<int, 3>{-1, -1, -1});
      }
    const double scale = 1.0 / (0.1 * mg);
    // See angular_band. A cropped first segment's start was an interior point of the previous
    // plan's segment, so it keeps the band.
    const bool interior = (sigma > 0.0 && sigma < 1.0) || (s == 0 && L.first_segment_cropped > 0.0);
    const double band = interior ? options.angular_band * scale : 0.0;
    problem.add_piece(make_piece(
        "dynamics_angular", lv, std::vector<double>(3, -band), std::vector<double>(3, band),
        [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          const T h = x[dur] * frac;
          Vec3<T> r, e, ed, edd, w, wd;
          hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
          hermite<T>(sigma, h, x, ep, &e, &ed, &edd);
          euler_to_angular<T>(e, ed, edd, &w, &wd);
          const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(e);
          const Eigen::Matrix<T, 3, 3> Iw = R * inertia.cast<T>() * R.transpose();
          const Vec3<T> Iww = Iw * w;
          Vec3<T> res = Iw * wd + w.cross(Iww);
          for (std::size_t i = 0; i < fp.size(); ++i) {
            const Vec3<T> f = (1.0 - sigma) * gather3(x, f0[i]) + sigma * gather3(x, f1[i]);
            res -= (gather3(x, fp[i]) - r).cross(f);
          }
          for (int i = 0; i < 3; ++i) g[i] = res[i] * scale;
        }));
  }
}

}  // namespace terrastride::planner
