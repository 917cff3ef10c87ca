// plan: `terrastride plan` over the socket, on the published map, a scene or a terrain dir. The
// solve runs in a child process (child_process.hpp); a deadline becomes the solver's budget.
#include <algorithm>
#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "common/plan_request.hpp"
#include "server/backend.hpp"
#include "server/samples_table.hpp"
#include "common/terrain_source.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// `terrastride plan` over the socket: terrain "current" (the published map, default), a scene
// name or a terrain dir. A deadline becomes the solver's wall-clock budget.
OpResult plan(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  gait_name(h);  // a name from the data folder: the server reads no gait file a client names
  // The same reader and limits as `terrastride plan` (plan_request.hpp).
  PlanRequest req;
  try {
    req = read_plan_request(h, backend.robot());
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  const std::string& spec = req.terrain;
  planner::PlannerOptions& po = req.options;
  const double sample_dt = req.sample_dt;
  const std::string& samples_encoding = req.samples;
  const planner::WarmStart warm = req.warm_start();
  // Terrains: the optimiser needs a C2 field; exact scenes are checked as they are.
  std::shared_ptr<const MapSnapshot> snapshot;  // keeps the published map alive while planning
  std::shared_ptr<const SceneRaster> raster;
  TerrainSource dir;  // a terrain directory: its map, and its octomap.bt for the checks
  const terrain::HeightField* plan_field = nullptr;
  const terrain::HeightField* check_field = nullptr;
  try {
    if (spec == "current") {
      snapshot = backend.map();
      if (!snapshot) throw ProtocolError(pc::kNoMap, "plan on \"current\": no map loaded");
      if (const auto* sc = dynamic_cast<const terrain::Scene*>(snapshot->field.get())) {
        raster = backend.scene_raster(snapshot->source.substr(snapshot->source.find(':') + 1));
        plan_field = raster->smooth.get();
        check_field = sc;
      } else {
        plan_field = check_field = snapshot->field.get();
      }
    } else {
      if (terrain::is_scene_name(spec)) {
        raster = backend.scene_raster(spec);
        plan_field = raster->smooth.get();
        check_field = raster->scene.get();
      } else {
        dir.spec = backend.terrain_dir_path(spec, "terrain");
        dir.map = terrain::load_terrain_dir(dir.spec);
        plan_field = check_field = dir.map.get();
      }
    }
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, "\"terrain\" " + spec + ": " + e.what());
  }
  json stance_corrections;
  try {
    check_stances_on_terrain(req, backend.robot(), *check_field);
    stance_corrections = settle_stance_feet(&req, *plan_field);
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  ctx.check_stop();
  // Cancel, deadline and shutdown stop the solve within one Ipopt iteration (the planner polls
  // the token); the deadline also caps Ipopt's own wall-clock budget.
  po.should_stop = CancellationToken::as_callback(ctx.token);
  if (ctx.token->has_deadline()) {
    const double left =
        std::chrono::duration<double>(ctx.token->deadline() - std::chrono::steady_clock::now())
            .count();
    if (left <= 0) ctx.check_stop();
    po.max_time = po.max_time > 0 ? std::min(po.max_time, left) : left;
  }
  // The solve, the samples and the reply run in a child process (child_process.hpp): Debian's
  // MUMPS is not re-entrant, so two plans in one process crash it; as processes they run at
  // once, their memory goes back when they end, and cancel/deadline/shutdown kill them at once.
  auto work = [&]() -> OpResult {
    planner::PlanOutcome out;
    try {
      out = planner::plan_motion(backend.robot(), *plan_field, *check_field, po, sample_dt, warm);
    } catch (const planner::GaitError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("\"gait\": ") + e.what());
    } catch (const planner::RequestError& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    } catch (const std::invalid_argument& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    ctx.check_stop();
    const double violation = out.solve.max_violation;
    if (!out.success && violation > 1e-3)
      throw ProtocolError(
          pc::kFailed,
          "plan: " +
              (out.message.empty() ? "status " + out.trajectory.solver.status : out.message) +
              " (max violation " + std::to_string(violation) + ")");
    out.trajectory.extra["terrain"] = spec;
    if (warm.previous) out.trajectory.extra["start_time"] = warm.shift;
    if (!stance_corrections.empty())
      out.trajectory.extra["start_state_corrections"] = stance_corrections;
    // The post-hoc checks `terrastride plan` runs, on the same terrain: an exact scene voxelised
    // for the leg capsules and the trunk; a map with its OctoMap (a cloud's, or a terrain dir's
    // octomap.bt), as `terrastride plan --terrain DIR` checks it.
    collision::CheckTerrain view;
    try {
      if (raster)
        view = scene_check_terrain(*raster->scene, spec, backend.robot(), out.trajectory,
                                   kPostHocVoxel);
      else if (snapshot)
        view = snapshot_check_terrain(*snapshot, backend.robot(), out.trajectory);
      else
        view = check_terrain_for(dir, backend.robot(), out.trajectory, kPostHocVoxel, false);
    } catch (const CommandError& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    const std::vector<std::string> failures =
        add_post_hoc_checks(backend.robot(), view, &out.trajectory);
    OpResult r;
    // "attachment": the samples as one float32 table (see docs/protocol.md): building, printing
    // and parsing a JSON tree of a thousand samples costs tens of milliseconds; the table a copy.
    r.result = plan_result(out.trajectory, samples_encoding, &r.attachments,
                           [](const planner::Trajectory& t) { return planner::plan_to_json(t); });
    // Success means a usable plan: solved, and every post-hoc check passed.
    r.result["success"] = out.success && failures.empty();
    r.result["checks_passed"] = failures.empty();
    r.result["max_violation"] = violation;
    if (!out.message.empty()) r.result["message"] = out.message;
    return r;
  };
  if (!backend.options().plan_in_child_process) return work();
  return run_in_child_process(ctx, work, backend.plan_limits(), &backend.plan_processes());
}

}  // namespace

void add_plan_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  // The request fields the reader takes (plan_request.hpp): any other key is refused by name (a
  // misspelt "optimise_timing" would otherwise plan with the default silently).
  registry.add(
      {"plan", OpKind::kWorker, "plan a motion (as `terrastride plan`)",
       [b](OpContext& c) { return plan(*b, c); },
       std::vector<std::string>{"terrain", "gait", "cycles", "duration", "goal", "constraints",
                                "feasibility", "sample_dt", "samples", "optimize_timing",
                                "max_time", "init", "start_time", "start_state"}});
}

}  // namespace terrastride::service
