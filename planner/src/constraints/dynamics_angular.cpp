// "dynamics_angular" (baseline): the base's angular dynamics, I w' + w x I w = sum (p - r) x f
// (world frame, I = R I_b R^T), at `angular_points` points of each segment, ends included. The
// ends hold exactly, the interior points within +-angular_band (see ProblemOptions). Rows in
// units of 0.1 m g x 1 m. Only for a base that may rotate.
#include <algorithm>
#include <array>
#include <vector>

#include "feasibility_common.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {

// The rotational side of the angular dynamics, I w' + w x I w (world frame, I = R I_b R^T), from
// the Euler angles e and their first and second derivatives.
template <class T>
Vec3<T> rotational_side(const Eigen::Matrix3d& inertia, const Vec3<T>& e, const Vec3<T>& ed,
                        const Vec3<T>& edd) {
  Vec3<T> w, wd;
  euler_to_angular<T>(e, ed, edd, &w, &wd);
  const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(e);
  const Eigen::Matrix<T, 3, 3> Iw = R * inertia.cast<T>() * R.transpose();
  const Vec3<T> Iww = Iw * w;
  return Iw * wd + w.cross(Iww);
}
// For the piece's AD scalars: the rotational side depends on the piece's variables only through
// e, e' and e'' (9 scalars), so it is differentiated with respect to these (AdInner, fixed size)
// and chained to the piece's variables once per row, instead of carrying the rotation, inertia
// and angular velocity products over all the piece's variables (some 40). The same value;
// derivatives equal up to round-off.
Vec3<Ad> rotational_side(const Eigen::Matrix3d& inertia, const Vec3<Ad>& e, const Vec3<Ad>& ed,
                         const Vec3<Ad>& edd) {
  const Ad* outer[9] = {&e[0], &e[1], &e[2], &ed[0], &ed[1], &ed[2], &edd[0], &edd[1], &edd[2]};
  AdInner inner[9];
  for (int i = 0; i < 9; ++i) inner[i] = AdInner(outer[i]->value(), 9, i);
  const Vec3<AdInner> r = rotational_side<AdInner>(
      inertia, Vec3<AdInner>(inner[0], inner[1], inner[2]),
      Vec3<AdInner>(inner[3], inner[4], inner[5]), Vec3<AdInner>(inner[6], inner[7], inner[8]));
  Vec3<Ad> out;
  for (int row = 0; row < 3; ++row) {
    AdVector d;
    for (int i = 0; i < 9; ++i)
      feasibility::accumulate(&d, r[row].derivatives()[i], outer[i]->derivatives());
    out[row] = Ad(r[row].value(), d);
  }
  return out;
}

}  // namespace

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
          Vec3<T> r, e, ed, edd;
          hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
          hermite<T>(sigma, h, x, ep, &e, &ed, &edd);
          Vec3<T> res = rotational_side(inertia, e, ed, edd);
          for (std::size_t i = 0; i < fp.size(); ++i) {
            const Vec3<T> f = (1.0 - sigma) * gather3(x, f0[i]) + sigma * gather3(x, f1[i]);
            res -= (gather3(x, fp[i]) - r).cross(f);
          }
          for (int i = 0; i < 3; ++i) g[i] = res[i] * scale;
        }));
  }
}

}  // namespace terrastride::planner
