// The initial guess of the contact forces.
#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <vector>

#include "initial_guess.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner::initialization {

// Forces of the initial guess: at each knot, the forces of the feet in stance that best satisfy
// both neighbouring segments' linear and angular dynamics for the guessed base motion, nearest to
// the weight shared equally (a small regularised least-squares problem per knot), then held in
// the friction pyramid. Ipopt then starts near dynamic balance instead of 1-2 m g away from it.
void guess_forces(const GuessInputs& in, Variables* variables, int first_knot, int last_knot) {
  const robot::RobotModel& robot = in.robot;
  const Layout& L = in.layout;
  std::vector<double>& x0 = variables->initial;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot.legs.size());
  const double mg = robot.mass * kGravity, mu = in.options.friction;
  const double fmax = in.options.max_normal_force_factor * mg;
  const bool rot_free = robot.base_dof_free[3] || robot.base_dof_free[4] || robot.base_dof_free[5];
  auto v3 = [&](int i) { return Eigen::Vector3d(x0[i], x0[i + 1], x0[i + 2]); };
  // Angular rows are divided by this lever arm so that they weigh like the force rows.
  constexpr double kLever = 0.3;  // m
  constexpr double kRegularisation = 1e-3;
  if (last_knot < 0) last_knot = S;
  for (int k = std::max(0, first_knot); k <= std::min(S, last_knot); ++k) {
    std::vector<int> feet, vars;
    for (int f = 0; f < nf; ++f) {
      const int v = k < S && L.force[f][k][0] >= 0 ? L.force[f][k][0]
                    : k > 0                        ? L.force[f][k - 1][1]
                                                   : -1;
      if (v >= 0) {
        feet.push_back(f);
        vars.push_back(v);
      }
    }
    if (feet.empty()) continue;
    const int n = static_cast<int>(feet.size());
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(12, 3 * n);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(12);
    int rows = 0;
    for (int side = 0; side < 2; ++side) {
      const int s = side == 0 ? k - 1 : k;  // the segment ending (0) or starting (1) at knot k
      if (s < 0 || s >= S) continue;
      const double sigma = side == 0 ? 1.0 : 0.0;
      const double h = x0[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
      const int b0 = L.base[s], b1 = L.base[s + 1];
      Eigen::Vector3d r, acc, e, ed, edd, w, wd;
      hermite<double>(sigma, h, v3(b0), v3(b0 + 3), v3(b1), v3(b1 + 3), &r, nullptr, &acc);
      hermite<double>(sigma, h, v3(b0 + 6), v3(b0 + 9), v3(b1 + 6), v3(b1 + 9), &e, &ed, &edd);
      euler_to_angular<double>(e, ed, edd, &w, &wd);
      const Eigen::Matrix3d R = rotation_zyx<double>(e);
      const Eigen::Matrix3d Iw = R * robot.inertia * R.transpose();
      b.segment<3>(rows) = robot.mass * acc + Eigen::Vector3d(0, 0, mg);
      if (rot_free) b.segment<3>(rows + 3) = (Iw * wd + w.cross(Iw * w)) / kLever;
      for (int i = 0; i < n; ++i) {
        if (!L.contact[feet[i]][s]) continue;
        A.block<3, 3>(rows, 3 * i).setIdentity();
        if (rot_free) {
          const Eigen::Vector3d lever = v3(L.foot_pos[feet[i]][k]) - r;
          Eigen::Matrix3d cross;  // lever x f as a matrix acting on f
          cross << 0, -lever.z(), lever.y(), lever.z(), 0, -lever.x(), -lever.y(), lever.x(), 0;
          A.block<3, 3>(rows + 3, 3 * i) = cross / kLever;
        }
      }
      rows += 6;
    }
    // Nearest to the equal share: min |A f - b|^2 + eps |f - f_equal|^2.
    Eigen::VectorXd f_equal = Eigen::VectorXd::Zero(3 * n);
    for (int i = 0; i < n; ++i) f_equal[3 * i + 2] = mg / n;
    const Eigen::MatrixXd At = A.topRows(rows).transpose();
    const Eigen::MatrixXd N =
        At * A.topRows(rows) + kRegularisation * Eigen::MatrixXd::Identity(3 * n, 3 * n);
    const Eigen::VectorXd f = N.ldlt().solve(At * b.head(rows) + kRegularisation * f_equal);
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d fi = f.segment<3>(3 * i);
      if (!fi.allFinite()) fi = f_equal.segment<3>(3 * i);
      fi.z() = std::clamp(fi.z(), 0.0, fmax);
      const double tangential = fi.head<2>().norm(), limit = mu * fi.z() / std::sqrt(2.0);
      if (tangential > limit) fi.head<2>() *= limit / tangential;
      for (int d = 0; d < 3; ++d) x0[vars[i] + d] = fi[d];
    }
  }
}

}  // namespace terrastride::planner::initialization
