// `terrastride regions --terrain DIR|FILE.bt|SCENE [--robot R]`: where on a map a robot may stand
// and go (terrain::list_safe_regions), with a `terrastride plan` command per region from a
// suggested start to a suggested goal that pass the planner's own refusals before a solve (the
// stances on the map, level reach, the trunk under overhangs, the end stance's reach): a command
// `plan` refuses at once is no suggestion. Pairs that fail are dropped and said so.
#include <cmath>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/plan_request.hpp"
#include "common/terrain_source.hpp"
#include "pasteable.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/before_solve.hpp"
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

// A start and goal the suggested plan command walks between, and the pairs dropped before it.
struct CheckedPair {
  const terrain::RegionPose* start = nullptr;  // null: no suggested pair passes
  const terrain::RegionPose* goal = nullptr;
  struct Dropped {
    const terrain::RegionPose* start;
    const terrain::RegionPose* goal;
    std::string reason;
  };
  std::vector<Dropped> dropped;
};

// The pose as the printed command gives it (pose_text's millimetres and milliradians).
nlohmann::json pose_numbers(const terrain::RegionPose& p) {
  auto r = [](double v) { return std::round(v * 1e3) / 1e3; };
  return nlohmann::json::array({r(p.xy.x()), r(p.xy.y()), r(p.yaw)});
}

// Why `plan --start START --goal GOAL --constraints all` would be refused before its solve, or ""
// when it passes: the same request reader, stance checks and planner pre-checks plan runs.
std::string refusal_before_solve(const robot::RobotModel& model, const TerrainSource& source,
                                 const terrain::RegionPose& start, const terrain::RegionPose& goal) {
  try {
    const nlohmann::json fields = {
        {"start", pose_numbers(start)}, {"goal", pose_numbers(goal)}, {"constraints", "all"}};
    const PlanRequest req = read_plan_request(fields, model);
    check_stances_on_terrain(req, model, *source.exact());
    planner::check_before_solve(model, *source.smooth(), req.options);
  } catch (const RequestFieldError& e) {
    return e.field() + ": " + e.problem();
  } catch (const std::exception& e) {  // UnreachableRequest, RequestError, GaitError
    return e.what();
  }
  return "";
}

// The first suggested pair that passes: the region's start with each of its goals, then each goal
// as the start with the others as goals (a start beside a wall may fail where its goals pass).
CheckedPair check_region_pair(const robot::RobotModel& model, const TerrainSource& source,
                              const terrain::SafeRegion& r) {
  CheckedPair out;
  std::vector<const terrain::RegionPose*> starts{&r.start};
  for (const auto& g : r.goals) starts.push_back(&g.pose);
  for (const terrain::RegionPose* s : starts)
    for (const auto& g : r.goals) {
      if (&g.pose == s) continue;
      const std::string why = refusal_before_solve(model, source, *s, g.pose);
      if (why.empty()) {
        out.start = s;
        out.goal = &g.pose;
        return out;
      }
      out.dropped.push_back({s, &g.pose, why});
    }
  return out;
}

// The command a user pastes, as printed, to plan from the checked start to the checked goal: this
// binary as the shell finds it, the terrain and robot quoted as their names need.
std::string plan_command(const RegionsOptions& o, const CheckedPair& p) {
  if (!p.start) return "";
  std::string cmd = pasteable_program() + " plan --terrain " + shell_word(o.terrain);
  if (o.robot != "hyq") cmd += " --robot " + shell_word(o.robot);
  return cmd + " --start " + pose_text(*p.start) + " --goal " + pose_text(*p.goal) +
         " --constraints all --out plan.json";
}

nlohmann::json listing_json(const RegionsOptions& o, const terrain::RegionListing& l,
                            const std::vector<CheckedPair>& pairs) {
  nlohmann::json regions = nlohmann::json::array();
  for (size_t i = 0; i < l.regions.size(); ++i) {
    const terrain::SafeRegion& r = l.regions[i];
    nlohmann::json dropped = nlohmann::json::array();
    for (const auto& d : pairs[i].dropped)
      dropped.push_back(
          {{"start", pose_json(*d.start)}, {"goal", pose_json(*d.goal)}, {"refused", d.reason}});
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
                       {"plan_command", plan_command(o, pairs[i])},
                       {"plan_pairs_refused_before_solve", dropped}});
  }
  return {{"terrain", o.terrain},       {"robot", o.robot},
          {"foot_radius", l.foot_radius}, {"resolution", l.resolution},
          {"regions_total", l.regions_total}, {"regions_too_small", l.regions_too_small},
          {"standable_cells", l.standable_cells},
          {"regions", regions}};
}

// The commands, each from a start to a goal plan's pre-checks accept, and the pairs they refused.
void print_plan_commands(const RegionsOptions& o, const terrain::RegionListing& listing,
                         const std::vector<CheckedPair>& pairs) {
  if (listing.regions.empty()) return;
  std::cout << "plan commands to paste as printed (--start and --goal are X,Y,YAW, the yaw in "
               "radians; each pair passed plan's checks before a solve, which cannot promise "
               "the solve succeeds):\n";
  for (size_t i = 0; i < listing.regions.size(); ++i) {
    const terrain::SafeRegion& r = listing.regions[i];
    const CheckedPair& p = pairs[i];
    for (const auto& d : p.dropped)
      std::cout << "region " << r.id << ": dropped start " << pose_text(*d.start) << " goal "
                << pose_text(*d.goal) << ", plan refuses it before solving: " << d.reason
                << "\n";
    if (p.start)
      std::cout << "region " << r.id << ": " << plan_command(o, p) << "\n";
    else if (!r.goals.empty())
      std::cout << "region " << r.id << ": no suggested start and goal pass plan's checks\n";
  }
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
  std::vector<CheckedPair> pairs;
  for (const auto& r : listing.regions) pairs.push_back(check_region_pair(model, source, r));
  if (o.json) {
    std::cout << listing_json(o, listing, pairs).dump(2) << "\n";
    return;
  }
  std::cout << terrain::describe_regions(listing);
  print_plan_commands(o, listing, pairs);
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
