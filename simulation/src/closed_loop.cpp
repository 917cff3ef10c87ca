// The closed loop's pieces that do not touch MuJoCo (terrastride/simulation/simulation.hpp): the measured
// state in plan.json's start-state terms, and the in-process re-planner over a PlanningSession.
#include <memory>
#include <stdexcept>

#include "terrastride/simulation/simulation.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planning_session.hpp"

namespace terrastride::simulation {

namespace {

nlohmann::json vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

}  // namespace

nlohmann::json start_state_json(const MeasuredState& state, const std::vector<std::string>& feet) {
  if (state.foot_position.size() != feet.size() || state.foot_velocity.size() != feet.size())
    throw SimulationError("measured state: " + std::to_string(state.foot_position.size()) +
                          " feet, the plan has " + std::to_string(feet.size()));
  nlohmann::json j;
  j["base"] = {{"position", vec(state.base_position)},
               {"euler_zyx", vec(state.base_euler_zyx)},
               {"linear_velocity", vec(state.base_linear_velocity)},
               {"angular_velocity", vec(state.base_angular_velocity)}};
  j["feet"] = nlohmann::json::object();
  for (std::size_t f = 0; f < feet.size(); ++f)
    j["feet"][feet[f]] = {{"position", vec(state.foot_position[f])},
                          {"velocity", vec(state.foot_velocity[f])}};
  return j;
}

ReplannerFactory session_replanner(const robot::RobotModel& robot,
                                   const terrain::HeightField& plan_terrain,
                                   const terrain::HeightField& check_terrain,
                                   const planner::PlannerOptions& options,
                                   const planner::Trajectory& reference, double horizon,
                                   double sample_dt, double budget, int budget_iterations) {
  auto ref = std::make_shared<const planner::Trajectory>(reference);
  const planner::PlannerOptions opts = options;
  return [&robot, &plan_terrain, &check_terrain, opts, ref, horizon, sample_dt,
          budget, budget_iterations]() -> Replanner {
    std::shared_ptr<planner::PlanningSession> session;
    try {
      session = std::make_shared<planner::PlanningSession>(robot, plan_terrain, check_terrain,
                                                           opts, *ref, horizon, sample_dt);
    } catch (const std::invalid_argument& e) {
      throw SimulationError(std::string("re-planning session: ") + e.what());
    }
    return [session, budget, budget_iterations](const MeasuredState& ms) {
      Replan out;
      out.start_time = ms.t;
      const planner::Trajectory& reference = session->reference();
      try {
        // As plan.session.step reads a "start_state": onto the session's current plan at t.
        const double t0 = session->previous_start_time();
        const bool on_previous = ms.t >= t0 && ms.t <= t0 + session->previous().duration;
        const planner::Trajectory& from = on_previous ? session->previous() : reference;
        const planner::SrbdProblem::StartState start = planner::start_state_from_json(
            start_state_json(ms, reference.feet), "measured state", from,
            on_previous ? ms.t - t0 : ms.t);
        planner::StepLimits limits;
        limits.budget = budget;
        if (budget <= 0.0) limits.iterations = budget_iterations;
        planner::SessionStep step = session->step(start, ms.t, limits);
        out.success = step.outcome.success;
        out.iterations = step.outcome.solve.iterations;
        out.fallback = step.fallback;
        out.fallback_reason = step.fallback_reason;
        out.message = step.outcome.message;
        out.start_time = step.start_time;
        out.plan = std::move(step.outcome.trajectory);
        if (auto it = out.plan.extra.find("session"); it != out.plan.extra.end()) out.session = *it;
        // A step whose solve failed (no budget): why, with the families still violated.
        if (!out.success && !out.message.empty()) out.session["failure"] = out.message;
      } catch (const std::exception& e) {
        // A state the planner refuses (non-finite after a blow-up, a time outside the plan).
        out.success = false;
        out.message = e.what();
      }
      return out;
    };
  };
}

}  // namespace terrastride::simulation
