// plan.json on disk: written atomically (perception::write_file_atomically), read with every
// field validated.
#include "json_reader.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/plan_io.hpp"

namespace terrastride::planner {

void write_plan_file(const std::string& path, const Trajectory& trajectory,
                     const SerialisedSamples* samples) {
  // perception's writer: a regular file (also behind a symbolic link, which stays) is replaced
  // atomically, a FIFO or device is written through, /dev/stdout is the process's descriptor.
  try {
    perception::write_file_atomically(path, plan_text(trajectory, samples));
  } catch (const perception::InputError& e) {
    throw PlanFileError(e.what());
  }
}

Trajectory read_plan_file(const std::string& path) {
  return plan_from_json(io::read_json_file(path, "plan file"), path);
}

robot::RobotModel robot_of_plan(const Trajectory& trajectory, const std::string& source) {
  if (trajectory.robot_definition.empty())
    return robot::load_robot(
        robot::resolve_robot_path(trajectory.robot.empty() ? "hyq" : trajectory.robot));
  robot::RobotModel model;
  try {
    model = robot::parse_robot(trajectory.robot_definition, source + ": robot_file.yaml");
  } catch (const robot::RobotFileError& e) {
    throw PlanFileError(e.what());
  }
  if (model.name != trajectory.robot)
    throw PlanFileError(source + ": robot: '" + trajectory.robot +
                        "' but the robot_file it carries defines robot '" + model.name + "'");
  // The very file of a shipped robot: named by its path, so that its fitted polytopes beside it
  // are found (a re-plan from this plan). Any other definition keeps the plan as its source.
  try {
    const std::string shipped = robot::resolve_robot_path(model.name);
    if (robot::load_robot(shipped).definition == trajectory.robot_definition)
      model.source_file = shipped;
  } catch (const robot::RobotFileError&) {
  }
  return model;
}

}  // namespace terrastride::planner
