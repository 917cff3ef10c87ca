// Dense checks of a plan: every constraint of the formulation evaluated along the whole
// trajectory (docs/design.md §6.8: every 2 ms), against the EXACT terrain rather than the
// smoothed one the optimiser saw.
#pragma once

#include <map>
#include <string>

#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

struct DenseCheckLimits {
  double friction = 0.5;         // pyramid coefficient
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

}  // namespace terrastride::planner
