// The robot's Foxglove topics (docs/export.md): /tf frames per link (map -> base -> each leg's
// hip, thigh and shin, from the joint angles), the links as primitives in those frames, contact
// forces, the numbers to plot (joint angles, velocities, torques against their limits; foot
// forces, friction-cone and force-polytope margins; tracking errors) and the checks' and the
// simulation's findings as foxglove.Log messages at the time they occur.
#pragma once

#include <string>

#include "export/foxglove_json.hpp"
#include "report/report.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::service::foxglove {

struct RobotTopicStats {
  size_t footholds = 0;
  size_t shin_contacts = 0;  // samples x legs whose shin touches an occupied voxel
  size_t logs = 0;           // foxglove.Log messages on /log
};

// The export's own message schemas (terrastride.JointStates, terrastride.FootStates,
// terrastride.Tracking, terrastride.Verdict): plain JSON objects of numbers keyed by leg and
// joint, so Foxglove's Plot panel plots e.g. /plan/joints.LF.kfe.torque.
void add_robot_schemas(Publisher& pub, const robot::RobotModel& model);

// The plan: /tf, /plan/robot, /plan/contact_forces, /plan/footholds, /plan/shin_contacts,
// /plan/base_path, /plan/joints, /plan/feet, /plan/verdict and /log. `friction` is the friction
// coefficient the margins are measured with.
RobotTopicStats publish_plan(Publisher& pub, const Clock& clock, const robot::RobotModel& model,
                             const planner::Trajectory& traj, const collision::CheckReport& checks,
                             const report::TerrainView& view, double friction);

// The simulation (`terrastride simulate --out sim.json`, read as JSON): /tf under the sim_
// prefix, /sim/robot, /sim/contact_forces, /sim/joints, /sim/feet, /sim/tracking, /sim/verdict
// and its findings on /log. Throws CommandError naming `path` on a malformed file.
// The feet's margins are measured on `field` (may be null) with `friction`, as the plan's.
RobotTopicStats publish_simulation(Publisher& pub, const Clock& clock,
                                   const robot::RobotModel& model, const nlohmann::json& sim,
                                   const std::string& path, const terrain::HeightField* field,
                                   double friction);

}  // namespace terrastride::service::foxglove
