// The shipped robots as the planner tests use them.
#pragma once

#include <string>
#include <vector>

#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner::testing {

inline robot::RobotModel hyq() { return robot::load_robot(robot::resolve_robot_path("hyq")); }

// Leg names in the robot's order (the feet of a gait timeline).
inline std::vector<std::string> feet_of(const robot::RobotModel& r) {
  std::vector<std::string> f;
  for (const auto& l : r.legs) f.push_back(l.name);
  return f;
}

}  // namespace terrastride::planner::testing
