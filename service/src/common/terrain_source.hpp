// `--terrain DIR|FILE.bt|SCENE` for `terrastride plan` and `terrastride check`: a folder written
// by `terrastride map`, an OctoMap file (mapped in memory as `terrastride map FILE.bt` maps it),
// or a scene name (docs/design.md §11: the exact analytic terrain). One place
// for both commands, so they read a terrain argument the same way.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {

struct TerrainSource {
  std::string spec;
  std::shared_ptr<const terrain::Scene> scene;     // SCENE: the exact terrain
  std::shared_ptr<const terrain::TerrainMap> map;  // DIR: its map; SCENE: the 2 cm B-spline (if asked)
  // FILE.bt|FILE.ot: the OctoMap itself (the map is built from it in memory); null otherwise (a
  // DIR's octomap.bt is read by check_terrain_for).
  std::shared_ptr<const octomap::OcTree> octree;
  // What the optimiser sees (C2): the map. What the checks use: the scene when there is one.
  const terrain::HeightField* smooth() const { return map.get(); }
  const terrain::HeightField* exact() const {
    return scene ? static_cast<const terrain::HeightField*>(scene.get()) : map.get();
  }
  std::string kind() const { return scene ? "scene" : "map"; }
};

// terrain::open_terrain for one spec (no clouds; a folder's octomap.bt is read by
// check_terrain_for). Throws CommandError naming "--terrain SPEC". `smooth_scene`: also build a
// scene's smooth map (for planning). `file_hint`: the advice given when SPEC is an existing file.
TerrainSource load_terrain_source(const std::string& spec, bool smooth_scene,
                                  const std::string& file_hint);

// The post-hoc checks' view of the terrain: the exact field for footholds; for the leg capsules
// a map's octomap.bt (a CommandError when missing and `require_octomap`, else no capsule check)
// or the scene voxelised at `resolution` over the trajectory's extent.
collision::CheckTerrain check_terrain_for(const TerrainSource& source,
                                          const robot::RobotModel& model,
                                          const planner::Trajectory& trajectory, double resolution,
                                          bool require_octomap);

// An exact scene's view for the post-hoc checks: the scene itself for footholds, and its boxes
// voxelised at `resolution` over the trajectory's extent for the leg capsules.
collision::CheckTerrain scene_check_terrain(const terrain::Scene& scene, const std::string& name,
                                            const robot::RobotModel& model,
                                            const planner::Trajectory& trajectory,
                                            double resolution);

// The post-hoc checks of a plan (docs/design.md: joint torques, leg capsules where `view` has an
// occupancy map, footholds), as `terrastride plan` and the socket's plan run them after every
// solve: their figures join traj->checks, and {"terrain", "failures", "wall_s"} (or {"error"}
// for a plan the checks cannot read) becomes traj->extra["post_hoc"]. Returns the failures
// (one sentence each; empty when every check passed).
std::vector<std::string> add_post_hoc_checks(const robot::RobotModel& model,
                                             const collision::CheckTerrain& view,
                                             planner::Trajectory* traj);

// The voxel size of the post-hoc leg check on an exact scene (`terrastride check --resolution`).
constexpr double kPostHocVoxel = 0.01;

// A plan file and its robot (planner::robot_of_plan: the definition it carries, else the shipped
// robot it names), as `terrastride check PLAN` and `terrastride simulate PLAN` read them.
// `robot_flag` (--robot, optional) names the robot file of a plan that carries none; for a plan
// that carries one it must be that very definition. Throws CommandError naming the file.
struct PlanWithRobot {
  planner::Trajectory trajectory;
  robot::RobotModel robot;
};
PlanWithRobot read_plan_with_robot(const std::string& path, const std::string& robot_flag = "");

}  // namespace terrastride::service
