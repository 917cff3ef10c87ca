#include "common/terrain_source.hpp"

#include <algorithm>
#include <filesystem>
#include <sstream>
#include <stdexcept>

#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/terrain_open.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {

TerrainSource load_terrain_source(const std::string& spec, bool smooth_scene,
                                  const std::string& file_hint) {
  terrain::TerrainOpenOptions options;
  options.smooth_scene = smooth_scene;
  options.file_hint = file_hint;
  options.folder_octomap = false;
  TerrainSource t;
  t.spec = spec;
  try {
    terrain::OpenedTerrain opened = terrain::open_terrain({spec}, options);
    t.scene = std::move(opened.scene);
    t.map = std::move(opened.map);
    t.octree = std::move(opened.octree);
  } catch (const terrain::TerrainOpenError& e) {
    throw CommandError(std::string("--terrain ") + e.what());
  }
  return t;
}

collision::CheckTerrain check_terrain_for(const TerrainSource& source,
                                          const robot::RobotModel& model,
                                          const planner::Trajectory& trajectory, double resolution,
                                          bool require_octomap) {
  namespace fs = std::filesystem;
  collision::CheckTerrain view;
  view.field = source.exact();
  try {
    if (source.octree) {
      view.octree = source.octree;
      view.description = "OctoMap " + source.spec + " (" +
                         std::to_string(source.octree->getResolution()) + " m voxels)";
      return view;
    }
    if (!source.scene) {
      const std::string bt = (fs::path(source.spec) / "octomap.bt").string();
      if (!fs::exists(bt)) {
        if (require_octomap)
          throw CommandError("--terrain " + source.spec +
                             ": no octomap.bt (the scan's occupancy map the leg check needs)");
        view.description = "map " + source.spec + " (no octomap.bt: leg capsules not checked)";
        return view;
      }
      try {
        view.octree = collision::read_octomap(bt);
      } catch (const std::runtime_error& e) {
        throw CommandError(std::string("--terrain: ") + e.what());
      }
      view.description = "map " + source.spec + " (scan OctoMap at " +
                         std::to_string(view.octree->getResolution()) + " m)";
      return view;
    }
    view = scene_check_terrain(*source.scene, source.spec, model, trajectory, resolution);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--terrain ") + source.spec + ": " + e.what());
  } catch (const std::invalid_argument& e) {
    throw CommandError(std::string("--terrain ") + source.spec + ": " + e.what());
  }
  return view;
}

collision::CheckTerrain scene_check_terrain(const terrain::Scene& scene, const std::string& name,
                                            const robot::RobotModel& model,
                                            const planner::Trajectory& trajectory,
                                            double resolution) {
  // The scene has no scan: voxelise its exact boxes where the legs go, so the very same FCL
  // check runs on it.
  collision::CheckTerrain view;
  view.field = &scene;
  Eigen::Vector2d lo, hi;
  collision::trajectory_extent(model, trajectory, 0.1, &lo, &hi);
  collision::VoxeliseOptions vo;
  vo.resolution = resolution;
  view.octree = collision::voxelise_scene(scene, lo, hi, vo);
  std::ostringstream d;
  d << "scene " << name << " (exact; voxelised at " << resolution << " m for the leg check)";
  view.description = d.str();
  return view;
}

std::vector<std::string> add_post_hoc_checks(const robot::RobotModel& model,
                                             const collision::CheckTerrain& view,
                                             planner::Trajectory* traj) {
  if (traj->samples.empty()) return {};
  try {
    const collision::CheckReport rep = collision::run_checks(model, *traj, view);
    for (const auto& [k, v] : rep.keys()) traj->checks[k] = v;
    // The quality block's energy proxy comes from the torque check (planner/quality.hpp).
    if (traj->extra.contains("quality") && traj->extra["quality"].is_object())
      traj->extra["quality"]["energy_proxy_J"] = rep.torque.energy_proxy_J;
    const std::vector<std::string> failures = rep.failures();
    traj->extra["post_hoc"] = {
        {"terrain", view.description}, {"failures", failures}, {"wall_s", rep.wall_s}};
    if (rep.trunk) {
      const auto& tr = *rep.trunk;
      traj->extra["post_hoc"]["trunk"] = {
          {"min_distance_m", tr.min_distance},
          {"min_t", tr.min_sample >= 0 ? nlohmann::json(tr.time[tr.min_sample]) : nlohmann::json()},
          {"min_certain_distance_m", tr.min_certain_distance},
          {"collisions_certain", tr.collisions_certain},
          {"contacts_uncertain", tr.contacts_uncertain},
          {"deep_contact_depth_m", tr.deep_contact_depth}};
    } else if (view.octree) {
      traj->extra["post_hoc"]["trunk"] = "not checked: the robot file has no trunk (trunk: none)";
    }
    return failures;
  } catch (const collision::TrajectoryError& e) {
    // A plan the checks cannot interpret (e.g. non-finite numbers from a failed solve): the
    // keys stay absent (never faked), and that is itself a failure.
    traj->extra["post_hoc"] = {{"error", e.what()}};
    return {std::string("the post-hoc checks could not read the plan: ") + e.what()};
  }
}

PlanWithRobot read_plan_with_robot(const std::string& path, const std::string& robot_flag) {
  PlanWithRobot out;
  try {
    out.trajectory = planner::read_plan_file(path);
  } catch (const planner::PlanFileError& e) {
    throw CommandError(e.what());
  }
  const std::string& name = out.trajectory.robot;
  if (!robot_flag.empty()) {
    try {
      out.robot = robot::load_robot(robot::resolve_robot_path(robot_flag));
    } catch (const robot::RobotFileError& e) {
      throw CommandError(std::string("--robot: ") + e.what());
    }
    const std::string& carried = out.trajectory.robot_definition;
    if (!carried.empty() && carried != out.robot.definition)
      throw CommandError("--robot " + robot_flag + " (robot '" + out.robot.name + "', hash " +
                         robot::robot_definition_hash(out.robot.definition) + ") is not the robot " +
                         path + " was planned with ('" + name + "', hash " +
                         robot::robot_definition_hash(carried) +
                         "); leave --robot out to use the plan's own");
    if (carried.empty() && !name.empty() && name != out.robot.name)
      throw CommandError("--robot " + robot_flag + " is robot '" + out.robot.name + "', but " +
                         path + " was planned with robot '" + name + "'");
    return out;
  }
  try {
    out.robot = planner::robot_of_plan(out.trajectory, path);
  } catch (const planner::PlanFileError& e) {
    throw CommandError(e.what());
  } catch (const robot::RobotFileError& e) {
    throw CommandError(path + ": robot: '" + name + "' cannot be loaded: " + e.what() +
                       " (the plan carries no robot definition, as plans made now do: give its "
                       "robot file with --robot FILE)");
  }
  return out;
}

}  // namespace terrastride::service
