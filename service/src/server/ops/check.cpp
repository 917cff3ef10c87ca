// check: `terrastride check` over the socket, the post-hoc checks of a plan.json object against
// the published map or a scene.
#include <memory>
#include <string>
#include <vector>

#include "server/backend.hpp"
#include "terrastride/collision/checks.hpp"
#include "common/terrain_source.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// `terrastride check` over the socket: the post-hoc checks of a plan.json object against the
// current map (its OctoMap for the leg capsules and the trunk) or a scene (its exact boxes,
// voxelised where the legs go), as `terrastride check` runs them.
OpResult check(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const RequestPlan plan = read_request_plan(backend, h, "check");
  const robot::RobotModel& model = plan.robot;
  const planner::Trajectory& traj = plan.trajectory;
  const std::string spec = protocol::get_string(h, "terrain", std::string("current"));
  std::shared_ptr<const MapSnapshot> snapshot;
  std::unique_ptr<terrain::Scene> scene;
  collision::CheckTerrain terrain;
  try {
    if (spec == "current") {
      snapshot = backend.map();
      if (!snapshot) throw ProtocolError(pc::kNoMap, "check on \"current\": no map loaded");
      terrain = snapshot_check_terrain(*snapshot, model, traj);
    } else {
      scene = terrain::make_scene(spec);
      terrain = scene_check_terrain(*scene, spec, model, traj, kPostHocVoxel);
    }
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, std::string("\"terrain\": ") + e.what());
  } catch (const std::invalid_argument& e) {
    throw ProtocolError(pc::kBadRequest, std::string("\"terrain\": ") + e.what());
  }
  ctx.check_stop();
  collision::CheckReport report;
  try {
    report = collision::run_checks(model, traj, terrain);
  } catch (const std::invalid_argument& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  OpResult r;
  r.result = {{"checks", report.keys()},
              {"failures", report.failures()},
              {"passed", report.passed()},
              {"terrain", terrain.description},
              {"wall_s", report.wall_s}};
  return r;
}

}  // namespace

void add_check_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  registry.add({"check", OpKind::kWorker, "post-hoc checks of a plan (as `terrastride check`)",
                [b](OpContext& c) { return check(*b, c); },
                std::vector<std::string>{"plan", "terrain"}});
}

}  // namespace terrastride::service
