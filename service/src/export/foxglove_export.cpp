// `terrastride export` (foxglove_export.hpp): the report's terrain view and post-hoc checks turned
// into Foxglove messages, written with the MCAP writer of mcap_writer.hpp.
#include "export/foxglove_export.hpp"

#include <octomap/OcTree.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>

#include "export/mcap_writer.hpp"
#include "report/terrain_input.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/robot/geometry.hpp"
#include "terrastride/service/cli.hpp"
#include "common/terrain_source.hpp"

namespace terrastride::service::foxglove {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

#define FOXGLOVE_SCHEMA(name, text) {name, text},
const std::map<std::string, std::string> kSchemas = {
#include "export/foxglove_schemas.inc"
};
#undef FOXGLOVE_SCHEMA

constexpr const char* kMapFrame = "map";
constexpr double kArrowMetresPerNewton = 1.0 / 1000.0;  // a 500 N foot force: a 0.5 m arrow

std::string base64(const std::string& bytes) {
  static const char* kAlphabet =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8) | uint8_t(bytes[i + 2]);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = uint8_t(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v = (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

uint64_t to_ns(double t) {
  return static_cast<uint64_t>(std::llround(std::max(0.0, t) * 1e9));
}
json stamp(double t) {
  const uint64_t ns = to_ns(t);
  return {{"sec", ns / 1000000000ull}, {"nsec", ns % 1000000000ull}};
}
double finite(double v) {
  return std::isfinite(v) ? v : 0.0;
}
json vec3(const Eigen::Vector3d& v) {
  return {{"x", finite(v.x())}, {"y", finite(v.y())}, {"z", finite(v.z())}};
}
json quat(const Eigen::Quaterniond& q) {
  return {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}};
}
json pose(const Eigen::Vector3d& p, const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity()) {
  return {{"position", vec3(p)}, {"orientation", quat(q)}};
}
json color(double r, double g, double b, double a = 1.0) {
  return {{"r", r}, {"g", g}, {"b", b}, {"a", a}};
}
json size3(double x, double y, double z) {
  return {{"x", x}, {"y", y}, {"z", z}};
}
json zero_duration() {
  return {{"sec", 0}, {"nsec", 0}};
}
Eigen::Quaterniond orientation_zyx(const Eigen::Vector3d& euler_zyx) {
  return Eigen::Quaterniond(robot::rotation_zyx<double>(euler_zyx)).normalized();
}

// An empty SceneEntity (every array the schema requires present).
json entity(double t, const std::string& id, double lifetime_s = 0.0) {
  json lifetime = zero_duration();
  if (lifetime_s > 0) lifetime = {{"sec", to_ns(lifetime_s) / 1000000000ull},
                                  {"nsec", to_ns(lifetime_s) % 1000000000ull}};
  return {{"timestamp", stamp(t)}, {"frame_id", kMapFrame}, {"id", id},
          {"lifetime", lifetime},  {"frame_locked", false},  {"metadata", json::array()},
          {"arrows", json::array()}, {"cubes", json::array()}, {"spheres", json::array()},
          {"cylinders", json::array()}, {"lines", json::array()}, {"triangles", json::array()},
          {"texts", json::array()}, {"models", json::array()}};
}
json scene_update(json entities) {
  return {{"deletions", json::array()}, {"entities", std::move(entities)}};
}
json line_strip(const std::vector<Eigen::Vector3d>& points, const json& c, double thickness) {
  json pts = json::array();
  for (const auto& p : points) pts.push_back(vec3(p));
  return {{"type", 0},  // LINE_STRIP
          {"pose", pose(Eigen::Vector3d::Zero())},
          {"thickness", thickness},
          {"scale_invariant", false},
          {"points", pts},
          {"color", c},
          {"colors", json::array()},
          {"indices", json::array()}};
}
json sphere(const Eigen::Vector3d& p, double d, const json& c) {
  return {{"pose", pose(p)}, {"size", size3(d, d, d)}, {"color", c}};
}
// An arrow from `from` along `force`, its length kArrowMetresPerNewton per newton.
json force_arrow(const Eigen::Vector3d& from, const Eigen::Vector3d& force, const json& c) {
  const double n = force.norm();
  const Eigen::Quaterniond q =
      n > 1e-9 ? Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), force / n)
               : Eigen::Quaterniond::Identity();
  const double length = n * kArrowMetresPerNewton;
  const double head = std::min(0.05, 0.3 * length);
  return {{"pose", pose(from, q)},
          {"shaft_length", std::max(0.0, length - head)},
          {"shaft_diameter", 0.012},
          {"head_length", head},
          {"head_diameter", 0.03},
          {"color", c}};
}
json margin_color(double margin) {
  if (margin < 0.0) return color(0.9, 0.1, 0.1);   // unsafe
  if (margin < 0.02) return color(1.0, 0.75, 0.0);  // within 2 cm of an unsafe cell
  return color(0.1, 0.75, 0.3);
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
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
    if (fs::exists(named, ec) && fs::exists(terrain[0], ec) && fs::equivalent(named, terrain[0], ec))
      return;
  }
  std::string given;
  for (const auto& t : terrain) given += (given.empty() ? "" : " ") + t;
  throw CommandError("--plan " + plan_path + ": it was planned on terrain '" + named +
                     "', not on --terrain " + given +
                     " (export a plan with the terrain it was made for)");
}

struct Drawn {
  Eigen::Vector3d base;
  Eigen::Quaterniond orientation;
  std::vector<Eigen::Vector3d> feet, knees, hips, forces;
  std::vector<bool> contact;
};

// The robot at one moment: trunk box, legs hip-knee-foot (knees by the leg's inverse kinematics),
// feet; `shin` colours each shin (nullptr: all grey).
json robot_entity(double t, const std::string& id, const robot::RobotModel& model, const Drawn& d,
                  const json& body_color, const std::vector<json>* shin_colors, double lifetime) {
  json e = entity(t, id, lifetime);
  if (model.trunk) {
    const Eigen::Vector3d c = d.base + d.orientation * model.trunk->center;
    e["cubes"].push_back({{"pose", pose(c, d.orientation)},
                          {"size", vec3(model.trunk->size)},
                          {"color", body_color}});
  }
  for (size_t l = 0; l < d.feet.size(); ++l) {
    e["lines"].push_back(line_strip({d.hips[l], d.knees[l]}, color(0.35, 0.35, 0.4), 0.03));
    e["lines"].push_back(line_strip({d.knees[l], d.feet[l]},
                                    shin_colors ? (*shin_colors)[l] : color(0.35, 0.35, 0.4),
                                    0.025));
    e["spheres"].push_back(sphere(d.feet[l], 2 * model.foot_radius,
                                  d.contact[l] ? color(0.1, 0.3, 0.9) : color(0.6, 0.6, 0.65)));
  }
  return e;
}

Drawn draw(const robot::RobotModel& model, const std::vector<int>& leg_of_foot,
           const Eigen::Vector3d& base, const Eigen::Vector3d& euler,
           const std::vector<Eigen::Vector3d>& feet, const std::vector<Eigen::Vector3d>& forces,
           const std::vector<bool>& contact) {
  Drawn d;
  d.base = base;
  d.orientation = orientation_zyx(euler);
  const Eigen::Matrix3d R = robot::rotation_zyx<double>(euler);
  d.feet = feet;
  d.forces = forces;
  d.contact = contact;
  for (size_t f = 0; f < feet.size(); ++f) {
    const robot::LegModel& leg = model.legs[leg_of_foot[f]];
    const Eigen::Vector3d foot_b = R.transpose() * (feet[f] - base);
    const Eigen::Vector3d q = robot::leg_joint_angles<double>(leg, foot_b);
    d.knees.push_back(base + R * robot::knee_in_base<double>(leg, q));
    d.hips.push_back(base + R * leg.haa_origin);
  }
  return d;
}

// The terrain as one foxglove.Grid: heights, the safety margin per radius and, with overhangs,
// the overhead layer.
json terrain_grid(const report::TerrainView& view) {
  // The overhead layer (the underside of the lowest overhang, world z; NaN where none, which
  // Foxglove leaves uncoloured) follows the margins when the terrain has overhangs.
  const bool has_overhead = view.overhead.size() == view.height.size();
  const size_t nfields = 1 + view.radii.size() + (has_overhead ? 1 : 0);
  const size_t cell_stride = 4 * nfields;
  json fields = json::array();
  fields.push_back({{"name", "height"}, {"offset", 0}, {"type", 7}});  // FLOAT32
  for (size_t r = 0; r < view.radii.size(); ++r) {
    char name[64];
    std::snprintf(name, sizeof name, "margin_r%.3f", view.radii[r]);
    fields.push_back({{"name", name}, {"offset", 4 * (r + 1)}, {"type", 7}});
  }
  if (has_overhead)
    fields.push_back({{"name", "overhead"}, {"offset", 4 * (nfields - 1)}, {"type", 7}});
  // Foxglove's grid: row-major, rows along +y, columns along +x (the view is x-major).
  std::string data(static_cast<size_t>(view.nx) * view.ny * cell_stride, '\0');
  for (int j = 0; j < view.ny; ++j)
    for (int i = 0; i < view.nx; ++i) {
      char* cell = data.data() + (static_cast<size_t>(j) * view.nx + i) * cell_stride;
      const size_t k = view.index(i, j);
      float h = view.height[k];
      std::memcpy(cell, &h, 4);
      for (size_t r = 0; r < view.radii.size(); ++r) {
        float m = view.margin[r][k];
        std::memcpy(cell + 4 * (r + 1), &m, 4);
      }
      if (has_overhead) {
        const float o = std::isfinite(view.overhead[k]) ? view.overhead[k]
                                                        : std::numeric_limits<float>::quiet_NaN();
        std::memcpy(cell + 4 * (nfields - 1), &o, 4);
      }
    }
  json grid{{"timestamp", stamp(0)},
            {"frame_id", kMapFrame},
            {"pose", pose(Eigen::Vector3d(view.origin.x(), view.origin.y(), 0.0))},
            {"column_count", view.nx},
            {"cell_size", {{"x", view.resolution}, {"y", view.resolution}}},
            {"row_stride", view.nx * cell_stride},
            {"cell_stride", cell_stride},
            {"fields", fields},
            {"data", base64(data)}};
  return grid;
}

// A thin violet tile per cell at the overhang's underside (at most `max_tiles`).
json overhang_entity(const report::TerrainView& view, size_t max_tiles) {
  json e = entity(0, "overhangs");
  e["cubes"] = json::array();
  size_t tiles = 0;
  for (int i = 0; i < view.nx; ++i)
    for (int j = 0; j < view.ny; ++j) {
      const float z = view.overhead[view.index(i, j)];
      if (!std::isfinite(z) || tiles >= max_tiles) continue;
      const Eigen::Vector2d c = view.center(i, j);
      e["cubes"].push_back({{"pose", pose(Eigen::Vector3d(c.x(), c.y(), z))},
                            {"size", size3(view.resolution, view.resolution, 0.01)},
                            {"color", color(0.48, 0.17, 0.75, 0.6)}});
      ++tiles;
    }
  e["metadata"].push_back({{"key", "overhang_cells"}, {"value", std::to_string(tiles)}});
  return e;
}

}  // namespace

ExportSummary export_foxglove(const ExportOptions& o) {
  if (o.terrain.empty()) throw CommandError("--terrain is required");
  if (!o.sim.empty() && o.plan.empty())
    throw CommandError("--sim " + o.sim + ": a simulation is drawn beside its plan; give --plan");
  if (o.compression != "zstd" && o.compression != "none")
    throw CommandError("--compression " + o.compression + ": zstd or none");
  if (fs::path(o.out).extension() != ".mcap")
    throw CommandError("--out " + o.out + ": the export is an .mcap file");
  try {
    perception::check_output_file(o.out);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }

  // Inputs: the plan (and the robot it names), the simulation, then the terrain.
  std::optional<PlanWithRobot> plan;
  if (!o.plan.empty()) {
    if (!fs::exists(o.plan)) throw CommandError("--plan " + o.plan + ": no such file");
    plan = read_plan_with_robot(o.plan);
    check_plan_terrain(plan->trajectory, o.plan, o.terrain);
  }
  json sim;
  if (!o.sim.empty()) {
    const std::string text = read_text(o.sim);
    if (text.empty()) throw CommandError("--sim " + o.sim + ": missing or empty");
    try {
      sim = json::parse(text);
    } catch (const std::exception& e) {
      throw CommandError("--sim " + o.sim + ": not JSON: " + e.what());
    }
    if (!sim.is_object() || !sim.contains("samples") || !sim["samples"].is_array() ||
        sim["samples"].empty())
      throw CommandError("--sim " + o.sim +
                         ": no \"samples\" (write it with `terrastride simulate PLAN --out "
                         "sim.json`)");
    const size_t feet = plan->trajectory.feet.size();
    for (const json& s : sim["samples"])
      if (!s.contains("t") || !s.contains("base") || !s.contains("feet") || s["feet"].size() != feet)
        throw CommandError("--sim " + o.sim + ": its samples do not have the plan's " +
                           std::to_string(feet) + " feet (a simulation of another plan?)");
  }

  report::TerrainInputOptions topts;
  topts.radii = o.radii;
  topts.resolution = o.resolution;
  robot::RobotModel model;
  if (plan) {
    model = plan->robot;
  } else {
    try {
      model = robot::load_robot(robot::resolve_robot_path("hyq"));
    } catch (const std::exception& e) {
      throw CommandError(std::string("robot hyq: ") + e.what());
    }
  }
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
  if (plan) {  // a plan whose feet are nowhere on this terrain was made for another one
    const Eigen::Vector2d lo = view.origin, hi = view.origin + view.resolution *
                                                                   Eigen::Vector2d(view.nx, view.ny);
    int outside = 0, total = 0;
    for (const auto& s : plan->trajectory.samples)
      for (const auto& f : s.feet) {
        ++total;
        if (f.position.x() < lo.x() || f.position.y() < lo.y() || f.position.x() > hi.x() ||
            f.position.y() > hi.y())
          ++outside;
      }
    if (total > 0 && outside == total)
      throw CommandError("--plan " + o.plan + ": none of its feet is on the terrain (x " +
                         std::to_string(lo.x()) + ".." + std::to_string(hi.x()) + ", y " +
                         std::to_string(lo.y()) + ".." + std::to_string(hi.y()) +
                         "): a plan for another terrain?");
  }

  mcap::WriterOptions wo;
  wo.compression = o.compression == "none" ? "" : "zstd";
  mcap::Writer w(wo);
  std::map<std::string, uint16_t> schema_ids;
  for (const auto& [name, text] : kSchemas) schema_ids[name] = w.add_schema(name, "jsonschema", text);
  ExportSummary summary;
  std::map<uint16_t, std::string> topic_of;
  const auto channel = [&](const std::string& topic, const std::string& schema,
                           std::map<std::string, std::string> meta = {}) {
    const uint16_t id = w.add_channel(schema_ids.at(schema), topic, "json", meta);
    topic_of[id] = topic;
    summary.messages_per_topic[topic] = 0;
    return id;
  };
  const auto publish = [&](uint16_t ch, double t, const json& msg) {
    w.add_message(ch, to_ns(t), msg.dump());
    ++summary.messages_per_topic[topic_of[ch]];
  };

  // ---- the terrain: heights and safety margins as one grid, occupied voxels as cubes.
  {
    std::map<std::string, std::string> meta{{"source", view.source}, {"kind", view.kind}};
    const uint16_t ch = channel("/terrain/grid", "foxglove.Grid", meta);
    publish(ch, 0, terrain_grid(view));
  }
  if (view.overhead.size() == view.height.size())  // overhangs in 3-D
    publish(channel("/terrain/overhangs", "foxglove.SceneUpdate"), 0,
            scene_update(json::array({overhang_entity(view, o.max_voxels)})));
  if (view.octree) {
    const uint16_t ch = channel("/terrain/voxels", "foxglove.SceneUpdate");
    json e = entity(0, "occupied_voxels");
    const double zmin = view.octree->getBBXMin().z();
    for (auto it = view.octree->begin_leafs(), end = view.octree->end_leafs(); it != end; ++it) {
      if (!view.octree->isNodeOccupied(*it)) continue;
      if (summary.voxels >= o.max_voxels) break;
      const double s = it.getSize();
      const double z = it.getZ();
      const double shade = std::clamp(0.4 + 0.6 * std::tanh(std::max(0.0, z - zmin)), 0.4, 1.0);
      e["cubes"].push_back({{"pose", pose(Eigen::Vector3d(it.getX(), it.getY(), z))},
                            {"size", size3(s, s, s)},
                            {"color", color(0.55 * shade, 0.45 * shade, 0.35 * shade, 0.85)}});
      ++summary.voxels;
    }
    e["metadata"].push_back({{"key", "voxels"}, {"value", std::to_string(summary.voxels)}});
    publish(ch, 0, scene_update(json::array({e})));
  }

  // ---- the plan over time, its footholds and shin contacts.
  if (plan) {
    const planner::Trajectory& traj = plan->trajectory;
    std::vector<int> leg_of_foot;
    for (const auto& f : traj.feet) {
      const int l = model.leg_index(f);
      if (l < 0) throw CommandError("--plan " + o.plan + ": foot " + f + " is not a leg of " + model.name);
      leg_of_foot.push_back(l);
    }
    collision::CheckTerrain ct;
    ct.field = view.field.get();
    ct.octree = view.octree;
    ct.description = view.source;
    collision::CheckReport checks;
    try {
      checks = collision::run_checks(model, traj, ct);
    } catch (const std::exception& e) {
      throw CommandError("--plan " + o.plan + ": " + e.what());
    }
    summary.duration_s = traj.samples.empty() ? 0.0 : traj.samples.back().t;

    const uint16_t tf = channel("/tf", "foxglove.FrameTransforms");
    const uint16_t robot_ch = channel("/plan/robot", "foxglove.SceneUpdate");
    const uint16_t force_ch = channel("/plan/contact_forces", "foxglove.SceneUpdate",
                                      {{"arrow_m_per_N", std::to_string(kArrowMetresPerNewton)}});
    const uint16_t foothold_ch = channel("/plan/footholds", "foxglove.SceneUpdate");
    const uint16_t shin_ch = channel("/plan/shin_contacts", "foxglove.SceneUpdate");
    const uint16_t path_ch = channel("/plan/base_path", "foxglove.SceneUpdate");

    // Static overviews at t = 0: footholds coloured by margin, the base path, shin contacts.
    json fh = entity(0, "footholds");
    if (checks.footholds)
      for (const auto& f : checks.footholds->footholds) {
        fh["spheres"].push_back(sphere(f.position, 0.05, margin_color(f.margin)));
        fh["metadata"].push_back({{"key", traj.feet[f.leg] + "@" + std::to_string(f.t_start)},
                                  {"value", std::to_string(f.margin)}});
        ++summary.footholds;
      }
    publish(foothold_ch, 0, scene_update(json::array({fh})));
    std::vector<Eigen::Vector3d> path;
    for (const auto& s : traj.samples) path.push_back(s.base.position);
    json pe = entity(0, "base_path");
    pe["lines"].push_back(line_strip(path, color(0.0, 0.85, 0.95), 0.01));
    publish(path_ch, 0, scene_update(json::array({pe})));

    // Per sample and leg: the shin's colour (verdict of the leg-capsule check).
    const auto* clearance = checks.clearance ? &*checks.clearance : nullptr;
    const auto shin_state = [&](size_t k, size_t f) -> int {  // 0 clear, 1 possible, 2 certain
      if (!clearance) return 0;
      for (const auto& series : clearance->legs)
        if (series.leg == traj.feet[f] && k < series.shin_verdict.size())
          return static_cast<int>(series.shin_verdict[k]);
      return 0;
    };
    json contacts = entity(0, "shin_contacts");
    double dt = traj.sample_dt > 0 ? traj.sample_dt : 0.01;
    for (size_t k = 0; k < traj.samples.size(); ++k) {
      const auto& s = traj.samples[k];
      std::vector<Eigen::Vector3d> feet, forces;
      std::vector<bool> contact;
      for (const auto& f : s.feet) {
        feet.push_back(f.position);
        forces.push_back(f.force);
        contact.push_back(f.contact);
      }
      const Drawn d = draw(model, leg_of_foot, s.base.position, s.base.euler_zyx, feet, forces, contact);
      std::vector<json> shin_colors;
      for (size_t f = 0; f < feet.size(); ++f) {
        const int v = shin_state(k, f);
        shin_colors.push_back(v == 2 ? color(0.9, 0.1, 0.1)
                              : v == 1 ? color(1.0, 0.6, 0.0)
                                       : color(0.35, 0.35, 0.4));
        if (v > 0) {
          contacts["spheres"].push_back(
              sphere(0.5 * (d.knees[f] + d.feet[f]), 0.03, shin_colors.back()));
          ++summary.shin_contacts;
        }
      }
      publish(tf, s.t,
              {{"transforms",
                json::array({{{"timestamp", stamp(s.t)},
                              {"parent_frame_id", kMapFrame},
                              {"child_frame_id", "plan_base"},
                              {"translation", vec3(s.base.position)},
                              {"rotation", quat(d.orientation)}}})}});
      publish(robot_ch, s.t,
              scene_update(json::array(
                  {robot_entity(s.t, "plan_robot", model, d, color(0.85, 0.85, 0.9, 0.6),
                                &shin_colors, 0.0)})));
      json fe = entity(s.t, "plan_forces");
      for (size_t f = 0; f < feet.size(); ++f)
        if (contact[f] && forces[f].norm() > 1e-6)
          fe["arrows"].push_back(force_arrow(feet[f], forces[f], color(0.95, 0.45, 0.1)));
      publish(force_ch, s.t, scene_update(json::array({fe})));
    }
    (void)dt;
    publish(shin_ch, 0, scene_update(json::array({contacts})));

    // ---- the simulated robot beside the plan.
    if (!sim.is_null()) {
      const uint16_t sim_robot = channel("/sim/robot", "foxglove.SceneUpdate");
      const uint16_t sim_force = channel("/sim/contact_forces", "foxglove.SceneUpdate",
                                         {{"arrow_m_per_N", std::to_string(kArrowMetresPerNewton)}});
      const auto v3 = [&](const json& a) {
        if (!a.is_array() || a.size() != 3) throw CommandError("--sim " + o.sim + ": a 3-vector expected");
        return Eigen::Vector3d(a[0].get<double>(), a[1].get<double>(), a[2].get<double>());
      };
      try {
        for (const json& s : sim["samples"]) {
          const double t = s["t"].get<double>();
          std::vector<Eigen::Vector3d> feet, forces;
          std::vector<bool> contact;
          for (const json& f : s["feet"]) {
            feet.push_back(v3(f["position"]));
            forces.push_back(v3(f["force"]));
            contact.push_back(f["contact"].get<bool>());
          }
          const Eigen::Vector3d base = v3(s["base"]["position"]);
          const Drawn d = draw(model, leg_of_foot, base, v3(s["base"]["euler_zyx"]), feet, forces, contact);
          publish(tf, t,
                  {{"transforms",
                    json::array({{{"timestamp", stamp(t)},
                                  {"parent_frame_id", kMapFrame},
                                  {"child_frame_id", "sim_base"},
                                  {"translation", vec3(base)},
                                  {"rotation", quat(d.orientation)}}})}});
          publish(sim_robot, t,
                  scene_update(json::array(
                      {robot_entity(t, "sim_robot", model, d, color(0.3, 0.5, 0.95, 0.5), nullptr, 0.0)})));
          json fe = entity(t, "sim_forces");
          for (size_t f = 0; f < feet.size(); ++f)
            if (contact[f] && forces[f].norm() > 1e-6)
              fe["arrows"].push_back(force_arrow(feet[f], forces[f], color(0.2, 0.4, 1.0)));
          publish(sim_force, t, scene_update(json::array({fe})));
        }
      } catch (const json::exception& e) {
        throw CommandError("--sim " + o.sim + ": " + e.what());
      }
    }
  }

  const std::string bytes = w.finish();
  summary.messages = w.message_count();
  summary.chunks = w.chunk_count();
  summary.bytes = bytes.size();
  try {
    perception::write_file_atomically(o.out, bytes);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
  return summary;
}

}  // namespace terrastride::service::foxglove
