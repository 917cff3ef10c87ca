// A Foxglove / Lichtblick layout for an export (Layouts -> Import from file): a 3-D panel that
// follows the planned base, plots of the joint torques against their limits, the foot forces and
// margins (and the tracking error with a simulation), and the /log panel.
#pragma once

#include <nlohmann/json.hpp>

#include "terrastride/robot/robot_model.hpp"

namespace terrastride::service::foxglove {

nlohmann::json foxglove_layout(const robot::RobotModel& model, bool has_plan, bool has_sim);

}  // namespace terrastride::service::foxglove
