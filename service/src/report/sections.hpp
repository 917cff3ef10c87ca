// The report's sections, one function each, which build_report (report.cpp) composes: the
// terrain (terrain_section.cpp) and, per plan, its overview, path and feet, footholds, joint
// torques, leg clearance, solver and dense-check rows and elevation profile (plan_sections.cpp),
// and the simulated execution (simulation_section.cpp).
// Internal to the report; the document's format is report.hpp's.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstddef>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "report/report.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::service::report {

// Rounds to `digits` decimals so report.json stays small; NaN/inf become null (JSON has neither).
inline nlohmann::json num(double v, int digits = 4) {
  if (!std::isfinite(v)) return nullptr;
  const double s = std::pow(10.0, digits);
  return std::round(v * s) / s;
}

inline nlohmann::json vec3(const Eigen::Vector3d& v, int digits = 4) {
  return nlohmann::json::array({num(v.x(), digits), num(v.y(), digits), num(v.z(), digits)});
}

inline std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << v;
  return os.str();
}

// One entry of the report's problems: what broke (`id`), in which plan, in one sentence.
inline nlohmann::json problem(const std::string& id, const std::string& plan,
                              const std::string& text) {
  return {{"id", id}, {"plan", plan}, {"text", text}};
}

// One row of a summary table: status "ok", "problem", "note" or "absent" (with the reason).
inline nlohmann::json row(const std::string& label, nlohmann::json value, const std::string& unit,
                          const std::string& status, const std::string& note) {
  return {{"label", label},
          {"value", std::move(value)},
          {"unit", unit},
          {"status", status},
          {"note", note}};
}

// The terrain: the grid as drawn (heights, and per foot radius the safety margins; very large
// grids decimated), its statistics and the layer of the robot's foot radius.
nlohmann::json terrain_section(const TerrainView& terrain, const ReportOptions& options,
                               double foot_radius);

// What the sections of one plan read, and the two lists they add to, in page order.
struct PlanSections {
  const PlanInput& input;
  const TerrainView& terrain;
  const robot::RobotModel& model;
  const collision::CheckReport& checks;  // the post-hoc checks on `terrain`
  size_t stride;                         // display stride of the time series
  nlohmann::json& summary;               // rows of the plan's summary table
  nlohmann::json& problems;              // the report's problems
  // The plan's simulated execution on `terrain` (null: not simulated) or why it could not run.
  const simulation::SimulationReport* simulation = nullptr;
  std::string simulation_error;
};

// The plan's name, file, robot, gait, timing, solver figures and the checks its file holds.
nlohmann::json plan_overview(const PlanInput& input, size_t stride);
// "time", "base" and "feet": the base path and the feet with their contacts.
nlohmann::json path_and_feet(const planner::Trajectory& trajectory, size_t stride);
// The stance footholds with their safety margins; unsafe ones are problems.
nlohmann::json footholds_section(const PlanSections& s);
// Joint torques against their limits per leg and joint, and kinematic excursions.
nlohmann::json torque_section(const PlanSections& s);
// Leg capsules against the OctoMap: distances, certain collisions and uncertain contacts.
nlohmann::json clearance_section(const PlanSections& s);
// The solver's status row.
void solver_rows(const PlanSections& s);
// The dense checks of the plan file against their limits.
void dense_check_rows(const PlanSections& s);
// "Simulated execution": the MuJoCo run's tracking error over time, joint torques against their
// limits, contact events (feet planned vs actual, shin/thigh/trunk contacts) and the verdict
// (simulation_section.cpp); a "fail" is a problem, a "warn" a note.
nlohmann::json simulation_section(const PlanSections& s);
// The motion's quality figures (quality_section.cpp) as summary rows and an object.
nlohmann::json quality_section(const PlanSections& s);
// The elevation profile along the base path: ground, base, feet, and the shin points from IK.
nlohmann::json profile_section(const planner::Trajectory& trajectory, const TerrainView& terrain,
                               const robot::RobotModel& model, size_t stride);

}  // namespace terrastride::service::report
