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

// The request's fields, read by the same reader and limits as `terrastride plan`
// (plan_request.hpp); its gait a name from the data folder (the server reads no gait file a
// client names).
PlanRequest read_request(Backend& backend, const json& h) {
  gait_name(h);
  try {
    return read_plan_request(h, backend.robot());
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
}

// The request's terrain: the optimiser needs a C2 field; exact scenes are checked as they are.
RequestTerrain open_request_terrain(Backend& backend, const std::string& spec) {
  try {
    return backend.request_terrain(spec, "plan", /*smooth=*/true);
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, "\"terrain\" " + spec + ": " + e.what());
  }
}

// Cancel, deadline and shutdown stop the solve within one Ipopt iteration (the planner polls the
// token); the deadline also caps Ipopt's own wall-clock budget.
void stop_with_request(OpContext& ctx, planner::PlannerOptions* po) {
  po->should_stop = CancellationToken::as_callback(ctx.token);
  if (!ctx.token->has_deadline()) return;
  const double left =
      std::chrono::duration<double>(ctx.token->deadline() - std::chrono::steady_clock::now())
          .count();
  if (left <= 0) ctx.check_stop();
  po->max_time = po->max_time > 0 ? std::min(po->max_time, left) : left;
}

// The solve; a plan far from feasible (max violation above 1e-3) is a failed request.
planner::PlanOutcome solve_request(Backend& backend, OpContext& ctx, const PlanRequest& req,
                                   const RequestTerrain& terrain, const planner::WarmStart& warm) {
  planner::PlanOutcome out;
  try {
    out = planner::plan_motion(backend.robot(), *terrain.smooth, *terrain.exact, req.options,
                               req.sample_dt, warm);
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
  return out;
}

// The post-hoc checks `terrastride plan` runs, on the same terrain: an exact scene voxelised for
// the leg capsules and the trunk; a map with its OctoMap (a cloud's, or a terrain dir's
// octomap.bt), as `terrastride plan --terrain DIR` checks it. Their failures.
std::vector<std::string> post_hoc_failures(Backend& backend, const RequestTerrain& terrain,
                                           const std::string& spec,
                                           planner::Trajectory* trajectory) {
  collision::CheckTerrain view;
  try {
    if (terrain.raster) {
      view = scene_check_terrain(*terrain.raster->scene, spec, backend.robot(), *trajectory,
                                 kPostHocVoxel);
    } else if (terrain.snapshot) {
      view = snapshot_check_terrain(*terrain.snapshot, backend.robot(), *trajectory);
    } else {
      TerrainSource dir;  // the map, and its octomap.bt for the checks
      dir.spec = terrain.folder.spec;
      dir.map = terrain.folder.map;
      view = check_terrain_for(dir, backend.robot(), *trajectory, kPostHocVoxel, false);
    }
  } catch (const CommandError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  return add_post_hoc_checks(backend.robot(), view, trajectory);
}

// `terrastride plan` over the socket: terrain "current" (the published map, default), a scene
// name or a terrain dir. A deadline becomes the solver's wall-clock budget.
OpResult plan(Backend& backend, OpContext& ctx) {
  PlanRequest req = read_request(backend, ctx.request.header);
  const std::string spec = req.terrain;
  const planner::WarmStart warm = req.warm_start();
  // Keeps the published map or the scene's raster alive while planning.
  const RequestTerrain terrain = open_request_terrain(backend, spec);
  json stance_corrections;
  try {
    check_stances_on_terrain(req, backend.robot(), *terrain.exact);
    stance_corrections = settle_stance_feet(&req, *terrain.smooth);
  } catch (const RequestFieldError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  ctx.check_stop();
  stop_with_request(ctx, &req.options);
  // The solve, the samples and the reply run in a child process (child_process.hpp): Debian's
  // MUMPS is not re-entrant, so two plans in one process crash it; as processes they run at
  // once, their memory goes back when they end, and cancel/deadline/shutdown kill them at once.
  auto work = [&]() -> OpResult {
    planner::PlanOutcome out = solve_request(backend, ctx, req, terrain, warm);
    out.trajectory.extra["terrain"] = spec;
    if (warm.previous) out.trajectory.extra["start_time"] = warm.shift;
    if (!stance_corrections.empty())
      out.trajectory.extra["start_state_corrections"] = stance_corrections;
    const std::vector<std::string> failures =
        post_hoc_failures(backend, terrain, spec, &out.trajectory);
    OpResult r;
    // "attachment": the samples as one float32 table (see docs/protocol.md): building, printing
    // and parsing a JSON tree of a thousand samples costs tens of milliseconds; the table a copy.
    r.result = plan_result(out.trajectory, req.samples, &r.attachments,
                           [](const planner::Trajectory& t) { return planner::plan_to_json(t); });
    // Success means a usable plan: solved, and every post-hoc check passed.
    r.result["success"] = out.success && failures.empty();
    r.result["checks_passed"] = failures.empty();
    r.result["max_violation"] = out.solve.max_violation;
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
