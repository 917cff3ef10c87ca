#include "report/report.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"

#ifndef TERRASTRIDE_REPORT_ASSETS_DIR
#define TERRASTRIDE_REPORT_ASSETS_DIR ""
#endif

namespace terrastride::service::report {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Margins beyond this are drawn as "far from anything unsafe" (flat scenes report 1e9).
constexpr double kMarginDisplayCap = 1.0;

// Rounds to `digits` decimals so report.json stays small; NaN/inf become null (JSON has neither).
json num(double v, int digits = 4) {
  if (!std::isfinite(v)) return nullptr;
  const double s = std::pow(10.0, digits);
  return std::round(v * s) / s;
}

json vec3(const Eigen::Vector3d& v, int digits = 4) {
  return json::array({num(v.x(), digits), num(v.y(), digits), num(v.z(), digits)});
}

// Problem and check thresholds: the targets of DESIGN.md and issues 4-5 (plan.json "checks").
struct CheckLimit {
  const char* key;
  const char* label;
  const char* unit;
  double limit;  // a value above this is a problem (below for "min" checks)
  bool lower_is_bad;
};

// Dense checks the planner writes into plan.json; the linear dynamics limit is 2 % of m g and is
// filled in per robot.
const CheckLimit kDenseChecks[] = {
    {"dynamics_linear_max_N", "dynamics residual, linear", "N", 0.0, false},
    {"dynamics_angular_max_Nm", "dynamics residual, angular", "N m", 10.0, false},
    {"penetration_max_m", "swing-foot penetration", "m", 0.005, false},
    {"friction_violation_max_N", "friction-pyramid violation", "N", 1.0, false},
    {"slip_max_m", "stance-foot slip", "m", 0.001, false},
    {"range_of_motion_excess_max_m", "range-of-motion excess", "m", 0.005, false},
};

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << v;
  return os.str();
}

// Index of the radius closest to r (the robot's foot radius) in the safety layers.
int closest_radius(const std::vector<double>& radii, double r) {
  int best = 0;
  for (size_t i = 1; i < radii.size(); ++i)
    if (std::abs(radii[i] - r) < std::abs(radii[best] - r)) best = static_cast<int>(i);
  return best;
}

// ---------------------------------------------------------------- terrain section

json terrain_json(const TerrainView& t, const ReportOptions& options, double foot_radius) {
  // Decimate very large grids for display (every number shown is still a real cell value).
  int stride = 1;
  while (static_cast<size_t>((t.nx + stride - 1) / stride) * ((t.ny + stride - 1) / stride) >
         options.max_display_cells)
    ++stride;
  json xs = json::array(), ys = json::array();
  for (int i = 0; i < t.nx; i += stride) xs.push_back(num(t.center(i, 0).x(), 4));
  for (int j = 0; j < t.ny; j += stride) ys.push_back(num(t.center(0, j).y(), 4));
  // Plotly heatmaps take z[row = y][col = x].
  json height = json::array();
  std::vector<json> margins(t.radii.size(), json::array());
  for (int j = 0; j < t.ny; j += stride) {
    json hrow = json::array();
    std::vector<json> mrows(t.radii.size(), json::array());
    for (int i = 0; i < t.nx; i += stride) {
      const size_t k = t.index(i, j);
      hrow.push_back(num(t.height[k], 4));
      for (size_t r = 0; r < t.radii.size(); ++r) {
        const double m = t.margin[r][k];
        mrows[r].push_back(num(std::isfinite(m) ? std::min(m, kMarginDisplayCap) : m, 3));
      }
    }
    height.push_back(std::move(hrow));
    for (size_t r = 0; r < t.radii.size(); ++r) margins[r].push_back(std::move(mrows[r]));
  }

  size_t observed = 0;
  double hmin = std::numeric_limits<double>::infinity(), hmax = -hmin;
  for (size_t k = 0; k < t.height.size(); ++k) {
    if (t.observed[k]) ++observed;
    if (std::isfinite(t.height[k])) {
      hmin = std::min<double>(hmin, t.height[k]);
      hmax = std::max<double>(hmax, t.height[k]);
    }
  }
  json layers = json::array();
  for (size_t r = 0; r < t.radii.size(); ++r) {
    size_t safe = 0;
    for (size_t k = 0; k < t.height.size(); ++k)
      if (t.observed[k] && std::isfinite(t.margin[r][k]) && t.margin[r][k] >= 0.0) ++safe;
    layers.push_back({{"radius_m", num(t.radii[r], 4)},
                      {"safe_cells", safe},
                      {"safe_fraction", num(observed ? double(safe) / observed : 0.0, 4)},
                      {"margin", std::move(margins[r])}});
  }
  const int primary = t.radii.empty() ? -1 : closest_radius(t.radii, foot_radius);
  return {{"source", t.source},
          {"kind", t.kind},
          {"resolution_m", t.resolution},
          {"nx", t.nx},
          {"ny", t.ny},
          {"origin", {num(t.origin.x(), 4), num(t.origin.y(), 4)}},
          {"display_stride", stride},
          {"cells", t.height.size()},
          {"observed_cells", observed},
          {"observed_fraction", num(t.height.empty() ? 0.0 : double(observed) / t.height.size(), 4)},
          {"height_min_m", num(hmin)},
          {"height_max_m", num(hmax)},
          {"has_octomap", static_cast<bool>(t.octree)},
          {"foot_radius_m", foot_radius},
          {"primary_layer", primary},
          {"safe_fraction", primary >= 0 ? layers[primary]["safe_fraction"] : json(nullptr)},
          {"x", std::move(xs)},
          {"y", std::move(ys)},
          {"height", std::move(height)},
          {"layers", std::move(layers)},
          {"info", t.info},
          {"build_s", num(t.build_s, 4)}};
}

// ---------------------------------------------------------------- plan section

// Stations for the elevation profile: distance along the line from the base's start to its end
// position (a straight axis, so feet beside a swaying base still project smoothly); the x axis when
// the base ends where it started.
struct PathStations {
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  Eigen::Vector2d axis = Eigen::Vector2d::UnitX();
  double polyline_length = 0.0;

  explicit PathStations(const planner::Trajectory& traj) {
    if (traj.samples.empty()) return;
    origin = traj.samples.front().base.position.head<2>();
    const Eigen::Vector2d end = traj.samples.back().base.position.head<2>();
    if ((end - origin).norm() > 0.05) axis = (end - origin).normalized();
    for (size_t k = 1; k < traj.samples.size(); ++k)
      polyline_length += (traj.samples[k].base.position.head<2>() -
                          traj.samples[k - 1].base.position.head<2>())
                             .norm();
  }
  double length() const { return polyline_length; }
  double project(const Eigen::Vector2d& q) const { return (q - origin).dot(axis); }
};

const char* kJointNames[3] = {"HAA", "HFE", "KFE"};

json problem(const std::string& id, const std::string& plan, const std::string& text) {
  return {{"id", id}, {"plan", plan}, {"text", text}};
}

// One row of the summary table: status "ok", "problem" or "absent" (with the reason).
json row(const std::string& label, json value, const std::string& unit, const std::string& status,
         const std::string& note) {
  return {{"label", label}, {"value", std::move(value)}, {"unit", unit}, {"status", status},
          {"note", note}};
}

json plan_json(const PlanInput& input, const TerrainView& terrain, const robot::RobotModel& model,
               json& problems) {
  const planner::Trajectory& traj = input.trajectory;
  const std::string& name = input.name;
  const size_t n = traj.samples.size();
  const size_t n_feet = traj.feet.size();
  // Display stride: about 1500 points per curve are plenty for the page.
  const size_t stride = std::max<size_t>(1, n / 1500);

  json out{{"name", name},
           {"path", input.path},
           {"robot", traj.robot},
           {"gait", traj.gait},
           {"duration_s", traj.duration},
           {"sample_dt_s", traj.sample_dt},
           {"samples", n},
           {"display_stride", stride},
           {"feet_names", traj.feet}};
  out["solver"] = {{"status", traj.solver.status},
                   {"iterations", traj.solver.iterations},
                   {"wall_s", num(traj.solver.wall_s, 4)},
                   {"n_variables", traj.solver.n_variables},
                   {"n_constraints", traj.solver.n_constraints}};
  json checks_in = json::object();
  for (const auto& [key, value] : traj.checks) checks_in[key] = num(value, 6);
  out["plan_checks"] = checks_in;

  // Path, feet.
  json t = json::array(), bx = json::array(), by = json::array(), bz = json::array();
  std::vector<json> fx(n_feet, json::array()), fy(n_feet, json::array()),
      fz(n_feet, json::array()), fc(n_feet, json::array());
  for (size_t k = 0; k < n; k += stride) {
    const auto& s = traj.samples[k];
    t.push_back(num(s.t, 4));
    bx.push_back(num(s.base.position.x()));
    by.push_back(num(s.base.position.y()));
    bz.push_back(num(s.base.position.z()));
    for (size_t f = 0; f < n_feet; ++f) {
      fx[f].push_back(num(s.feet[f].position.x()));
      fy[f].push_back(num(s.feet[f].position.y()));
      fz[f].push_back(num(s.feet[f].position.z()));
      fc[f].push_back(s.feet[f].contact ? 1 : 0);
    }
  }
  out["time"] = t;
  out["base"] = {{"x", bx}, {"y", by}, {"z", bz}};
  json feet = json::array();
  for (size_t f = 0; f < n_feet; ++f)
    feet.push_back({{"name", traj.feet[f]}, {"x", fx[f]}, {"y", fy[f]}, {"z", fz[f]}, {"contact", fc[f]}});
  out["feet"] = feet;

  // Post-hoc checks (collision module): torques, leg capsules against the OctoMap, footholds.
  collision::CheckTerrain check_terrain;
  check_terrain.field = terrain.field.get();
  check_terrain.octree = terrain.octree;
  check_terrain.description = terrain.source;
  json summary = json::array();
  const double foot_radius = model.foot_radius;
  std::string octree_note;
  if (!check_terrain.octree) {
    octree_note = "the terrain has no OctoMap";
  }
  const collision::CheckReport checks =
      input.checks ? *input.checks : collision::run_checks(model, traj, check_terrain);

  // Footholds.
  json footholds = json::array();
  int unsafe = 0;
  if (checks.footholds) {
    for (const auto& fh : checks.footholds->footholds) {
      footholds.push_back({{"foot", traj.feet[fh.leg]},
                           {"t_start", num(fh.t_start, 3)},
                           {"t_end", num(fh.t_end, 3)},
                           {"position", vec3(fh.position)},
                           {"margin_m", num(std::min(fh.margin, 1e3), 4)},
                           {"safe", fh.safe()}});
      if (!fh.safe()) {
        ++unsafe;
        problems.push_back(problem(
            "unsafe_foothold", name,
            traj.feet[fh.leg] + " foothold at t = " + fmt(fh.t_start, 2) + "-" + fmt(fh.t_end, 2) +
                " s, (" + fmt(fh.position.x(), 3) + ", " + fmt(fh.position.y(), 3) +
                ") m: margin " + fmt(fh.margin * 1000, 1) + " mm for a " +
                fmt(foot_radius * 1000, 1) + " mm foot (unsafe terrain under the foot)"));
      }
    }
    summary.push_back(row("unsafe footholds", unsafe, "", unsafe > 0 ? "problem" : "ok",
                          std::to_string(footholds.size()) + " stance footholds checked, foot radius " +
                              fmt(foot_radius * 1000, 1) + " mm"));
    summary.push_back(row("worst foothold margin",
                          num(std::min(checks.footholds->worst_margin, 1e3), 4), "m",
                          checks.footholds->worst_margin < 0 ? "problem" : "ok",
                          "signed distance to the nearest unsafe cell"));
  } else {
    summary.push_back(row("unsafe footholds", nullptr, "", "absent", "no terrain to check against"));
  }
  out["footholds"] = footholds;
  if (traj.checks.count("unsafe_footholds") && traj.checks.at("unsafe_footholds") > 0 &&
      unsafe == 0) {
    problems.push_back(problem("unsafe_foothold", name,
                               "the plan file reports " +
                                   fmt(traj.checks.at("unsafe_footholds"), 0) +
                                   " unsafe footholds (on the terrain it was planned on)"));
  }

  // Torques.
  {
    const auto& tr = checks.torque;
    json legs = json::array();
    for (size_t l = 0; l < tr.legs.size(); ++l) {
      const auto& series = tr.legs[l];
      json joints = json::array();
      for (int j = 0; j < 3; ++j) {
        json tau = json::array();
        for (size_t k = 0; k < series.tau.size(); k += stride) tau.push_back(num(series.tau[k][j], 2));
        joints.push_back({{"name", kJointNames[j]},
                          {"limit_Nm", model.legs[l].torque_limit[j]},
                          {"worst_ratio", num(series.worst_ratio[j], 4)},
                          {"tau_Nm", tau}});
      }
      legs.push_back({{"name", series.leg}, {"violating_samples", series.violating_samples},
                      {"joints", joints}});
    }
    json time = json::array();
    for (size_t k = 0; k < tr.time.size(); k += stride) time.push_back(num(tr.time[k], 4));
    out["torque"] = {{"source", "collision::check_joint_torques (tau = M qdd + c + g - J^T f)"},
                     {"time", time},
                     {"legs", legs},
                     {"ratio_max", num(tr.ratio_max, 4)},
                     {"violating_samples", tr.violating_samples}};
    const bool bad = tr.ratio_max > 1.0 + 1e-9;
    std::string where;
    if (tr.worst_leg >= 0)
      where = tr.legs[tr.worst_leg].leg + " " + kJointNames[tr.worst_joint] + " at t = " +
              fmt(tr.time[tr.worst_sample], 2) + " s";
    summary.push_back(row("worst torque ratio |tau|/tau_max", num(tr.ratio_max, 4), "",
                          bad ? "problem" : "ok", where));
    summary.push_back(row("samples over a torque limit", tr.violating_samples, "",
                          tr.violating_samples > 0 ? "problem" : "ok",
                          "of " + std::to_string(tr.time.size())));
    if (bad)
      problems.push_back(problem("torque_limit", name,
                                 "joint torque " + fmt(tr.ratio_max, 3) + " x the limit (" + where +
                                     "); " + std::to_string(tr.violating_samples) +
                                     " samples over a limit"));
    if (checks.kinematics.unreachable_samples > 0 || checks.kinematics.joint_limit_samples > 0) {
      const int u = checks.kinematics.unreachable_samples;
      const int jl = checks.kinematics.joint_limit_samples;
      std::string text = std::to_string(u) + " samples with a foot out of reach, " +
                         std::to_string(jl) + " outside the joint range";
      if (!checks.kinematics.issues.empty()) text += " (first: " + checks.kinematics.issues.front().message + ")";
      summary.push_back(row("kinematic excursions", u + jl, "", "problem", text));
      problems.push_back(problem("kinematics", name, text));
    }
  }

  // Leg capsules against the OctoMap.
  if (checks.clearance) {
    const auto& cl = *checks.clearance;
    const bool resolved = !cl.certain_source.empty();
    json legs = json::array();
    for (const auto& series : cl.legs) {
      json shin = json::array(), thigh = json::array(), shin_c = json::array(),
           verdict = json::array();
      for (size_t k = 0; k < series.shin_distance.size(); k += stride) {
        shin.push_back(num(series.shin_distance[k], 4));
        shin_c.push_back(num(series.shin_certain_distance[k], 4));
        // Worst verdict within the stride, so a short certain collision is not dropped.
        int v = 0;
        for (size_t m = k; m < std::min(k + stride, series.shin_verdict.size()); ++m)
          v = std::max(v, static_cast<int>(series.shin_verdict[m]));
        verdict.push_back(v);
      }
      for (size_t k = 0; k < series.thigh_distance.size(); k += stride)
        thigh.push_back(num(series.thigh_distance[k], 4));
      legs.push_back({{"name", series.leg}, {"shin_m", shin}, {"thigh_m", thigh},
                      {"shin_certain_m", shin_c}, {"shin_verdict", verdict},
                      {"shin_min_m", num(series.shin_min)},
                      {"shin_certain_min_m", num(series.shin_certain_min)},
                      {"shin_collision_samples", series.shin_collision_samples},
                      {"shin_certain_samples", series.shin_certain_samples}});
    }
    json time = json::array();
    for (size_t k = 0; k < cl.time.size(); k += stride) time.push_back(num(cl.time[k], 4));
    out["clearance"] = {{"source", "collision::check_leg_clearance (FCL capsules vs the OctoMap, " +
                                       fmt(cl.octree_resolution, 3) + " m voxels)"},
                        {"certain_solid", cl.certain_source},
                        {"certain_resolved_below_m", num(cl.certain_resolved_below)},
                        {"octree_resolution_m", num(cl.octree_resolution)},
                        {"time", time},
                        {"legs", legs},
                        {"shin_min_m", num(cl.shin_min_distance)},
                        {"thigh_min_m", num(cl.thigh_min_distance)},
                        {"shin_certain_min_m", num(cl.shin_min_certain_distance)},
                        {"thigh_certain_min_m", num(cl.thigh_min_certain_distance)},
                        {"shin_collisions", cl.shin_collisions},
                        {"thigh_collisions", cl.thigh_collisions},
                        {"shin_collisions_certain", cl.shin_collisions_certain},
                        {"shin_contacts_uncertain", cl.shin_contacts_uncertain},
                        {"thigh_collisions_certain", cl.thigh_collisions_certain},
                        {"thigh_contacts_uncertain", cl.thigh_contacts_uncertain}};
    // The problem is the certain count; contacts within the map's uncertainty are a note.
    const bool bad = cl.shin_collisions_certain > 0;
    summary.push_back(row("shin samples in certain collision", cl.shin_collisions_certain, "",
                          bad ? "problem" : "ok",
                          resolved ? "minimum distance to the certain solid " +
                                         std::string(cl.shin_min_certain_distance >=
                                                             cl.certain_resolved_below - 1e-9
                                                         ? ">= "
                                                         : "") +
                                         fmt(cl.shin_min_certain_distance * 1000, 1) + " mm"
                                   : "no surface estimate: every voxel contact counts"));
    summary.push_back(row("minimum shin distance to the voxels", num(cl.shin_min_distance), "m",
                          bad ? "problem" : (cl.shin_contacts_uncertain > 0 ? "note" : "ok"),
                          std::to_string(cl.shin_contacts_uncertain) +
                              " samples touch voxels only within the map's uncertainty (" +
                              fmt(cl.octree_resolution * 100, 1) + " cm voxels)"));
    if (bad)
      problems.push_back(problem("shin_collision", name,
                                 "shin capsule certainly collides with the terrain in " +
                                     std::to_string(cl.shin_collisions_certain) +
                                     " samples (first at t = " +
                                     fmt(cl.first_certain_collision_t, 2) + " s; " +
                                     std::to_string(cl.shin_contacts_uncertain) +
                                     " more touch voxels within the map's uncertainty)"));
    if (cl.thigh_collisions_certain > 0)
      problems.push_back(problem("thigh_collision", name,
                                 "thigh capsule certainly collides with the terrain in " +
                                     std::to_string(cl.thigh_collisions_certain) + " samples"));
  } else {
    out["clearance"] = {{"absent", "leg capsules not checked: " + octree_note}};
    summary.push_back(row("minimum shin distance", nullptr, "m", "absent", octree_note));
  }

  // Solver.
  {
    const bool ok = traj.solver.status == "optimal" || traj.solver.status == "solved";
    summary.push_back(row("solver status", traj.solver.status, "", ok ? "ok" : "problem",
                          std::to_string(traj.solver.iterations) + " iterations, " +
                              fmt(traj.solver.wall_s, 3) + " s, " +
                              std::to_string(traj.solver.n_variables) + " variables, " +
                              std::to_string(traj.solver.n_constraints) + " constraints"));
    if (!ok)
      problems.push_back(problem("solver", name, "solver ended with status '" +
                                                     traj.solver.status + "', not optimal"));
  }
  // Dense checks from the plan file.
  for (const CheckLimit& c : kDenseChecks) {
    auto it = traj.checks.find(c.key);
    double limit = c.limit;
    if (std::string(c.key) == "dynamics_linear_max_N") limit = 0.02 * model.mass * 9.81;
    if (it == traj.checks.end()) {
      summary.push_back(row(c.label, nullptr, c.unit, "absent", "not in the plan file"));
      continue;
    }
    const bool bad = it->second > limit;
    summary.push_back(row(c.label, num(it->second, 6), c.unit, bad ? "problem" : "ok",
                          "limit " + fmt(limit, 4) + " " + c.unit + " (dense check of the plan)"));
    if (bad)
      problems.push_back(problem(c.key, name,
                                 std::string(c.label) + " " + fmt(it->second, 4) + " " + c.unit +
                                     " exceeds " + fmt(limit, 4) + " " + c.unit));
  }
  out["summary"] = summary;

  // Elevation profile along the base path: terrain under the base, base height, feet, knees and the
  // shin points between knee and foot (from IK of each foot in the base frame).
  PathStations path(traj);
  json prof_s = json::array(), prof_ground = json::array(), prof_base = json::array();
  for (size_t k = 0; k < n; k += stride) {
    const auto& b = traj.samples[k].base.position;
    prof_s.push_back(num(path.project(b.head<2>()), 4));
    prof_ground.push_back(terrain.field ? num(terrain.field->height(b.x(), b.y())) : json(nullptr));
    prof_base.push_back(num(b.z()));
  }
  json prof_feet = json::array();
  for (size_t f = 0; f < n_feet; ++f) {
    json s = json::array(), z = json::array(), ground = json::array();
    for (size_t k = 0; k < n; k += stride) {
      const auto& p = traj.samples[k].feet[f].position;
      s.push_back(num(path.project(p.head<2>()), 4));
      z.push_back(num(p.z()));
      ground.push_back(terrain.field ? num(terrain.field->height(p.x(), p.y())) : json(nullptr));
    }
    prof_feet.push_back({{"name", traj.feet[f]}, {"s", s}, {"z", z}, {"ground", ground}});
  }
  // Shin points every ~0.05 s: knee, and 1/3, 2/3 of the way to the foot.
  json shin_s = json::array(), shin_z = json::array(), shin_leg = json::array(),
       shin_clear = json::array();
  const size_t shin_stride =
      std::max<size_t>(1, static_cast<size_t>(std::round(0.05 / std::max(traj.sample_dt, 1e-4))));
  for (size_t k = 0; k < n; k += shin_stride) {
    const auto& sample = traj.samples[k];
    const Eigen::Matrix3d R = collision::rotation_zyx(sample.base.euler_zyx);
    for (size_t f = 0; f < n_feet && f < model.legs.size(); ++f) {
      const auto& leg = model.legs[f];
      const Eigen::Vector3d foot_w = sample.feet[f].position;
      const Eigen::Vector3d foot_b = R.transpose() * (foot_w - sample.base.position);
      const auto ik = robot::inverse_kinematics(leg, foot_b);
      if (ik.status == robot::IkStatus::unreachable) continue;
      const Eigen::Vector3d knee_w = sample.base.position + R * robot::knee_position(leg, ik.q);
      for (double u : {0.0, 1.0 / 3.0, 2.0 / 3.0}) {
        const Eigen::Vector3d p = knee_w + u * (foot_w - knee_w);
        shin_s.push_back(num(path.project(p.head<2>()), 4));
        shin_z.push_back(num(p.z()));
        shin_leg.push_back(static_cast<int>(f));
        shin_clear.push_back(terrain.field ? num(p.z() - terrain.field->height(p.x(), p.y()))
                                           : json(nullptr));
      }
    }
  }
  out["profile"] = {{"path_length_m", num(path.length())},
                    {"axis_origin", {num(path.origin.x()), num(path.origin.y())}},
                    {"axis_direction", {num(path.axis.x()), num(path.axis.y())}},
                    {"s", prof_s},
                    {"ground", prof_ground},
                    {"base_z", prof_base},
                    {"feet", prof_feet},
                    {"shin_points", {{"s", shin_s}, {"z", shin_z}, {"leg", shin_leg},
                                     {"height_above_ground_m", shin_clear}}}};
  out["checks"] = checks.keys();
  out["check_failures"] = checks.failures();
  out["checks_wall_s"] = num(checks.wall_s, 4);
  return out;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return {};
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Makes text safe inside an inline <script>: no "</" can close the element early.
std::string script_safe(std::string text) {
  std::string out;
  out.reserve(text.size() + 64);
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '<' && i + 1 < text.size() && (text[i + 1] == '/' || text[i + 1] == '!')) {
      out += "<\\";
      continue;
    }
    out += text[i];
  }
  return out;
}

std::string replace_once(std::string text, const std::string& key, const std::string& value,
                         const std::string& source) {
  const size_t at = text.find(key);
  if (at == std::string::npos)
    throw CommandError(source + ": the placeholder " + key + " is missing");
  text.replace(at, key.size(), value);
  return text;
}

std::string html_escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

}  // namespace

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  return buf;
}

void rasterize_field(TerrainView& view, const terrain::HeightField& field,
                     const std::vector<double>& radii) {
  const size_t cells = static_cast<size_t>(view.nx) * view.ny;
  view.height.assign(cells, std::numeric_limits<float>::quiet_NaN());
  view.observed.assign(cells, 0);
  view.radii = radii;
  view.margin.assign(radii.size(), std::vector<float>(cells, std::numeric_limits<float>::quiet_NaN()));
  for (int i = 0; i < view.nx; ++i) {
    for (int j = 0; j < view.ny; ++j) {
      const Eigen::Vector2d c = view.center(i, j);
      const size_t k = view.index(i, j);
      view.height[k] = static_cast<float>(field.height(c.x(), c.y()));
      view.observed[k] = field.observed(c.x(), c.y()) ? 1 : 0;
      for (size_t r = 0; r < radii.size(); ++r)
        view.margin[r][k] = static_cast<float>(field.safety_margin(c.x(), c.y(), radii[r]).margin);
    }
  }
}

json build_report(const TerrainView& terrain, const std::vector<PlanInput>& plans,
                  const ReportOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  json problems = json::array();
  std::string robot_name = options.robot;
  if (!plans.empty() && !plans.front().trajectory.robot.empty())
    robot_name = plans.front().trajectory.robot;
  robot::RobotModel model;
  try {
    model = robot::load_robot(robot::resolve_robot_path(robot_name));
  } catch (const std::exception& e) {
    throw CommandError(std::string("robot '") + robot_name + "': " + e.what());
  }

  json report{{"format", "terrastride-report/1"},
              {"title", options.title},
              {"generated_utc", utc_now()},
              {"robot", {{"name", model.name}, {"foot_radius_m", model.foot_radius},
                         {"mass_kg", model.mass}}}};
  report["terrain"] = terrain_json(terrain, options, model.foot_radius);

  json plan_list = json::array();
  for (const PlanInput& p : plans) {
    robot::RobotModel plan_model = model;
    if (!p.trajectory.robot.empty() && p.trajectory.robot != model.name) {
      try {
        plan_model = robot::load_robot(robot::resolve_robot_path(p.trajectory.robot));
      } catch (const std::exception& e) {
        throw CommandError(p.path + ": robot '" + p.trajectory.robot + "': " + e.what());
      }
    }
    try {
      plan_list.push_back(plan_json(p, terrain, plan_model, problems));
    } catch (const collision::TrajectoryError& e) {
      throw CommandError(p.path + ": " + e.what());
    }
  }
  report["plans"] = plan_list;

  // Summary over everything.
  json summary = json::array();
  const json& tj = report["terrain"];
  for (const json& layer : tj["layers"]) {
    const bool primary = &layer == &tj["layers"][tj["primary_layer"].get<int>()];
    summary.push_back(row("safe fraction, foot radius " +
                              fmt(layer["radius_m"].get<double>() * 1000, 0) + " mm",
                          layer["safe_fraction"], "", "ok",
                          std::string("of observed cells") + (primary ? " (robot's foot)" : "")));
  }
  summary.push_back(row("observed fraction", tj["observed_fraction"], "", "ok",
                        std::to_string(tj["observed_cells"].get<size_t>()) + " of " +
                            std::to_string(tj["cells"].get<size_t>()) + " cells of " +
                            fmt(terrain.resolution, 3) + " m"));
  report["summary"] = summary;
  report["problems"] = problems;
  report["ok"] = problems.empty();
  report["report_build_s"] = num(
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 4);
  return report;
}

std::string assets_dir() {
  if (const char* env = std::getenv("TERRASTRIDE_REPORT_ASSETS_DIR"); env && *env) return env;
  return TERRASTRIDE_REPORT_ASSETS_DIR;
}

namespace {

struct Assets {
  std::string template_html;
  std::string index_html;
  std::string plotly;
};

const Assets& load_assets() {
  static const Assets assets = [] {
    const std::string dir = assets_dir();
    Assets a;
    const std::string tpl = dir + "/template.html";
    const std::string idx = dir + "/index_template.html";
    const std::string lib = dir + "/node_modules/plotly.js-dist-min/plotly.min.js";
    a.template_html = read_text(tpl);
    if (a.template_html.empty())
      throw CommandError("report template " + tpl +
                         " not found (set TERRASTRIDE_REPORT_ASSETS_DIR to the service/report folder)");
    a.index_html = read_text(idx);
    if (a.index_html.empty()) throw CommandError("report index template " + idx + " not found");
    a.plotly = read_text(lib);
    if (a.plotly.empty())
      throw CommandError("the plotting library " + lib +
                         " is not installed: run `npm ci --prefix " + dir +
                         "` (scripts/setup.sh does it)");
    return a;
  }();
  return assets;
}

}  // namespace

std::string render_html(const json& report) {
  const Assets& a = load_assets();
  std::string html = a.template_html;
  html = replace_once(html, "/*__TITLE__*/",
                      html_escape(report.value("title", std::string("report"))), "template.html");
  html = replace_once(html, "/*__PLOTLY__*/", script_safe(a.plotly), "template.html");
  html = replace_once(html, "/*__DATA__*/", script_safe(report.dump()), "template.html");
  return html;
}

std::string render_index_html(const json& index) {
  const Assets& a = load_assets();
  return replace_once(a.index_html, "/*__DATA__*/", script_safe(index.dump()),
                      "index_template.html");
}

std::string write_report(const json& report, const std::string& html_path) {
  fs::path json_path = fs::path(html_path).replace_extension(".json");
  const std::string html = render_html(report);
  perception::write_file_atomically(json_path.string(), report.dump(1) + "\n");
  perception::write_file_atomically(html_path, html);
  return json_path.string();
}

}  // namespace terrastride::service::report
