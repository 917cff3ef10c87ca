// The planner defaults that follow the robot: the swing set's acceleration bound from
// the swing legs' torque budget (feasibility.hpp, robot_swing_acceleration) and the number of
// gait cycles for a goal (planner.hpp, default_cycles). HyQ's stay what they were.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/LU>
#include <array>
#include <cmath>
#include <string>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {
namespace {

robot::RobotModel shipped(const std::string& name) {
  return robot::load_robot(robot::resolve_robot_path(name));
}

// The largest |tau_i| / tau_max_i of any leg and joint at the nominal stance when the swing foot
// accelerates at `a` in every component (the 8 corners of the bound's box), by recursive
// Newton-Euler (an evaluation independent of the bound's M J^-1).
double worst_torque_ratio(const robot::RobotModel& r, double a) {
  double worst = 0.0;
  for (const auto& leg : r.legs) {
    const auto ik = robot::inverse_kinematics(leg, leg.nominal_foot + Eigen::Vector3d(0, 0, r.foot_radius));
    EXPECT_TRUE(ik.ok()) << ik.message;
    const Eigen::Matrix3d jinv = robot::foot_jacobian(leg, ik.q).inverse();
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d acc(corner & 1 ? a : -a, corner & 2 ? a : -a, corner & 4 ? a : -a);
      const Eigen::Vector3d tau = robot::inverse_dynamics(leg, ik.q, Eigen::Vector3d::Zero(),
                                                          jinv * acc, Eigen::Vector3d(0, 0, -9.81));
      worst = std::max(worst, tau.cwiseAbs().cwiseQuotient(leg.torque_limit).maxCoeff());
    }
  }
  return worst;
}

TEST(RobotDefaults, SwingAccelerationFollowsTheSwingLegsTorque) {
  // HyQ's 100 m/s^2 unchanged (the constant the other robots are measured by).
  EXPECT_EQ(robot_swing_acceleration(shipped("hyq")), 100.0);
  EXPECT_EQ(feasibility_options(shipped("hyq"), {}).swing_acceleration,
            FeasibilityOptions{}.swing_acceleration);
  // HyQ's LF leg on a slider, its nominal foot right below the HAA joint instead of 8 cm outward:
  // its HAA moves less of the leg's inertia there (was 100 as a constant).
  EXPECT_EQ(robot_swing_acceleration(shipped("monoped")), 105.0);
  // ANYmal C's heavy thigh on 80 N m motors: far less than HyQ's; Go2's light legs: more.
  EXPECT_EQ(robot_swing_acceleration(shipped("anymal_c")), 35.0);
  EXPECT_EQ(robot_swing_acceleration(shipped("go2")), 135.0);
  for (const char* name : {"hyq", "go2", "anymal_c"}) {
    const auto r = shipped(name);
    const double bound = robot_swing_acceleration(r);
    // At the bound a swing leg uses about two thirds of a joint's torque (0.65, rounding to
    // 5 m/s^2 included); 5 % beyond the saturating acceleration (bound / 0.65), some joint is
    // past its limit: the bound is the robot's, not a fixed number.
    EXPECT_LE(worst_torque_ratio(r, bound), 0.70) << name;
    EXPECT_GE(worst_torque_ratio(r, bound), 0.60) << name;
    EXPECT_GT(worst_torque_ratio(r, 1.05 * bound / 0.65), 1.0) << name;
  }
  // A setting still wins over the robot's default.
  EXPECT_EQ(feasibility_options(shipped("anymal_c"), {{"swing_acceleration", 25.0}}).swing_acceleration,
            25.0);
  EXPECT_THROW(feasibility_options(shipped("anymal_c"), {{"swing_acceleration", -1.0}}),
               std::invalid_argument);
}

TEST(RobotDefaults, CyclesCoverTheGoalInStridesOfTheRangeOfMotionBox) {
  const auto hyq = shipped("hyq"), go2 = shipped("go2"), anymal = shipped("anymal_c");
  const Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  // HyQ (box 0.5 m long): its benchmark and off-path goals keep the 3 cycles they were planned in.
  for (const Eigen::Vector3d& goal : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(1.5, 0, 0),
                                     Eigen::Vector3d(1, 0.3, 0.5), Eigen::Vector3d(0.8, -0.25, -0.4),
                                     Eigen::Vector3d(0, 0, 0)})
    EXPECT_EQ(default_cycles(hyq, origin, goal), 3) << goal.transpose();
  EXPECT_EQ(default_cycles(hyq, origin, Eigen::Vector3d(2, 0, 0)), 4);
  // Go2's box is 0.308 m long: 1 m is 3.2 strides, 4 cycles; ANYmal C's 0.457 m: 3.
  EXPECT_NEAR(2 * go2.legs[0].range_of_motion.x(), 0.308, 1e-3);
  EXPECT_EQ(default_cycles(go2, origin, Eigen::Vector3d(1, 0, 0)), 4);
  EXPECT_EQ(default_cycles(go2, Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(1, 1.5, 3)), 3);
  EXPECT_EQ(default_cycles(anymal, origin, Eigen::Vector3d(1, 0, 0)), 3);
  // A far goal is capped at the request limit (the horizon check then names it).
  EXPECT_EQ(default_cycles(go2, origin, Eigen::Vector3d(900, 0, 0)), 50);
}

}  // namespace
}  // namespace terrastride::planner
