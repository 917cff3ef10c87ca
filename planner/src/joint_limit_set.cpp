// "joints" (beyond the paper; not in "all"): the legs' joint ranges. The range-of-motion box of the
// baseline (TOWR's kinematic model) is a box around the nominal foot, and HyQ's joint ranges do not
// contain all of it: a foot high and forward under the hip needs HFE beyond its range (measured on
// the pallet plans: 100-300 samples up to 8 deg past HFE's limit). This set keeps the joint angles
// from inverse kinematics of the foot in the base frame (DESIGN.md, Robot) within
// [q_min + margin, q_max - margin] at every knot of the base spline: during stances (the foot
// stands, the base moves) and at the knots inside swings. Between knots the angles move little
// (stance) or the margin covers them (swing); the post-hoc check measures the result densely.
// Each row depends on the knot's base position and orientation and the foot position only.
#include <algorithm>
#include <cmath>

#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"

namespace terrastride::planner {

void build_joint_limit_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const double margin = options.joint_margin;
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    std::vector<double> lo(3), hi(3);
    for (int j = 0; j < 3; ++j) {
      lo[j] = leg.q_min[j] + margin;
      hi[j] = leg.q_max[j] - margin;
      if (!(lo[j] < hi[j]))
        throw std::invalid_argument("joint margin " + std::to_string(margin) +
                                    " rad leaves no range for joint " + std::to_string(j) +
                                    " of leg " + leg.name);
    }
    for (int k = 0; k <= S; ++k) {
      LocalVars lv;
      const auto p = lv.add3(L.foot_pos[f][k]);
      const auto r = lv.add3(L.base[k]);
      const auto e = lv.add3(L.base[k] + 6);
      problem.add_piece(make_piece("joint_limits", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        const Vec3<T> base = gather3(x, r);
        const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(gather3(x, e));
        const Vec3<T> q = feasibility::leg_joint_angles<T>(leg, R.transpose() * (gather3(x, p) - base));
        for (int j = 0; j < 3; ++j) g[j] = q[j];
      }));
    }
  }
}

}  // namespace terrastride::planner
