// "joints"' velocity rows (constraints/joint_velocity.cpp; joint velocities within the robot
// file's limits): Jacobians against central differences, values against an independent
// evaluation (the leg's Jacobian from leg_kinematics, the base's rotation rate by differencing
// its rotation matrix), and no rows for a robot without velocity limits (HyQ).
#include <cmath>

#include "family_test.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

robot::RobotModel go2() { return robot::load_robot(robot::resolve_robot_path("go2")); }

// turning_crawl_options scaled to Go2's legs (0.43 m of thigh and shank to HyQ's 0.69): a turning
// crawl 0.2 m ahead within its reach.
ProblemOptions go2_crawl_options(bool timing) {
  ProblemOptions o = turning_crawl_options(timing);
  o.goal = Eigen::Vector3d(0.2, 0.03, 0.2);
  return o;
}

TEST(JointVelocity, JacobianMatchesCentralDifferences) {
  const auto r = go2();
  ASSERT_TRUE(has_velocity_limits(r));
  // A step low enough for Go2's reach at the initial guess (a step its legs cannot reach puts
  // them at their singular straight pose, where the rows are hundreds of rad/s).
  TanhStep terrain(0.03, 0.15, 0.05, 0.01);
  SrbdProblem p(r, terrain, crawl_timeline(r, 1.2), go2_crawl_options(true));
  const auto pieces = pieces_added_by(p, [&] { build_joint_velocity_rows(p); });
  ASSERT_FALSE(pieces.empty());
  for (const Piece* piece : pieces) EXPECT_EQ(piece->rows(), 3);
  // Small noise: far from the guess the legs near their singular (straight) pose, where the rows
  // reach thousands of rad/s and central differences lose their digits.
  EXPECT_GT(check_kind_derivatives(p, "joint_velocity", 0.002), 0);
  EXPECT_GT(largest_jacobian_entry(p, "joint_velocity"), 0.1);
}

TEST(JointVelocity, KnotRowsAreTheJointVelocitiesOfTheLegsJacobian) {
  const auto r = go2();
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r, 1.2), go2_crawl_options(false));
  const auto pieces = pieces_added_by(p, [&] { build_joint_velocity_rows(p); });
  const Layout& L = p.layout();
  const int S = L.num_segments;
  const std::vector<double> x = perturbed_guess(p, 7, 0.003);
  std::size_t next = 0;
  double worst = 0.0, largest = 0.0;
  for (int f = 0; f < static_cast<int>(r.legs.size()); ++f) {
    for (int k = 0; k <= S; ++k) {
      const Piece& piece = *pieces.at(next++);
      const Eigen::Vector3d base = vec3_at(x, L.base[k]), base_vel = vec3_at(x, L.base[k] + 3);
      const Eigen::Vector3d e = vec3_at(x, L.base[k] + 6), ed = vec3_at(x, L.base[k] + 9);
      const Eigen::Vector3d foot = vec3_at(x, L.foot_pos[f][k]);
      const Eigen::Vector3d foot_vel =
          L.foot_vel[f][k] < 0 ? Eigen::Vector3d::Zero() : vec3_at(x, L.foot_vel[f][k]);
      // d/dt R^T (p_foot - p_base), R's rate by a central difference along the Euler rates.
      const double h = 1e-6;
      const Eigen::Matrix3d R = rotation_of(e);
      const Eigen::Matrix3d Rd = (rotation_of(e + h * ed) - rotation_of(e - h * ed)) / (2 * h);
      const Eigen::Vector3d v_rel =
          Rd.transpose() * (foot - base) + R.transpose() * (foot_vel - base_vel);
      const auto ik = robot::inverse_kinematics(r.legs[f], R.transpose() * (foot - base));
      ASSERT_NE(ik.status, robot::IkStatus::unreachable) << ik.message;
      const Eigen::Vector3d expected = robot::foot_jacobian(r.legs[f], ik.q).inverse() * v_rel;
      const std::vector<double> g = rows_at(piece, x);
      for (int j = 0; j < 3; ++j) {
        worst = std::max(worst, std::abs(g[j] - expected[j]));
        largest = std::max(largest, std::abs(expected[j]));
      }
    }
    // This foot's swing points (base, foot and duration Hermite variables: over 30 each; a knot
    // piece has at most 18).
    while (next < pieces.size() && pieces[next]->vars.size() > 30) ++next;
  }
  EXPECT_GT(largest, 0.05);  // the perturbed point moves the joints
  EXPECT_LT(worst, 1e-6);
}

TEST(JointVelocity, NoRowsForARobotWithoutVelocityLimits) {
  const auto r = hyq();
  ASSERT_FALSE(has_velocity_limits(r));
  FlatField flat;
  SrbdProblem p(r, flat, crawl_timeline(r), turning_crawl_options(false));
  EXPECT_TRUE(pieces_added_by(p, [&] { build_joint_velocity_rows(p); }).empty());
}

}  // namespace
}  // namespace terrastride::planner
