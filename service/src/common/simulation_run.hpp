// The MuJoCo execution of a plan (terrastride/simulation/simulation.hpp) as the service's callers use it:
// `simulate`, `plan --simulate`, `check --simulate`, the report's "Simulated execution" section,
// the demo and the socket's `simulate`. One JSON form of its results and one way its verdict
// joins a plan's checks, so they all say the same thing.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "terrastride/simulation/simulation.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::service {

// The run's summary: verdict and reasons, tracking, torques, contacts, per-leg and per-stance
// figures, speed and the thresholds (docs/design.md, "Simulation"; `simulate --json`).
nlohmann::json simulation_summary_json(const simulation::SimulationReport& report,
                                       const robot::RobotModel& model);

// The per-sample series (`simulate --out`): actual vs planned base, joint torques, per-foot
// contact and force, shin/thigh/trunk contact forces.
nlohmann::json simulation_samples_json(const simulation::SimulationReport& report,
                                       const robot::RobotModel& model);

// The robustness margin (`simulate --margin`).
nlohmann::json margin_json(const simulation::MarginReport& margin);

// The verdict's numeric code in plan.json's `checks` (a map of numbers): 0 pass, 1 warn, 2 fail.
double verdict_code(const std::string& verdict);

// Runs the plan on `terrain` (a scene's exact boxes, or a map's planning surface as a
// heightfield) and adds the verdict to it, as the post-hoc checks are added
// (add_post_hoc_checks): `checks` gains sim_verdict (verdict_code) and the tracking, torque and
// contact figures (sim_*); extra["post_hoc"]["simulation"] the summary; a "fail" verdict joins
// extra["post_hoc"]["failures"] and is returned (one sentence), a "warn" is reported there but
// not returned (it is not a failure). A plan the simulation cannot run (SimulationError) is a
// failure too, with extra["post_hoc"]["simulation"] = {"error"}. `report` receives the run.
std::vector<std::string> add_simulation_check(const robot::RobotModel& model,
                                              const terrain::HeightField& terrain,
                                              const simulation::SimulationOptions& options,
                                              planner::Trajectory* trajectory,
                                              simulation::SimulationReport* report = nullptr);

}  // namespace terrastride::service
