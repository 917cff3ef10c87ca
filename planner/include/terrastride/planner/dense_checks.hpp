// Dense checks of a plan: every constraint of the formulation evaluated along the whole
// trajectory (docs/design.md §6.8: every 2 ms), against the EXACT terrain rather than the
// smoothed one the optimiser saw.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

struct DenseCheckLimits {
  double friction = 0.5;          // pyramid coefficient
  double max_normal_force = 0.0;  // N; <= 0: no upper bound checked
};

// `dense` must be sampled finely (every 2 ms for the reported figures). Returns the plan.json
// "checks" keys: dynamics_linear_max_N (over the robot's free linear directions),
// dynamics_angular_max_Nm (only when the base may rotate), penetration_max_m (swing feet below the
// terrain), friction_violation_max_N (pyramid in the terrain normal frame, 0 <= f_n <= f_max),
// slip_max_m (stance foot displacement from touch-down), range_of_motion_excess_max_m; plus
// stance_height_error_max_m (|stance foot height - terrain height|).
std::map<std::string, double> dense_checks(const robot::RobotModel& robot,
                                           const terrain::HeightField& terrain,
                                           const Trajectory& dense, const DenseCheckLimits& limits);

// One instant of a solution for joint rows: foot `foot` at fraction `sigma` of segment `segment`
// (Layout's segments), and the rows that instant needs: the joint angles within their ranges, the
// joint velocities within their limits, the contact force within the leg's force polytope (the
// torques; stance segments only).
struct JointPoint {
  int foot = 0;
  int segment = 0;
  double sigma = 0.0;
  bool range = false;
  bool velocity = false;
  bool torque = false;
};

// Every leg of `robot` has torque limits (> 0 for each joint).
bool has_torque_limits(const robot::RobotModel& robot);

// The joints of a solution checked densely, on the splines themselves (not on a sampled plan):
// every segment at steps of at most `max_dt` seconds (both ends included), each leg's angles by
// robot::inverse_kinematics (as the post-hoc check) and its velocities as the "joint_velocity"
// rows compute them (the foot's velocity relative to the base through the leg's inverse
// Jacobian; robots whose every leg has velocity limits only), and in stance its torques as the
// post-hoc torque check computes them (collision::check_joint_torques: the leg's inverse dynamics
// with the contact force and the base's acceleration as apparent gravity, the joint
// accelerations as central differences of the velocities on the check's grid; robots whose every
// leg has torque limits only).
struct JointDenseCheck {
  double range_excess_rad = 0.0;  // largest angle beyond a joint's range (0: none)
  double velocity_ratio = 0.0;    // largest |q'| / q'_lim (0: no velocity limits)
  double torque_ratio = 0.0;      // largest |tau| / tau_lim in stance (0: no torque limits)
  // Where each largest one is (-1: nowhere): the foot, the joint (0 HAA, 1 HFE, 2 KFE), the time.
  int range_foot = -1, range_joint = -1, velocity_foot = -1, velocity_joint = -1;
  int torque_foot = -1, torque_joint = -1;
  double range_t = 0.0, velocity_t = 0.0, torque_t = 0.0;
  int samples = 0;  // instants checked per foot
  // Per (segment, foot), in segment then foot order: the worst instant of its angles beyond
  // their ranges, that of its velocities above their limits and that of its torques above
  // theirs, where it has such (one point with several rows where they coincide).
  std::vector<JointPoint> violations;
};
JointDenseCheck dense_joint_check(const SrbdProblem& problem, const std::vector<double>& x,
                                  double max_dt);

}  // namespace terrastride::planner
