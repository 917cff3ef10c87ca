// `terrastride export` (foxglove_export.hpp): the inputs read and checked, then the terrain's
// topics (terrain_topics.hpp), the plan's and the simulation's (robot_topics.hpp) written with the
// MCAP writer of mcap_writer.hpp, and a Foxglove layout beside the file (layout.hpp).
#include "export/foxglove_export.hpp"

#include <octomap/OcTree.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>

#include "export/foxglove_json.hpp"
#include "export/layout.hpp"
#include "export/robot_topics.hpp"
#include "export/terrain_topics.hpp"
#include "report/terrain_input.hpp"
#include "common/terrain_source.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/json_input.hpp"
#include "terrastride/planner/options.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service::foxglove {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string layout_path(const ExportOptions& o) {
  if (!o.layout.empty()) return o.layout;
  return (fs::path(o.out).parent_path() / (fs::path(o.out).stem().string() + ".layout.json"))
      .string();
}

void check_options(const ExportOptions& o) {
  if (o.terrain.empty()) throw CommandError("--terrain is required");
  for (const auto& t : o.terrain)
    if (perception::is_bag_file(t))
      throw CommandError("--terrain " + t +
                         ": a recording is mapped first (`terrastride map BAG --topic T --frame F "
                         "--out DIR`), then exported with `--terrain DIR --bag-frame F`");
  if (!o.sim.empty() && o.plan.empty())
    throw CommandError("--sim " + o.sim + ": a simulation is drawn beside its plan; give --plan");
  if (o.compression != "zstd" && o.compression != "none")
    throw CommandError("--compression " + o.compression + ": zstd or none");
  if (fs::path(o.out).extension() != ".mcap")
    throw CommandError("--out " + o.out + ": the export is an .mcap file");
  if (!std::isnan(o.start_time) && !(o.start_time >= 0 && o.start_time < 1e10))
    throw CommandError("--start-time: seconds since 1970 (0 .. 1e10), got " +
                       std::to_string(o.start_time));
  if (o.max_points == 0) throw CommandError("--max-points: at least 1");
  if (fs::path(layout_path(o)).extension() != ".json")
    throw CommandError("--layout " + o.layout + ": the layout is a .json file");
  try {
    perception::check_output_file(o.out);
    perception::check_output_file(layout_path(o));
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out/--layout: ") + e.what());
  }
}

// The plan must have been made on this terrain: the terrain it names (plan --terrain) is the one
// given, by scene name or by folder (same file on disk).
void check_plan_terrain(const planner::Trajectory& traj, const std::string& plan_path,
                        const std::vector<std::string>& terrain) {
  if (!traj.extra.contains("terrain") || !traj.extra["terrain"].is_string()) return;
  const std::string named = traj.extra["terrain"].get<std::string>();
  if (terrain.size() == 1) {
    std::error_code ec;
    if (named == terrain[0]) return;
    if (fs::exists(named, ec) && fs::exists(terrain[0], ec) &&
        fs::equivalent(named, terrain[0], ec))
      return;
  }
  std::string given;
  for (const auto& t : terrain) given += (given.empty() ? "" : " ") + t;
  throw CommandError("--plan " + plan_path + ": it was planned on terrain '" + named +
                     "', not on --terrain " + given +
                     " (export a plan with the terrain it was made for)");
}

json read_simulation(const std::string& path, size_t feet) {
  const std::string text = read_text(path);
  if (text.empty()) throw CommandError("--sim " + path + ": missing or empty");
  json sim;
  try {
    sim = perception::parse_json_input(text);
  } catch (const std::exception& e) {
    throw CommandError("--sim " + path + ": not JSON: " + e.what());
  }
  if (!sim.is_object() || !sim.contains("samples") || !sim["samples"].is_array() ||
      sim["samples"].empty())
    throw CommandError(
        "--sim " + path +
        ": no \"samples\" (write it with `terrastride simulate PLAN --out sim.json`)");
  for (const json& s : sim["samples"])
    if (!s.is_object() || !s.contains("t") || !s.contains("base") || !s.contains("feet") ||
        !s["feet"].is_array() || s["feet"].size() != feet)
      throw CommandError("--sim " + path + ": its samples do not have the plan's " +
                         std::to_string(feet) + " feet (a simulation of another plan?)");
  return sim;
}

// A plan whose feet are nowhere on this terrain was made for another one.
void check_plan_on_view(const planner::Trajectory& traj, const std::string& plan_path,
                        const report::TerrainView& view) {
  const Eigen::Vector2d lo = view.origin,
                        hi = view.origin + view.resolution * Eigen::Vector2d(view.nx, view.ny);
  int outside = 0, total = 0;
  for (const auto& s : traj.samples)
    for (const auto& f : s.feet) {
      ++total;
      if (f.position.x() < lo.x() || f.position.y() < lo.y() || f.position.x() > hi.x() ||
          f.position.y() > hi.y())
        ++outside;
    }
  if (total > 0 && outside == total)
    throw CommandError("--plan " + plan_path + ": none of its feet is on the terrain (x " +
                       std::to_string(lo.x()) + ".." + std::to_string(hi.x()) + ", y " +
                       std::to_string(lo.y()) + ".." + std::to_string(hi.y()) +
                       "): a plan for another terrain?");
}

// t = 0 is the first cloud's stamp of a recording (the plan starts at its last: the robot plans
// on what it has seen), --start-time, or kDefaultEpoch.
Clock make_clock(const ExportOptions& o, const std::vector<SensorInput>& sensors) {
  Clock clock;
  uint64_t first = UINT64_MAX, last = 0;
  for (const auto& s : sensors)
    if (s.has_stamp) {
      first = std::min(first, s.stamp_ns);
      last = std::max(last, s.stamp_ns);
    }
  if (!std::isnan(o.start_time)) {
    clock.epoch_ns = static_cast<uint64_t>(std::llround(o.start_time * 1e9));
  } else if (first != UINT64_MAX) {
    clock.epoch_ns = first;
  } else {
    clock.epoch_ns = static_cast<uint64_t>(kDefaultEpoch) * 1000000000ull;
  }
  if (first != UINT64_MAX) clock.plan_offset_s = 1e-9 * static_cast<double>(last - first);
  return clock;
}

// The friction coefficient the plan was made with (plan.json "feasibility_settings" or the
// planner's default), for the friction-cone margins.
double plan_friction(const planner::Trajectory& traj) {
  for (const char* key : {"friction", "mu"})
    if (traj.extra.contains(key) && traj.extra[key].is_number())
      return traj.extra[key].get<double>();
  return planner::ProblemOptions{}.friction;
}

}  // namespace

ExportSummary export_foxglove(const ExportOptions& o) {
  check_options(o);
  // Inputs: the plan (and the robot it names), the simulation, then the terrain.
  std::optional<PlanWithRobot> plan;
  if (!o.plan.empty()) {
    if (!fs::exists(o.plan)) throw CommandError("--plan " + o.plan + ": no such file");
    plan = read_plan_with_robot(o.plan);
    check_plan_terrain(plan->trajectory, o.plan, o.terrain);
  }
  json sim;
  if (!o.sim.empty()) sim = read_simulation(o.sim, plan->trajectory.feet.size());
  robot::RobotModel model;
  try {
    model = plan ? plan->robot : robot::load_robot(robot::resolve_robot_path("hyq"));
  } catch (const std::exception& e) {
    throw CommandError(std::string("robot hyq: ") + e.what());
  }
  report::TerrainInputOptions topts;
  topts.radii = o.radii;
  topts.resolution = o.resolution;
  topts.foot_radius = model.foot_radius;
  topts.voxelise_scene = static_cast<bool>(plan);
  if (plan) {
    try {
      collision::trajectory_extent(model, plan->trajectory, 0.3, &topts.voxel_lo, &topts.voxel_hi);
    } catch (const std::exception& e) {
      throw CommandError("--plan " + o.plan + ": " + e.what());
    }
  }
  const report::TerrainView view = report::load_terrain_view(o.terrain, topts);
  if (plan) check_plan_on_view(plan->trajectory, o.plan, view);
  collision::CheckReport checks;
  if (plan) {
    collision::CheckTerrain ct;
    ct.field = view.field.get();
    ct.octree = view.octree;
    ct.description = view.source;
    try {
      checks = collision::run_checks(model, plan->trajectory, ct);
    } catch (const std::exception& e) {
      throw CommandError("--plan " + o.plan + ": " + e.what());
    }
  }

  // The clouds the terrain came from: the files themselves, or a map folder's inputs.
  const std::vector<SensorInput> sensors = sensor_inputs(view.info);
  CloudInputs clouds;
  clouds.bag_frame = o.bag_frame;
  if (view.kind == "clouds") clouds.files = o.terrain;
  if (view.kind == "map") clouds.recorded = sensors;
  const Clock clock = make_clock(o, sensors);

  Publisher pub(o.compression);
  if (plan) add_robot_schemas(pub, model);
  const TerrainTopicStats ts = publish_terrain(pub, clock, view, model.foot_radius, o.max_voxels);
  TerrainTopicStats cs = ts;
  publish_clouds(pub, clock, clouds, sensors, o.max_points, &cs);
  ExportSummary summary;
  const double friction = plan ? plan_friction(plan->trajectory) : 0.0;
  if (plan) {
    const RobotTopicStats ps =
        publish_plan(pub, clock, model, plan->trajectory, checks, view, friction);
    summary.footholds = ps.footholds;
    summary.shin_contacts = ps.shin_contacts;
    summary.logs += ps.logs;
    summary.duration_s = plan->trajectory.samples.empty() ? 0.0 : plan->trajectory.samples.back().t;
  }
  if (!sim.is_null())
    summary.logs +=
        publish_simulation(pub, clock, model, sim, o.sim, view.field.get(), friction).logs;

  const std::string bytes = pub.writer().finish();
  summary.messages_per_topic = pub.messages_per_topic();
  summary.messages = pub.writer().message_count();
  summary.chunks = pub.writer().chunk_count();
  summary.bytes = bytes.size();
  summary.voxels = ts.voxels;
  summary.voxel_messages = ts.voxel_messages;
  summary.relief_triangles = ts.relief_triangles;
  summary.relief_cells = ts.relief_cells;
  summary.grid_decimation = ts.grid_decimation;
  summary.points = cs.points;
  summary.points_in = cs.points_in;
  summary.largest_message = pub.largest_message();
  summary.largest_topic = pub.largest_topic();
  summary.epoch_s = 1e-9 * static_cast<double>(clock.epoch_ns);
  summary.layout = layout_path(o);
  const json layout = foxglove_layout(model, static_cast<bool>(plan), !sim.is_null());
  try {
    perception::write_file_atomically(o.out, bytes);
    perception::write_file_atomically(summary.layout, layout.dump(2) + "\n");
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out/--layout: ") + e.what());
  }
  return summary;
}

}  // namespace terrastride::service::foxglove
