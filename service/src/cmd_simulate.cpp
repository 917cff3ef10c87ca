// `terrastride simulate`: executes a plan in MuJoCo with a tracking controller, as an independent
// judge of the plan (issue #16; collision/include/terrastride/collision/simulation.hpp).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "terrastride/collision/simulation.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;

// Exit code when the simulation ran and the plan failed (as `check`: 1 bad input, 2 usage).
constexpr int kSimulationFailed = 3;

struct SimulateCliOptions {
  std::string plan;
  std::string terrain;
  double dt = 0.002;
  std::vector<std::string> pushes;
  double mass_scale = 1.0;
  double friction = 0.5;
  std::string out;
  bool json = false;
};

json vec(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

json summary_json(const collision::SimulationReport& r, const robot::RobotModel& model,
                  const std::string& plan, const std::string& terrain) {
  const auto& th = r.thresholds;
  json legs = json::array();
  for (size_t i = 0; i < model.legs.size(); ++i)
    legs.push_back({{"leg", model.legs[i].name},
                    {"torque_max_Nm", vec(r.torque_max[i])},
                    {"saturated_s", vec(r.saturated_time[i])},
                    {"joint_limit_s", vec(r.joint_limit_time[i])},
                    {"joint_limit_impulse_Nms", vec(r.joint_limit_impulse[i])},
                    {"shin_impulse_Ns", r.shin_impulse[i]},
                    {"thigh_impulse_Ns", r.thigh_impulse[i]}});
  json stances = json::array();
  for (const auto& s : r.stances)
    stances.push_back({{"foot", model.legs[s.foot].name},
                       {"t_start", s.t_start},
                       {"t_end", s.t_end},
                       {"touched_down", s.touched_down},
                       {"touchdown_t", s.touched_down ? json(s.touchdown_t) : json()},
                       {"touchdown_error_m", s.touchdown_error},
                       {"slip_m", s.slip},
                       {"centre_drift_m", s.centre_drift}});
  return {{"plan", plan},
          {"terrain", terrain},
          {"verdict", r.verdict},
          {"reasons", r.reasons},
          {"fell", r.fell},
          {"heightfield_filled_cells", r.filled_cells},
          {"fall_t", r.fell ? json(r.fall_t) : json()},
          {"dt", r.dt},
          {"duration", r.duration},
          {"steps", r.steps},
          {"wall_s", r.wall_s},
          {"realtime_factor", r.realtime_factor},
          {"physics_wall_s", r.physics_wall_s},
          {"cpu_s", r.cpu_s},
          {"position_error_rms_m", r.position_rms},
          {"position_error_max_m", r.position_max},
          {"position_error_max_t", r.position_max_t},
          {"tilt_error_max_rad", r.tilt_max},
          {"height_drop_max_m", r.height_drop_max},
          {"saturation_fraction", r.saturation_fraction},
          {"joint_limit_impulse_max_Nms", r.joint_limit_impulse_max},
          {"joint_limit_max_s", r.joint_limit_max_s},
          {"slip_max_m", r.slip_max},
          {"centre_drift_max_m", r.centre_drift_max},
          {"touchdown_error_max_m", r.touchdown_error_max},
          {"missed_touchdowns", r.missed_touchdowns},
          {"shin_impulse_max_Ns", r.shin_impulse_max},
          {"trunk_impulse_Ns", r.trunk_impulse},
          {"legs", legs},
          {"stances", stances},
          {"thresholds",
           {{"fall_height_m", th.fall_height_m},
            {"fall_tilt_deg", th.fall_tilt_rad * 180.0 / M_PI},
            {"body_contact_impulse_Ns", th.body_contact_impulse_Ns},
            {"position_rms_m", th.position_rms_m},
            {"position_max_m", th.position_max_m},
            {"saturation_fraction", th.saturation_fraction},
            {"slip_m", th.slip_m},
            {"touchdown_error_m", th.touchdown_error_m},
            {"shin_impulse_Ns", th.shin_impulse_Ns},
            {"joint_limit_impulse_Nms", th.joint_limit_impulse_Nms}}}};
}

json samples_json(const collision::SimulationReport& r, const robot::RobotModel& model) {
  json out = json::array();
  for (const auto& s : r.samples) {
    json feet = json::array();
    for (size_t i = 0; i < model.legs.size(); ++i)
      feet.push_back({{"contact", static_cast<bool>(s.foot_contact[i])},
                      {"planned_contact", static_cast<bool>(s.planned_contact[i])},
                      {"force", vec(s.foot_force[i])},
                      {"position", vec(s.foot_position[i])},
                      {"joint_torque", vec(s.joint_torque[i])},
                      {"shin_force", s.shin_force[i]},
                      {"thigh_force", s.thigh_force[i]}});
    out.push_back(
        {{"t", s.t},
         {"base", {{"position", vec(s.base_position)}, {"euler_zyx", vec(s.base_euler_zyx)}}},
         {"planned_base",
          {{"position", vec(s.planned_position)}, {"euler_zyx", vec(s.planned_euler_zyx)}}},
         {"feet", feet},
         {"trunk_force", s.trunk_force}});
  }
  return out;
}

void print_human(const collision::SimulationReport& r, const robot::RobotModel& model,
                 const std::string& plan, const std::string& terrain) {
  std::cout << std::fixed << std::setprecision(4);
  std::cout << "plan      " << plan << "\nterrain   " << terrain << "\n";
  std::cout << "simulated " << r.duration << " s in " << r.steps << " steps of " << r.dt << " s, "
            << std::setprecision(3) << r.wall_s << " s wall (" << std::setprecision(1)
            << r.realtime_factor << "x real time; " << r.duration / std::max(r.cpu_s, 1e-9)
            << "x per CPU second)\n"
            << std::setprecision(4);
  std::cout << "base      position error RMS " << r.position_rms << " m, max " << r.position_max
            << " m (t = " << r.position_max_t << " s); orientation error max "
            << r.tilt_max * 180 / M_PI << " deg\n";
  std::cout << "torques   saturated " << 100 * r.saturation_fraction
            << " % of the time; largest end-stop impulse " << r.joint_limit_impulse_max
            << " N m s\n";
  std::cout << "feet      slip max " << r.slip_max << " m (sphere centre drift max "
            << r.centre_drift_max << " m), touchdown error max " << r.touchdown_error_max << " m, "
            << r.missed_touchdowns << " missed touchdowns\n";
  std::cout << "leg   |tau| max (HAA HFE KFE) [N m]   shin impulse [N s]   thigh impulse [N s]\n";
  for (size_t i = 0; i < model.legs.size(); ++i)
    std::cout << std::left << std::setw(6) << model.legs[i].name << std::right << std::setw(8)
              << std::setprecision(1) << r.torque_max[i][0] << std::setw(8) << r.torque_max[i][1]
              << std::setw(8) << r.torque_max[i][2] << std::setprecision(3) << std::setw(20)
              << r.shin_impulse[i] << std::setw(22) << r.thigh_impulse[i] << "\n";
  std::cout << "trunk contact impulse " << r.trunk_impulse << " N s\n\n";
  if (r.verdict == "pass") {
    std::cout << "PASS: the plan executed within every threshold\n";
  } else {
    std::cout << (r.verdict == "fail" ? "FAIL" : "WARN") << ":\n";
    for (const auto& why : r.reasons) std::cout << "  - " << why << "\n";
  }
}

void run_simulate(const SimulateCliOptions& o) {
  if (!o.out.empty()) {
    try {
      perception::check_output_file(o.out);
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--out: ") + e.what());
    }
  }
  collision::SimulationOptions sim;
  sim.dt = o.dt;
  sim.mass_scale = o.mass_scale;
  sim.friction = o.friction;
  if (!std::isfinite(o.dt) || o.dt < 1e-4 || o.dt > 0.01)
    throw CommandError("--dt: must be in [0.0001, 0.01] s");
  if (!std::isfinite(o.mass_scale) || o.mass_scale <= 0.1 || o.mass_scale >= 10)
    throw CommandError("--mass-scale: must be in (0.1, 10)");
  if (!std::isfinite(o.friction) || o.friction <= 0 || o.friction >= 5)
    throw CommandError("--friction: must be in (0, 5)");
  for (const auto& text : o.pushes) {
    const Eigen::VectorXd v = parse_numbers(text, 5, "--push");
    if (v[4] < 0) throw CommandError("--push " + text + ": the duration must not be negative");
    sim.pushes.push_back({v[0], Eigen::Vector3d(v[1], v[2], v[3]), v[4]});
  }
  planner::Trajectory traj;
  try {
    traj = planner::read_plan_file(o.plan);
  } catch (const planner::PlanFileError& e) {
    throw CommandError(e.what());
  }
  robot::RobotModel model;
  try {
    model = robot::load_robot(robot::resolve_robot_path(traj.robot.empty() ? "hyq" : traj.robot));
  } catch (const robot::RobotFileError& e) {
    throw CommandError(o.plan + ": robot: '" + traj.robot + "' cannot be loaded: " + e.what());
  }
  const auto names = terrain::scene_names();
  const bool is_scene = std::find(names.begin(), names.end(), o.terrain) != names.end();
  if (!is_scene && !std::filesystem::is_directory(o.terrain))
    throw CommandError("--terrain " + o.terrain +
                       ": neither a terrain directory from 'terrastride map' nor a scene name "
                       "(flat, pallet_10, pallet_15, eur_pallet, stairs, gap)");
  collision::SimulationReport rep;
  try {
    if (is_scene) {
      rep = collision::simulate_plan(model, traj, *terrain::make_scene(o.terrain), sim);
    } else {
      std::unique_ptr<terrain::TerrainMap> map;
      try {
        map = terrain::load_terrain_dir(o.terrain);
      } catch (const perception::InputError& e) {
        throw CommandError("--terrain " + o.terrain + ": " + e.what());
      }
      rep = collision::simulate_plan(model, traj, *map, sim);
    }
  } catch (const collision::SimulationError& e) {
    throw CommandError(o.plan + ": " + e.what());
  }
  const json summary = summary_json(rep, model, o.plan, rep.terrain);
  if (!o.out.empty()) {
    json full = summary;
    full["samples"] = samples_json(rep, model);
    try {
      perception::write_file_atomically(o.out, full.dump() + "\n");
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--out: ") + e.what());
    }
  }
  if (o.json) {
    std::cout << summary.dump() << "\n";
  } else {
    print_human(rep, model, o.plan, rep.terrain);
  }
  std::cout.flush();
  if (rep.verdict == "fail")
    throw CommandError("the plan failed in simulation: " +
                           (rep.reasons.empty() ? std::string("fall") : rep.reasons.front()),
                       kSimulationFailed);
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto opts = std::make_shared<SimulateCliOptions>();
  CLI::App* cmd = app.add_subcommand(
      "simulate",
      "Executes a plan in MuJoCo (model generated from the robot file; terrain: a scene's exact "
      "boxes or a map's elevation as a heightfield) with a tracking controller (leg "
      "gravity/Coriolis, planned forces, a trunk PD wrench "
      "over the stance feet, swing feed-forward, joint PD), as an independent judge.\n"
      "Verdict: fail on a fall (trunk 15 cm below the plan, 30 deg orientation error, trunk or "
      "thigh on the terrain); pass when base error RMS <= 2 cm and max <= 6 cm, torques saturated "
      "<= 1 % of the time, slip <= 1 cm per stance, touchdown error <= 3 cm, shin contact impulse "
      "< 5 N s, end-stop impulse of every joint <= 1 N m s; warn otherwise.\n"
      "Exit codes: 0 pass or warn; 3 fail; 1 bad input; 2 usage.");
  cmd->add_option("plan", opts->plan, "plan.json written by 'terrastride plan'")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--terrain", opts->terrain,
                  "Terrain directory from 'terrastride map' (its elevation becomes a heightfield) "
                  "or a scene name (flat, pallet_10, pallet_15, eur_pallet, stairs, gap: exact "
                  "boxes)")
      ->required();
  cmd->add_option("--dt", opts->dt, "Simulation time step (s)")->capture_default_str();
  cmd->add_option("--push", opts->pushes,
                  "T,FX,FY,FZ,DURATION: a force (N, world frame) on the trunk from T for DURATION "
                  "seconds; repeatable");
  cmd->add_option("--mass-scale", opts->mass_scale,
                  "Trunk mass and inertia times this (an unplanned payload)")
      ->capture_default_str();
  cmd->add_option("--friction", opts->friction, "Terrain friction coefficient")
      ->capture_default_str();
  cmd->add_option("--out", opts->out,
                  "Write the summary and per-sample actual vs planned base, joint torques, foot "
                  "contacts and forces, shin/thigh/trunk contact forces (every 10 ms) as JSON");
  cmd->add_flag("--json", opts->json, "Print the summary as one JSON object");
  cmd->callback([opts] { run_simulate(*opts); });
}

}  // namespace terrastride::service
