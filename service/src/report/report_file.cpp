// The report of a terrain and plans named by files: the report's own generator, which
// `terrastride report` calls once, or once per scan in batch mode (report_file.hpp).
#include "report/report_file.hpp"

#include <filesystem>

#include "report/report.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service::report {

using nlohmann::json;
namespace fs = std::filesystem;

double robot_foot_radius(const std::string& name) {
  try {
    return robot::load_robot(robot::resolve_robot_path(name)).foot_radius;
  } catch (const std::exception& e) {
    throw CommandError("--robot " + name + ": " + e.what());
  }
}

json make_report_file(const std::vector<std::string>& terrain_inputs,
                      const std::vector<std::string>& plan_paths,
                      TerrainInputOptions terrain_options, ReportOptions options,
                      const std::string& out_html) {
  std::vector<PlanInput> plans;
  for (const std::string& path : plan_paths) {
    PlanInput p;
    p.path = path;
    p.name = fs::path(path).filename().string();
    try {
      p.trajectory = planner::read_plan_file(path);
    } catch (const std::exception& e) {
      throw CommandError(std::string("--plan ") + e.what());
    }
    plans.push_back(std::move(p));
  }
  if (!plans.empty() && !plans.front().trajectory.robot_definition.empty()) {
    options.robot = plans.front().trajectory.robot;
    try {
      terrain_options.foot_radius =
          planner::robot_of_plan(plans.front().trajectory, plans.front().path).foot_radius;
    } catch (const std::exception& e) {
      throw CommandError(std::string("--plan ") + e.what());
    }
  } else if (!plans.empty() && !plans.front().trajectory.robot.empty()) {
    options.robot = plans.front().trajectory.robot;
    terrain_options.foot_radius = robot_foot_radius(options.robot);
  }
  // Region the leg-capsule check needs for an analytic scene: where the plans' legs go.
  bool first = true;
  for (const PlanInput& p : plans) {
    robot::RobotModel model;
    try {
      model = !p.trajectory.robot_definition.empty()
                  ? planner::robot_of_plan(p.trajectory, p.path)
                  : robot::load_robot(robot::resolve_robot_path(
                        p.trajectory.robot.empty() ? options.robot : p.trajectory.robot));
    } catch (const std::exception& e) {
      throw CommandError(p.path + ": " + e.what());
    }
    Eigen::Vector2d lo, hi;
    try {
      collision::trajectory_extent(model, p.trajectory, 0.3, &lo, &hi);
    } catch (const std::exception& e) {
      throw CommandError(p.path + ": " + e.what());
    }
    terrain_options.voxel_lo = first ? lo : terrain_options.voxel_lo.cwiseMin(lo);
    terrain_options.voxel_hi = first ? hi : terrain_options.voxel_hi.cwiseMax(hi);
    first = false;
  }
  terrain_options.voxelise_scene = !plans.empty();
  const TerrainView view = load_terrain_view(terrain_inputs, terrain_options);
  json rep = build_report(view, plans, options);
  write_report(rep, out_html);
  return rep;
}

}  // namespace terrastride::service::report
