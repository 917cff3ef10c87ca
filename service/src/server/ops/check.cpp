// check: `terrastride check` over the socket, the post-hoc checks of a plan.json object against
// the published map or a scene.
#include <memory>
#include <string>
#include <vector>

#include "server/backend.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/plan_io.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// `terrastride check` over the socket: the post-hoc checks of a plan.json object against the
// current map (or a scene). The server keeps no OctoMap, so the capsule (shin/thigh) checks do
// not run here and their keys are absent, never faked.
OpResult check(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const auto it = h.find("plan");
  if (it == h.end() || !it->is_object())
    throw ProtocolError(pc::kBadRequest, "check needs \"plan\": a plan.json object");
  planner::Trajectory traj;
  try {
    traj = planner::plan_from_json(*it, "plan");
  } catch (const std::exception& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  robot::RobotModel model = backend.robot();
  if (!traj.robot.empty() && traj.robot != backend.robot().name) {
    // A robot name from the data folder, never a path a client names (see gait_name).
    if (!is_plain_name(traj.robot))
      throw ProtocolError(pc::kBadRequest, "plan.robot: a robot name (e.g. " +
                                               backend.robot().name +
                                               "); the server reads no robot files a client names");
    try {
      model = robot::load_robot(robot::resolve_robot_path(traj.robot));
    } catch (const robot::RobotFileError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("plan.robot: ") + e.what());
    }
  }
  const std::string spec = protocol::get_string(h, "terrain", std::string("current"));
  std::shared_ptr<const MapSnapshot> snapshot;
  std::unique_ptr<terrain::Scene> scene;
  collision::CheckTerrain terrain;
  if (spec == "current") {
    snapshot = backend.map();
    if (!snapshot) throw ProtocolError(pc::kNoMap, "check on \"current\": no map loaded");
    terrain.field = snapshot->field.get();
    terrain.description = snapshot->source;
  } else {
    try {
      scene = terrain::make_scene(spec);
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("\"terrain\": ") + e.what());
    }
    terrain.field = scene.get();
    terrain.description = "scene:" + spec;
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
