// The report: its sections composed into one document (report.hpp, sections.hpp).
#include "report/report.hpp"

#include <algorithm>
#include <chrono>
#include <sstream>
#include <string>
#include <vector>

#include "report/sections.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/simulation/simulation.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service::report {
namespace {

using nlohmann::json;

// One plan's part of the report: its sections in page order; its problems join `problems`.
json plan_json(const PlanInput& input, const TerrainView& terrain, const robot::RobotModel& model,
               const ReportOptions& options, json& problems) {
  const planner::Trajectory& traj = input.trajectory;
  // Display stride: about 1500 points per curve are plenty for the page.
  const size_t stride = std::max<size_t>(1, traj.samples.size() / 1500);
  json out = plan_overview(input, stride);
  out.update(path_and_feet(traj, stride));

  // Post-hoc checks (collision module): torques, leg capsules against the OctoMap, footholds.
  collision::CheckTerrain check_terrain;
  check_terrain.field = terrain.field.get();
  check_terrain.octree = terrain.octree;
  check_terrain.description = terrain.source;
  const collision::CheckReport checks =
      input.checks ? *input.checks : collision::run_checks(model, traj, check_terrain);

  // The simulated execution: the caller's (demo), or run here on the terrain when asked.
  std::shared_ptr<const simulation::SimulationReport> simulation = input.simulation;
  std::string simulation_error;
  if (!simulation && options.simulate) {
    try {
      if (!terrain.field) throw simulation::SimulationError("the terrain has no height field");
      simulation = std::make_shared<const simulation::SimulationReport>(
          simulation::simulate_plan(model, traj, *terrain.field, simulation::SimulationOptions{}));
    } catch (const simulation::SimulationError& e) {
      simulation_error = e.what();
    }
  }

  json summary = json::array();
  const PlanSections sections{input,    terrain,          model,           checks, stride, summary,
                              problems, simulation.get(), simulation_error};
  out["footholds"] = footholds_section(sections);
  out["torque"] = torque_section(sections);
  out["clearance"] = clearance_section(sections);
  out["simulation"] = simulation_section(sections);
  solver_rows(sections);
  dense_check_rows(sections);
  out["quality"] = quality_section(sections);
  out["summary"] = summary;
  out["profile"] = profile_section(traj, terrain, model, stride);
  out["checks"] = checks.keys();
  out["check_failures"] = checks.failures();
  out["checks_wall_s"] = num(checks.wall_s, 4);
  return out;
}

// The terrain rows' thresholds (stated in each row's note). The safe fraction is
// SafetyLayer::safe_fraction(), `map`'s figure: safe cells over observed (measured or interpolated)
// cells. For the robot's foot, below kSafeProblem there is next to no ground to stand on (a
// problem: the plans' footholds, if any, must be the few safe cells); below kSafeNote a note.
// The other radii get a note at most. An observed fraction below kObservedNote is a note: most
// of the grid's box was not seen.
constexpr double kSafeProblem = 0.05;
constexpr double kSafeNote = 0.5;
constexpr double kObservedNote = 0.1;

// One row per cloud input: its up estimate (terrain.json inputs[k].up). Levelled by a guess
// (--up auto), taken unchecked (--up z) or without a dominant plane to check against is a note:
// the map is only as level as that guess.
void up_rows(const json& inputs, json& summary) {
  for (const json& in : inputs) {
    const std::string method = in["method"].get<std::string>();
    const bool tilted = !in["tilt_deg"].is_null();
    std::string note = "method " + method + " (" + in["from"].get<std::string>() + ")";
    if (tilted)
      note += "; sensor " + fmt(in["sensor_height_m"].get<double>(), 2) +
              " m from the dominant plane, which holds " +
              fmt(100 * in["inlier_share"].get<double>(), 0) + " % of the points";
    else if (in.contains("problem"))
      note += "; " + in["problem"].get<std::string>();
    const bool sure = method == "pose" || (method == "check" && tilted);
    summary.push_back(row("up of " + in["path"].get<std::string>(),
                          tilted ? in["tilt_deg"] : json(method), tilted ? "deg tilt" : "",
                          sure ? "ok" : "note", note));
  }
}

// The report's own summary table: the safe fraction of every layer, and the observed fraction,
// each with a status against the thresholds above; a terrain problem goes into `problems`.
json overall_summary(const json& terrain, double resolution, json& problems) {
  json summary = json::array();
  for (const json& layer : terrain["layers"]) {
    const bool primary = &layer == &terrain["layers"][terrain["primary_layer"].get<int>()];
    const double f = layer["safe_fraction"].get<double>();
    const double radius = layer["radius_m"].get<double>();
    std::string status = "ok";
    if (f < kSafeNote) status = "note";
    if (primary && f < kSafeProblem) status = "problem";
    std::ostringstream radius_text;  // as `map` prints it (default stream format: 0.02)
    radius_text << radius;
    const std::string words = "safe for foot radius " + radius_text.str() + " m";
    summary.push_back(row(words, num(100.0 * f, 1), "% of observed cells", status,
                          std::string(primary ? "the robot's foot; " : "") + "ok at >= " +
                              fmt(100 * kSafeNote, 0) + " %, a note below" +
                              (primary ? ", a problem below " + fmt(100 * kSafeProblem, 0) + " %"
                                       : std::string())));
    if (status == "problem")
      problems.push_back(problem("terrain_unsafe", "",
                                 "only " + fmt(100.0 * f, 1) + " % of the observed cells are " +
                                     words + " (the robot's foot; a problem below " +
                                     fmt(100 * kSafeProblem, 0) + " %)"));
  }
  const double observed = terrain["observed_fraction"].get<double>();
  summary.push_back(row("observed fraction", terrain["observed_fraction"], "",
                        observed < kObservedNote ? "note" : "ok",
                        std::to_string(terrain["observed_cells"].get<size_t>()) + " of " +
                            std::to_string(terrain["cells"].get<size_t>()) + " cells of " +
                            fmt(resolution, 3) + " m; a note below " +
                            fmt(100 * kObservedNote, 0) + " %"));
  const size_t overhangs = terrain["overhang_cells"].get<size_t>();
  if (overhangs > 0) {
    summary.push_back(row("overhang cells", overhangs, "cells", "ok",
                          std::to_string(terrain["overhang_cells_over_unobserved_ground"]
                                             .get<size_t>()) +
                              " of them over ground never observed (no walkable ground there, not "
                              "in the safe fraction); the others have ground beneath with the "
                              "overhang's clearance above it"));
    summary.push_back(row("minimum free height under an overhang", terrain["min_free_height_m"],
                          "m", "ok",
                          terrain["min_free_height_m"].is_null()
                              ? "no overhang lies over observed ground"
                              : "the least room between observed ground and the underside of the "
                                "overhang above it (the overhead layer)"));
  }
  const size_t unreachable = terrain["unreachable_cells"].get<size_t>();
  if (unreachable > 0)
    summary.push_back(row("unreachable cells", unreachable, "cells", "ok",
                          "observed ground on levels no step of a leg joins to the floor's (a "
                          "cupboard top, a wall's crest): not safe, not in the safe fraction"));
  up_rows(terrain["inputs"], summary);
  return summary;
}

}  // namespace

json build_report(const TerrainView& terrain, const std::vector<PlanInput>& plans,
                  const ReportOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  json problems = json::array();
  std::string robot_name = options.robot;
  if (!plans.empty() && !plans.front().trajectory.robot.empty())
    robot_name = plans.front().trajectory.robot;
  robot::RobotModel model;
  try {
    // A plan that carries its robot is reported with that definition (planner::robot_of_plan).
    model = !plans.empty() && !plans.front().trajectory.robot_definition.empty()
                ? planner::robot_of_plan(plans.front().trajectory, plans.front().path)
                : robot::load_robot(robot::resolve_robot_path(robot_name));
  } catch (const std::exception& e) {
    throw CommandError(std::string("robot '") + robot_name + "': " + e.what());
  }

  json report{
      {"format", "terrastride-report/1"},
      {"title", options.title},
      {"generated_utc", utc_now()},
      {"robot",
       {{"name", model.name}, {"foot_radius_m", model.foot_radius}, {"mass_kg", model.mass}}}};
  report["terrain"] = terrain_section(terrain, options, model.foot_radius);

  json plan_list = json::array();
  for (const PlanInput& p : plans) {
    robot::RobotModel plan_model = model;
    if (!p.trajectory.robot_definition.empty() ? p.trajectory.robot_definition != model.definition
                                               : !p.trajectory.robot.empty() &&
                                                     p.trajectory.robot != model.name) {
      try {
        plan_model = planner::robot_of_plan(p.trajectory, p.path);
      } catch (const std::exception& e) {
        throw CommandError(p.path + ": robot '" + p.trajectory.robot + "': " + e.what());
      }
    }
    try {
      plan_list.push_back(plan_json(p, terrain, plan_model, options, problems));
    } catch (const collision::TrajectoryError& e) {
      throw CommandError(p.path + ": " + e.what());
    }
  }
  report["plans"] = plan_list;

  report["summary"] = overall_summary(report["terrain"], terrain.resolution, problems);
  report["problems"] = problems;
  report["ok"] = problems.empty();
  report["report_build_s"] =
      num(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 4);
  if (!options.clock_fields) {
    report.erase("generated_utc");
    report.erase("report_build_s");
    report["terrain"].erase("build_s");
    if (report["terrain"]["info"].is_object()) report["terrain"]["info"].erase("timings");
    for (json& p : report["plans"]) p.erase("checks_wall_s");
  }
  return report;
}

}  // namespace terrastride::service::report
