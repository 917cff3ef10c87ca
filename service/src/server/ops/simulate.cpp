// simulate: `terrastride simulate` over the socket, a plan.json object executed in MuJoCo on the
// published map (its planning surface as a heightfield), a scene (exact boxes) or a terrain
// directory under a --terrain-root (docs/protocol.md, "simulate").
#include <algorithm>
#include <memory>
#include <string>
#include <vector>

#include "server/backend.hpp"
#include "simulation_run.hpp"
#include "terrastride/collision/simulation.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// "pushes": [{"t": s, "force": [fx, fy, fz], "duration": s}, ...] (world frame, on the trunk).
std::vector<collision::Push> read_pushes(const json& h) {
  std::vector<collision::Push> pushes;
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
    collision::Push push;
    try {
      push.t = protocol::get_number(p, "t", std::nullopt);
      push.force = protocol::get_vector(p, "force", 3);
      push.duration = protocol::get_number(p, "duration", std::nullopt);
    } catch (const ProtocolError& e) {
      throw ProtocolError(pc::kBadRequest, at + ": " + e.what());
    }
    if (push.duration < 0 || push.duration > 1000)
      throw ProtocolError(pc::kBadRequest, at + ".duration: must be in [0, 1000] s");
    if (push.force.norm() > 1e6)
      throw ProtocolError(pc::kBadRequest, at + ".force: at most 1e6 N");
    pushes.push_back(push);
  }
  return pushes;
}

OpResult simulate(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const RequestPlan plan = read_request_plan(backend, h, "simulate");
  const robot::RobotModel& model = plan.robot;
  const planner::Trajectory& traj = plan.trajectory;
  // The simulation's options: the CLI's flags and limits.
  collision::SimulationOptions options;
  options.dt = protocol::get_number(h, "dt", 0.002);
  if (!(options.dt >= 1e-4 && options.dt <= 0.01))
    throw ProtocolError(pc::kBadRequest, "dt: must be in [0.0001, 0.01] s");
  options.mass_scale = protocol::get_number(h, "mass_scale", 1.0);
  if (!(options.mass_scale > 0.1 && options.mass_scale < 10))
    throw ProtocolError(pc::kBadRequest, "mass_scale: must be in (0.1, 10)");
  options.friction = protocol::get_number(h, "friction", 0.5);
  if (!(options.friction > 0 && options.friction < 5))
    throw ProtocolError(pc::kBadRequest, "friction: must be in (0, 5)");
  options.pushes = read_pushes(h);
  const bool margin = protocol::get_bool(h, "margin", false);
  const bool with_samples = protocol::get_bool(h, "samples", false);
  if (!with_samples) options.record_dt = 0.0;
  options.stop_requested = CancellationToken::as_callback(ctx.token);

  // The terrain, as `plan` resolves it; a scene (or a published scene) runs on its exact boxes.
  const std::string spec = protocol::get_string(h, "terrain", std::string("current"));
  std::shared_ptr<const MapSnapshot> snapshot;
  std::shared_ptr<const SceneRaster> raster;
  std::unique_ptr<terrain::TerrainMap> map;
  const terrain::HeightField* field = nullptr;
  try {
    if (spec == "current") {
      snapshot = backend.map();
      if (!snapshot) throw ProtocolError(pc::kNoMap, "simulate on \"current\": no map loaded");
      field = snapshot->field.get();
    } else {
      if (terrain::is_scene_name(spec)) {
        raster = backend.scene_raster(spec);
        field = raster->scene.get();
      } else {
        map = terrain::load_terrain_dir(backend.terrain_dir_path(spec, "terrain"));
        field = map.get();
      }
    }
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, "\"terrain\" " + spec + ": " + e.what());
  }
  ctx.check_stop();
  OpResult r;
  try {
    const collision::SimulationReport rep = collision::simulate_plan(model, traj, *field, options);
    r.result = simulation_summary_json(rep, model);
    if (with_samples) r.result["samples"] = simulation_samples_json(rep, model);
    if (margin)
      r.result["margin"] =
          margin_json(collision::simulation_margin(model, traj, *field, options, {}));
  } catch (const collision::SimulationCancelled&) {
    ctx.check_stop();  // the token's reason as the protocol's error
    throw ProtocolError(pc::kCancelled, "simulation stopped");
  } catch (const collision::SimulationError& e) {
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
                                "margin", "samples"}});
}

}  // namespace terrastride::service
