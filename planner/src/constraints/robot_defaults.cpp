// The feasibility defaults that depend on the robot (feasibility.hpp, robot_feasibility_defaults):
// the swing set's acceleration bound from the swing legs' torque budget. HyQ's 100 m/s^2 was an
// absolute number: on ANYmal C (a 3 kg thigh whose centre is 0.25 m from the HFE axis, 80 N m
// motors) a foot at 100 m/s^2 asks its HFE for 1.37 N m per m/s^2, 137 N m; the 'all' plan over
// pallet_21 needed 1.31 x the LF HFE limit in the post-hoc torque check.
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/LU>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {

namespace {
// The share of the saturating acceleration the bound allows (HyQ: 100 of 154 m/s^2), and the
// rounding that keeps a robot's bound a plain number (and HyQ's exactly its 100).
constexpr double kSwingTorqueShare = 0.65;
constexpr double kSwingAccelerationStep = 5.0;  // m/s^2
}  // namespace

double robot_swing_acceleration(const robot::RobotModel& robot) {
  const Eigen::Vector3d gravity(0.0, 0.0, -9.81);
  double saturating = std::numeric_limits<double>::infinity();
  for (const auto& leg : robot.legs) {
    // The foot sphere's centre over the nominal contact point, as the planner's rows place it.
    const robot::IkResult ik =
        robot::inverse_kinematics(leg, leg.nominal_foot + Eigen::Vector3d(0, 0, robot.foot_radius));
    if (ik.status == robot::IkStatus::unreachable)
      throw std::invalid_argument("robot '" + robot.name + "': swing acceleration bound: " +
                                  ik.message);
    const robot::LegDynamicsTerms d =
        robot::dynamics_terms(leg, ik.q, Eigen::Vector3d::Zero(), gravity);
    const Eigen::Matrix3d per_acceleration =
        d.mass_matrix * robot::foot_jacobian(leg, ik.q).inverse();  // N m per m/s^2
    for (int i = 0; i < 3; ++i) {
      const double spare = leg.torque_limit[i] - std::abs(d.gravity[i]);
      if (!(spare > 0))
        throw std::invalid_argument("robot '" + robot.name + "': leg " + leg.name + " joint " +
                                    std::to_string(i) +
                                    ": gravity alone needs the whole torque limit at the nominal "
                                    "stance (no swing acceleration bound)");
      const double per = per_acceleration.row(i).cwiseAbs().sum();
      if (per > 0) saturating = std::min(saturating, spare / per);
    }
  }
  if (!std::isfinite(saturating))
    throw std::invalid_argument("robot '" + robot.name +
                                "': no leg inertia to bound a swing acceleration with");
  const double bound =
      kSwingAccelerationStep * std::round(kSwingTorqueShare * saturating / kSwingAccelerationStep);
  return std::max(kSwingAccelerationStep, bound);
}

FeasibilityOptions robot_feasibility_defaults(const robot::RobotModel& robot) {
  FeasibilityOptions o;
  o.swing_acceleration = robot_swing_acceleration(robot);
  return o;
}

}  // namespace terrastride::planner
