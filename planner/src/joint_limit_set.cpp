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

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

namespace {

// Joint angles (HAA, HFE, KFE) of `leg` for the foot at pb in the base frame; a foot beyond reach
// gets the stretched knee's angles (the rows then push it back).
template <class T>
Vec3<T> joint_angles(const robot::LegModel& leg, const Vec3<T>& pb) {
  using std::acos;
  using std::atan2;
  using std::sqrt;
  const Vec3<T> v = pb - leg.haa_origin.cast<T>();
  const T gamma = atan2(v[1], -v[2]);
  const T rho = sqrt(v[1] * v[1] + v[2] * v[2]);
  const T X = v[0], Z = -(rho - leg.l0);
  T c = (X * X + Z * Z - leg.l1 * leg.l1 - leg.l2 * leg.l2) / (2.0 * leg.l1 * leg.l2);
  if (value_of(c) > 1.0 - 1e-6) c = T(1.0 - 1e-6);
  if (value_of(c) < -1.0 + 1e-6) c = T(-1.0 + 1e-6);
  const T qK = static_cast<double>(leg.knee_sign) * acos(c);
  using std::cos;
  using std::sin;
  const T qH = atan2(-X, -Z) - atan2(leg.l2 * sin(qK), leg.l1 + leg.l2 * cos(qK));
  return Vec3<T>(-static_cast<double>(leg.side) * gamma, qH, qK);
}

}  // namespace

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
        const Vec3<T> q = joint_angles<T>(leg, R.transpose() * (gather3(x, p) - base));
        for (int j = 0; j < 3; ++j) g[j] = q[j];
      }));
    }
  }
}

}  // namespace terrastride::planner
