// The robot geometry the planner and the post-hoc checks share (robot/geometry.hpp): the ZYX
// rotation against Eigen's angle-axis product, the inverse kinematics against the forward
// kinematic chain, the knee against the chain's knee, and the checks' IK and knee being the
// planner's.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <string>

#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::robot {
namespace {

RobotModel hyq() {
  return load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml");
}

TEST(Geometry, RotationZyxIsTheAngleAxisProduct) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> angle(-3.0, 3.0);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d e(angle(rng), 0.5 * angle(rng), angle(rng));
    const Eigen::Matrix3d expected = (Eigen::AngleAxisd(e[0], Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(e[1], Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(e[2], Eigen::Vector3d::UnitX()))
                                         .toRotationMatrix();
    const Eigen::Matrix3d R = rotation_zyx(e);
    EXPECT_LT((R - expected).cwiseAbs().maxCoeff(), 1e-15);
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-15);
  }
}

// Within reach, the planner's joint angles (leg_joint_angles) are the checks' inverse kinematics
// to the last bit, and put the foot where it was asked to be (forward kinematic chain).
TEST(Geometry, JointAnglesAreTheInverseKinematicsOfTheChain) {
  const RobotModel r = hyq();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int checked = 0;
  for (const LegModel& leg : r.legs)
    for (int i = 0; i < 300; ++i) {
      Eigen::Vector3d q;
      for (int j = 0; j < 3; ++j) q[j] = leg.q_min[j] + unit(rng) * (leg.q_max[j] - leg.q_min[j]);
      const Eigen::Vector3d foot = foot_position(leg, q);
      const IkResult ik = inverse_kinematics(leg, foot);
      if (ik.status == IkStatus::unreachable) continue;
      const Eigen::Vector3d angles = leg_joint_angles<double>(leg, foot);
      const LegPlane<double> p = leg_plane<double>(leg, foot);
      if (std::abs(p.cos_knee) < 1.0 - 1e-6) {  // not clamped
        EXPECT_EQ(angles, ik.q) << leg.name;
      }
      EXPECT_LT((foot_position(leg, ik.q) - foot).norm(), 1e-12) << leg.name;
      ++checked;
    }
  EXPECT_GT(checked, 1000);
}

// Beyond reach the planner's angles are the stretched knee's (finite), the checks' IK says so.
TEST(Geometry, BeyondReachTheKneeIsStretched) {
  const RobotModel r = hyq();
  const LegModel& lf = r.legs[0];
  const Eigen::Vector3d far = lf.haa_origin + Eigen::Vector3d(0, 0, -1.2);
  EXPECT_EQ(inverse_kinematics(lf, far).status, IkStatus::unreachable);
  const Eigen::Vector3d q = leg_joint_angles<double>(lf, far);
  EXPECT_TRUE(q.allFinite());
  EXPECT_NEAR(std::abs(q[2]), std::acos(1.0 - 1e-6), 1e-12);
}

// The knee formula is the chain's knee: l1 from the HFE joint and l2 from the foot.
TEST(Geometry, KneeIsTheChainsKnee) {
  const RobotModel r = hyq();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (const LegModel& leg : r.legs)
    for (int i = 0; i < 100; ++i) {
      Eigen::Vector3d q;
      for (int j = 0; j < 3; ++j) q[j] = leg.q_min[j] + unit(rng) * (leg.q_max[j] - leg.q_min[j]);
      const Eigen::Vector3d knee = knee_in_base<double>(leg, q);
      EXPECT_EQ(knee_position(leg, q), knee);
      EXPECT_NEAR((knee - hfe_position(leg, q)).norm(), leg.l1, 1e-12) << leg.name;
      EXPECT_NEAR((foot_position(leg, q) - knee).norm(), leg.l2, 1e-12) << leg.name;
      // The planner's thigh (constraints/thigh.cpp) runs from the chain's HFE joint.
      EXPECT_NEAR((hfe_in_base<double>(leg, q) - hfe_position(leg, q)).norm(), 0.0, 1e-12)
          << leg.name;
    }
}

TEST(Geometry, ShinExclusionIsTheFootSphereTheShinsCapAndTheMargin) {
  const RobotModel r = hyq();
  for (const LegModel& leg : r.legs) {
    EXPECT_DOUBLE_EQ(shin_exclusion(r, leg), 2 * r.foot_radius + leg.shin_radius + 0.01);
    EXPECT_DOUBLE_EQ(shin_exclusion(r, leg, 0.02), 2 * r.foot_radius + leg.shin_radius + 0.02);
  }
}

}  // namespace
}  // namespace terrastride::robot
