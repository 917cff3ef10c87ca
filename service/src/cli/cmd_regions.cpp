// `terrastride regions --terrain DIR|FILE.bt|SCENE [--robot R]`: where on a map a robot may stand
// and go (terrain::list_safe_regions), with a `terrastride plan` command per region that starts
// at its suggested start and walks to its first goal.
#include <cmath>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/terrain_source.hpp"
#include "pasteable.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/regions.hpp"

namespace terrastride::service {
namespace {

struct RegionsOptions {
  std::string terrain;
  std::string robot = "hyq";
  double foot_radius = 0.0;
  bool foot_radius_given = false;  // else: the robot's
  size_t max_regions = 10;
  double goal_distance = 1.0;
  double min_area = 0.05;
  bool json = false;
};

std::string pose_text(const terrain::RegionPose& p) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(3) << p.xy.x() << "," << p.xy.y() << "," << p.yaw;
  return os.str();
}

nlohmann::json pose_json(const terrain::RegionPose& p) {
  return {{"x", p.xy.x()}, {"y", p.xy.y()}, {"yaw", p.yaw}, {"height", p.height}};
}

// The command a user pastes, as printed, to plan from a region's start to its first goal: this
// binary as the shell finds it, the terrain and robot quoted as their names need.
std::string plan_command(const RegionsOptions& o, const terrain::SafeRegion& r) {
  if (r.goals.empty()) return "";
  std::string cmd = pasteable_program() + " plan --terrain " + shell_word(o.terrain);
  if (o.robot != "hyq") cmd += " --robot " + shell_word(o.robot);
  return cmd + " --start " + pose_text(r.start) + " --goal " + pose_text(r.goals.front().pose) +
         " --constraints all --out plan.json";
}

nlohmann::json listing_json(const RegionsOptions& o, const terrain::RegionListing& l) {
  nlohmann::json regions = nlohmann::json::array();
  for (const auto& r : l.regions) {
    nlohmann::json goals = nlohmann::json::array();
    for (const auto& g : r.goals)
      goals.push_back({{"pose", pose_json(g.pose)}, {"path_length_m", g.path_length}});
    regions.push_back({{"id", r.id},
                       {"cells", r.cells},
                       {"area_m2", r.area_m2},
                       {"bounds", {{r.lo.x(), r.lo.y()}, {r.hi.x(), r.hi.y()}}},
                       {"length_m", r.length_m},
                       {"width_m", r.width_m},
                       {"axis_yaw", r.axis_yaw},
                       {"ground_z", {r.height_min, r.height_max}},
                       {"start", pose_json(r.start)},
                       {"start_border_m", r.start_border_m},
                       {"goals", goals},
                       {"plan_command", plan_command(o, r)}});
  }
  return {{"terrain", o.terrain},       {"robot", o.robot},
          {"foot_radius", l.foot_radius}, {"resolution", l.resolution},
          {"regions_total", l.regions_total}, {"regions_too_small", l.regions_too_small},
          {"standable_cells", l.standable_cells},
          {"regions", regions}};
}

void run_regions(const RegionsOptions& o) {
  robot::RobotModel model;
  try {
    model = robot::load_robot(robot::resolve_robot_path(o.robot));
  } catch (const std::exception& e) {
    throw CommandError(std::string("--robot: ") + e.what());
  }
  if (!(o.goal_distance > 0 && o.goal_distance <= 100))
    throw CommandError("--goal-distance: must be within (0, 100] m");
  if (o.foot_radius_given && !(o.foot_radius >= 0 && o.foot_radius <= 0.5))
    throw CommandError("--foot-radius: must be within [0, 0.5] m");
  TerrainSource source =
      load_terrain_source(o.terrain, /*smooth_scene=*/true, map_it_first(o.terrain));
  terrain::RegionOptions ro;
  for (const auto& leg : model.legs) ro.footprint.feet.push_back(leg.nominal_foot.head<2>());
  ro.footprint.foot_radius = o.foot_radius_given ? o.foot_radius : model.foot_radius;
  // The trunk's reach and half its clearance above flat ground in the nominal stance bound the
  // ground beside the stance (a wall, a high step).
  if (model.trunk) {
    const Eigen::Vector3d h = model.trunk->half_size();
    ro.footprint.body_half = model.trunk->center.head<2>().cwiseAbs() + h.head<2>();
    ro.footprint.max_rise =
        0.5 * std::max(0.0, model.nominal_base_height + model.trunk->center.z() - h.z());
  }
  ro.max_regions = o.max_regions;
  ro.goal_distance = o.goal_distance;
  ro.min_area = o.min_area;
  terrain::RegionListing listing;
  try {
    listing = terrain::list_safe_regions(*source.map, ro);
  } catch (const perception::InputError& e) {
    throw CommandError(e.what());
  }
  if (o.json) {
    std::cout << listing_json(o, listing).dump(2) << "\n";
    return;
  }
  std::cout << terrain::describe_regions(listing);
  if (!listing.regions.empty())
    std::cout << "plan commands to paste as printed (--start and --goal are X,Y,YAW, the yaw in "
                 "radians):\n";
  for (const auto& r : listing.regions) {
    const std::string cmd = plan_command(o, r);
    if (!cmd.empty()) std::cout << "region " << r.id << ": " << cmd << "\n";
  }
}

}  // namespace

void add_regions_command(CLI::App& app) {
  auto o = std::make_shared<RegionsOptions>();
  CLI::App* cmd = app.add_subcommand(
      "regions",
      "List where a robot may stand and go on a map: the connected regions of safe ground its "
      "stance fits on, largest first, each with a start pose, goals and a plan command");
  cmd->add_option("--terrain", o->terrain,
                  "terrain: a folder written by `terrastride map`, an OctoMap (.bt/.ot) or a "
                  "scene name")
      ->required();
  cmd->add_option("--robot", o->robot, "robot name or robot file")->capture_default_str();
  cmd->add_option("--foot-radius", o->foot_radius,
                  "foot radius whose safety layer judges the feet (m; default: the robot's)");
  cmd->add_option("--max-regions", o->max_regions, "list at most this many, the largest")
      ->capture_default_str()
      ->check(CLI::Range(size_t{1}, size_t{1000}));
  cmd->add_option("--goal-distance", o->goal_distance,
                  "distance of the suggested goals from the start along the region (m)")
      ->capture_default_str();
  cmd->add_option("--min-area", o->min_area,
                  "leave out regions of fewer base positions than this area (m2)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1e6));
  cmd->add_flag("--json", o->json, "print JSON instead of text");
  cmd->callback([o, cmd] {
    o->foot_radius_given = cmd->count("--foot-radius") > 0;
    run_regions(*o);
  });
}

}  // namespace terrastride::service
