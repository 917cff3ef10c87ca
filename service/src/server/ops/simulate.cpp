// simulate: `terrastride simulate` over the socket, a plan.json object executed in MuJoCo on the
// published map (its planning surface as a heightfield), a scene (exact boxes) or a terrain
// directory under a --terrain-root (docs/protocol.md, "simulate").
#include <algorithm>
#include <chrono>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "server/backend.hpp"
#include "common/simulation_run.hpp"
#include "terrastride/simulation/simulation.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// The longest a simulate request runs (wall time, the margin search included): a client gets its
// reply (a `timeout` error) before the 300 s idle and reply timeouts clients commonly use; a 120 s
// plan at dt 1e-4 ran 301 s and its connection closed without a reply.
constexpr double kMaxWallSeconds = 240.0;
// Less than the CPU time one MuJoCo step with the controller has taken (HyQ and Go2 crawls on
// flat and pallet_15 at dt 2 ms and 0.1 ms: 18.6-24.3 us per step, 44-54 us of wall at load 6):
// a request whose steps need more than kMaxWallSeconds even at this pace cannot finish and is
// refused before it starts (`too_large`). One run never is (120 s at dt 0.1 ms: 1.2 M steps,
// 18 s); a margin search at small steps is (56 runs of them).
constexpr double kStepSecondsFloor = 15e-6;

std::string number_text(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// "pushes": [{"t": s, "force": [fx, fy, fz], "duration": s}, ...] (world frame, on the trunk).
std::vector<simulation::Push> read_pushes(const json& h) {
  std::vector<simulation::Push> pushes;
  const auto it = h.find("pushes");
  if (it == h.end()) return pushes;
  if (!it->is_array() || it->size() > 100)
    throw ProtocolError(pc::kBadRequest,
                        "pushes: an array of at most 100 {\"t\", \"force\", \"duration\"}");
  for (size_t k = 0; k < it->size(); ++k) {
    const json& p = (*it)[k];
    const std::string at = "pushes[" + std::to_string(k) + "]";
    if (!p.is_object()) throw ProtocolError(pc::kBadRequest, at + ": an object");
    for (const auto& [key, value] : p.items())
      if (key != "t" && key != "force" && key != "duration")
        throw ProtocolError(pc::kBadRequest, at + ": unknown field \"" + key + "\"");
    simulation::Push push;
    try {
      push.t = protocol::get_number(p, "t", std::nullopt);
      push.force = protocol::get_vector(p, "force", 3);
      push.duration = protocol::get_number(p, "duration", std::nullopt);
    } catch (const ProtocolError& e) {
      throw ProtocolError(pc::kBadRequest, at + ": " + e.what());
    }
    using Limits = simulation::SimulationLimits;
    if (!(push.duration >= 0 && push.duration <= Limits::kMaxPushDuration))
      throw ProtocolError(pc::kBadRequest, at + ".duration: must be in [0, " +
                                               number_text(Limits::kMaxPushDuration) + "] s");
    if (!(push.force.stableNorm() <= Limits::kMaxPushForce))
      throw ProtocolError(pc::kBadRequest, at + ".force: " + number_text(push.force.stableNorm()) +
                                               " N, more than the " +
                                               number_text(Limits::kMaxPushForce) + " N a push may have");
    pushes.push_back(push);
  }
  return pushes;
}

// The simulation's options from the request: the CLI's flags and limits (SimulationLimits).
simulation::SimulationOptions read_options(const json& h) {
  using Limits = simulation::SimulationLimits;
  simulation::SimulationOptions options;
  options.dt = protocol::get_number(h, "dt", 0.002);
  if (!(options.dt >= Limits::kMinDt && options.dt <= Limits::kMaxDt))
    throw ProtocolError(pc::kBadRequest, "dt: must be in [0.0001, 0.01] s");
  options.mass_scale = protocol::get_number(h, "mass_scale", 1.0);
  if (!(options.mass_scale > Limits::kMinMassScale && options.mass_scale < Limits::kMaxMassScale))
    throw ProtocolError(pc::kBadRequest, "mass_scale: must be in (0.1, 10)");
  options.friction = protocol::get_number(h, "friction", 0.5);
  if (!(options.friction > 0 && options.friction < Limits::kMaxFriction))
    throw ProtocolError(pc::kBadRequest, "friction: must be in (0, 5)");
  options.pushes = read_pushes(h);
  const std::string name = protocol::get_string(h, "force_distribution", std::string("clipped"));
  const auto spread = simulation::force_distribution_named(name);
  if (!spread)
    throw ProtocolError(pc::kBadRequest,
                        "force_distribution: clipped or constrained, got '" + name + "'");
  options.controller.force_distribution = *spread;
  return options;
}

// Refuses (too_large) a request whose steps cannot finish within kMaxWallSeconds even at the
// fastest pace a step has run: it would hold a worker only to time out.
void refuse_what_cannot_finish(const planner::Trajectory& plan, double dt, bool margin) {
  const long long steps = simulation::simulation_steps(plan, dt);
  const int runs = margin ? simulation::margin_max_runs({}) : 1;
  const double least_s = static_cast<double>(steps) * runs * kStepSecondsFloor;
  if (least_s <= kMaxWallSeconds) return;
  throw ProtocolError(
      pc::kTooLarge, "simulate: " + std::to_string(steps) + " steps (the plan's " +
                     number_text(plan.samples.back().t - plan.samples.front().t) + " s at dt " +
                     number_text(dt) + " s)" +
                     (margin ? " times up to " + std::to_string(runs) + " margin runs" : "") +
                     " take at least " + number_text(least_s) + " s at " +
                     number_text(kStepSecondsFloor * 1e6) + " us a step, beyond the " +
                     number_text(kMaxWallSeconds) +
                     " s a simulate request may run: raise dt, shorten the plan or drop margin");
}

// The terrain, as `plan` opens it (Backend::request_terrain); a scene (or a published scene) runs
// on its exact boxes.
RequestTerrain load_terrain(Backend& backend, const std::string& spec) {
  try {
    return backend.request_terrain(spec, "simulate", /*smooth=*/false);
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, "\"terrain\" " + spec + ": " + e.what());
  }
}

OpResult simulate(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const RequestPlan plan = read_request_plan(backend, h, "simulate");
  const robot::RobotModel& model = plan.robot;
  const planner::Trajectory& traj = plan.trajectory;
  simulation::SimulationOptions options = read_options(h);
  const bool margin = protocol::get_bool(h, "margin", false);
  const bool with_samples = protocol::get_bool(h, "samples", false);
  if (!with_samples) options.record_dt = 0.0;
  try {
    // The plan as `check` reads it, before the terrain is loaded or anything is estimated.
    simulation::validate_simulation(model, traj, options);
  } catch (const simulation::SimulationError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  refuse_what_cannot_finish(traj, options.dt, margin);
  // Stops on the request's cancel, deadline or shutdown, and after kMaxWallSeconds.
  const auto wall_limit = std::chrono::steady_clock::now() +
                          std::chrono::milliseconds(static_cast<long long>(kMaxWallSeconds * 1e3));
  options.stop_requested = [token = ctx.token, wall_limit] {
    return token->stop_requested() || std::chrono::steady_clock::now() >= wall_limit;
  };
  const RequestTerrain terrain =
      load_terrain(backend, protocol::get_string(h, "terrain", std::string("current")));
  ctx.check_stop();
  OpResult r;
  try {
    const simulation::SimulationReport rep =
        simulation::simulate_plan(model, traj, *terrain.exact, options);
    r.result = simulation_summary_json(rep, model);
    if (with_samples) r.result["samples"] = simulation_samples_json(rep, model);
    if (margin)
      r.result["margin"] =
          margin_json(simulation::simulation_margin(model, traj, *terrain.exact, options, {}));
  } catch (const simulation::SimulationCancelled& e) {
    ctx.check_stop();  // the token's reason as the protocol's error
    throw ProtocolError(pc::kTimeout, "simulate: stopped after " + number_text(kMaxWallSeconds) +
                                          " s, the most a simulate request may run (" + e.what() +
                                          ")");
  } catch (const simulation::SimulationError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  return r;
}

}  // namespace

void add_simulate_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  registry.add(
      {"simulate", OpKind::kWorker,
       "a plan executed in MuJoCo with a tracking controller (as `terrastride simulate`)",
       [b](OpContext& c) { return simulate(*b, c); },
       std::vector<std::string>{"plan", "terrain", "dt", "pushes", "mass_scale", "friction",
                                "force_distribution", "margin", "samples"}});
}

}  // namespace terrastride::service
