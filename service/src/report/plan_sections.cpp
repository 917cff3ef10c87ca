// The sections of one plan in the report: path and feet, footholds, joint torques, leg clearance,
// solver, dense checks and the elevation profile (sections.hpp).
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "report/sections.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::service::report {
namespace {

using nlohmann::json;

// Problem and check thresholds: the targets of docs/design.md §12 and §6.8
// (plan.json "checks").
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
      polyline_length +=
          (traj.samples[k].base.position.head<2>() - traj.samples[k - 1].base.position.head<2>())
              .norm();
  }
  double length() const { return polyline_length; }
  double project(const Eigen::Vector2d& q) const { return (q - origin).dot(axis); }
};

const char* kJointNames[3] = {"HAA", "HFE", "KFE"};

}  // namespace

json plan_overview(const PlanInput& input, size_t stride) {
  const planner::Trajectory& traj = input.trajectory;
  const std::string& name = input.name;
  const size_t n = traj.samples.size();

  json out{{"name", name},      {"path", input.path},          {"robot", traj.robot},
           {"gait", traj.gait}, {"duration_s", traj.duration}, {"sample_dt_s", traj.sample_dt},
           {"samples", n},      {"display_stride", stride},    {"feet_names", traj.feet}};
  out["solver"] = {{"status", traj.solver.status},
                   {"iterations", traj.solver.iterations},
                   {"wall_s", num(traj.solver.wall_s, 4)},
                   {"n_variables", traj.solver.n_variables},
                   {"n_constraints", traj.solver.n_constraints}};
  json checks_in = json::object();
  for (const auto& [key, value] : traj.checks) checks_in[key] = num(value, 6);
  out["plan_checks"] = checks_in;
  return out;
}

json path_and_feet(const planner::Trajectory& traj, size_t stride) {
  const size_t n = traj.samples.size();
  const size_t n_feet = traj.feet.size();
  json t = json::array(), bx = json::array(), by = json::array(), bz = json::array();
  std::vector<json> fx(n_feet, json::array()), fy(n_feet, json::array()), fz(n_feet, json::array()),
      fc(n_feet, json::array());
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
  json feet = json::array();
  for (size_t f = 0; f < n_feet; ++f)
    feet.push_back(
        {{"name", traj.feet[f]}, {"x", fx[f]}, {"y", fy[f]}, {"z", fz[f]}, {"contact", fc[f]}});
  return {{"time", t}, {"base", {{"x", bx}, {"y", by}, {"z", bz}}}, {"feet", feet}};
}

json footholds_section(const PlanSections& s) {
  const planner::Trajectory& traj = s.input.trajectory;
  const std::string& name = s.input.name;
  const collision::CheckReport& checks = s.checks;
  const double foot_radius = s.model.foot_radius;
  json& summary = s.summary;
  json& problems = s.problems;
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
                          std::to_string(footholds.size()) +
                              " stance footholds checked, foot radius " +
                              fmt(foot_radius * 1000, 1) + " mm"));
    summary.push_back(row("worst foothold margin",
                          num(std::min(checks.footholds->worst_margin, 1e3), 4), "m",
                          checks.footholds->worst_margin < 0 ? "problem" : "ok",
                          "signed distance to the nearest unsafe cell"));
  } else {
    summary.push_back(
        row("unsafe footholds", nullptr, "", "absent", "no terrain to check against"));
  }
  if (traj.checks.count("unsafe_footholds") && traj.checks.at("unsafe_footholds") > 0 &&
      unsafe == 0) {
    problems.push_back(problem("unsafe_foothold", name,
                               "the plan file reports " +
                                   fmt(traj.checks.at("unsafe_footholds"), 0) +
                                   " unsafe footholds (on the terrain it was planned on)"));
  }
  return footholds;
}

json torque_section(const PlanSections& s) {
  const std::string& name = s.input.name;
  const collision::CheckReport& checks = s.checks;
  const robot::RobotModel& model = s.model;
  const size_t stride = s.stride;
  json& summary = s.summary;
  json& problems = s.problems;
  const auto& tr = checks.torque;
  json legs = json::array();
  for (size_t l = 0; l < tr.legs.size(); ++l) {
    const auto& series = tr.legs[l];
    json joints = json::array();
    for (int j = 0; j < 3; ++j) {
      json tau = json::array();
      for (size_t k = 0; k < series.tau.size(); k += stride)
        tau.push_back(num(series.tau[k][j], 2));
      joints.push_back({{"name", kJointNames[j]},
                        {"limit_Nm", model.legs[l].torque_limit[j]},
                        {"worst_ratio", num(series.worst_ratio[j], 4)},
                        {"tau_Nm", tau}});
    }
    legs.push_back({{"name", series.leg},
                    {"violating_samples", series.violating_samples},
                    {"joints", joints}});
  }
  json time = json::array();
  for (size_t k = 0; k < tr.time.size(); k += stride) time.push_back(num(tr.time[k], 4));
  json torque = {{"source", "collision::check_joint_torques (tau = M qdd + c + g - J^T f)"},
                 {"time", time},
                 {"legs", legs},
                 {"ratio_max", num(tr.ratio_max, 4)},
                 {"violating_samples", tr.violating_samples}};
  const bool bad = tr.ratio_max > 1.0 + 1e-9;
  std::string where;
  if (tr.worst_leg >= 0)
    where = tr.legs[tr.worst_leg].leg + " " + kJointNames[tr.worst_joint] +
            " at t = " + fmt(tr.time[tr.worst_sample], 2) + " s";
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
    if (!checks.kinematics.issues.empty())
      text += " (first: " + checks.kinematics.issues.front().message + ")";
    summary.push_back(row("kinematic excursions", u + jl, "", "problem", text));
    problems.push_back(problem("kinematics", name, text));
  }
  return torque;
}

json clearance_section(const PlanSections& s) {
  const std::string& name = s.input.name;
  const collision::CheckReport& checks = s.checks;
  const size_t stride = s.stride;
  json& summary = s.summary;
  json& problems = s.problems;
  const std::string octree_note = s.terrain.octree ? "" : "the terrain has no OctoMap";
  json clearance;
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
      legs.push_back({{"name", series.leg},
                      {"shin_m", shin},
                      {"thigh_m", thigh},
                      {"shin_certain_m", shin_c},
                      {"shin_verdict", verdict},
                      {"shin_min_m", num(series.shin_min)},
                      {"shin_certain_min_m", num(series.shin_certain_min)},
                      {"shin_collision_samples", series.shin_collision_samples},
                      {"shin_certain_samples", series.shin_certain_samples}});
    }
    json time = json::array();
    for (size_t k = 0; k < cl.time.size(); k += stride) time.push_back(num(cl.time[k], 4));
    clearance = {{"source", "collision::check_leg_clearance (FCL capsules vs the OctoMap, " +
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
    summary.push_back(row(
        "shin samples in certain collision", cl.shin_collisions_certain, "", bad ? "problem" : "ok",
        resolved ? "minimum distance to the certain solid " +
                       std::string(cl.shin_min_certain_distance >= cl.certain_resolved_below - 1e-9
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
      problems.push_back(
          problem("shin_collision", name,
                  "shin capsule certainly collides with the terrain in " +
                      std::to_string(cl.shin_collisions_certain) +
                      " samples (first at t = " + fmt(cl.first_certain_collision_t, 2) + " s; " +
                      std::to_string(cl.shin_contacts_uncertain) +
                      " more touch voxels within the map's uncertainty)"));
    if (cl.thigh_collisions_certain > 0)
      problems.push_back(problem("thigh_collision", name,
                                 "thigh capsule certainly collides with the terrain in " +
                                     std::to_string(cl.thigh_collisions_certain) + " samples"));
    clearance["deep_contact_depth_m"] = num(cl.deep_contact_depth);
  } else {
    clearance = {{"absent", "leg capsules not checked: " + octree_note}};
    summary.push_back(row("minimum shin distance", nullptr, "m", "absent", octree_note));
  }
  if (checks.trunk) {
    const auto& tr = *checks.trunk;
    const bool bad = tr.collisions_certain > 0;
    clearance["trunk"] = {{"min_m", num(tr.min_distance)},
                          {"certain_min_m", num(tr.min_certain_distance)},
                          {"collisions_certain", tr.collisions_certain},
                          {"contacts_uncertain", tr.contacts_uncertain}};
    summary.push_back(row("trunk samples in certain collision", tr.collisions_certain, "",
                          bad ? "problem" : (tr.contacts_uncertain > 0 ? "note" : "ok"),
                          "trunk box vs the terrain; minimum distance to the voxels " +
                              fmt(tr.min_distance * 1000, 1) + " mm, " +
                              std::to_string(tr.contacts_uncertain) +
                              " samples touch voxels only within the map's uncertainty"));
    if (bad)
      problems.push_back(problem("trunk_collision", name,
                                 "trunk certainly collides with the terrain in " +
                                     std::to_string(tr.collisions_certain) +
                                     " samples (first at t = " +
                                     fmt(tr.first_certain_collision_t, 2) + " s)"));
  }
  return clearance;
}

void solver_rows(const PlanSections& s) {
  const planner::Trajectory& traj = s.input.trajectory;
  const std::string& name = s.input.name;
  const bool ok = traj.solver.status == "optimal" || traj.solver.status == "solved";
  s.summary.push_back(row("solver status", traj.solver.status, "", ok ? "ok" : "problem",
                          std::to_string(traj.solver.iterations) + " iterations, " +
                              fmt(traj.solver.wall_s, 3) + " s, " +
                              std::to_string(traj.solver.n_variables) + " variables, " +
                              std::to_string(traj.solver.n_constraints) + " constraints"));
  if (!ok)
    s.problems.push_back(problem(
        "solver", name, "solver ended with status '" + traj.solver.status + "', not optimal"));
}

void dense_check_rows(const PlanSections& s) {
  const planner::Trajectory& traj = s.input.trajectory;
  const std::string& name = s.input.name;
  for (const CheckLimit& c : kDenseChecks) {
    auto it = traj.checks.find(c.key);
    double limit = c.limit;
    if (std::string(c.key) == "dynamics_linear_max_N") limit = 0.02 * s.model.mass * 9.81;
    if (it == traj.checks.end()) {
      s.summary.push_back(row(c.label, nullptr, c.unit, "absent", "not in the plan file"));
      continue;
    }
    const bool bad = it->second > limit;
    s.summary.push_back(
        row(c.label, num(it->second, 6), c.unit, bad ? "problem" : "ok",
            "limit " + fmt(limit, 4) + " " + c.unit + " (dense check of the plan)"));
    if (bad)
      s.problems.push_back(problem(c.key, name,
                                   std::string(c.label) + " " + fmt(it->second, 4) + " " + c.unit +
                                       " exceeds " + fmt(limit, 4) + " " + c.unit));
  }
}

json profile_section(const planner::Trajectory& traj, const TerrainView& terrain,
                     const robot::RobotModel& model, size_t stride) {
  const size_t n = traj.samples.size();
  const size_t n_feet = traj.feet.size();
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
  return {
      {"path_length_m", num(path.length())},
      {"axis_origin", {num(path.origin.x()), num(path.origin.y())}},
      {"axis_direction", {num(path.axis.x()), num(path.axis.y())}},
      {"s", prof_s},
      {"ground", prof_ground},
      {"base_z", prof_base},
      {"feet", prof_feet},
      {"shin_points",
       {{"s", shin_s}, {"z", shin_z}, {"leg", shin_leg}, {"height_above_ground_m", shin_clear}}}};
}

}  // namespace terrastride::service::report
