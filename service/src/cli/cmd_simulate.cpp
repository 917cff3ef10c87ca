// `terrastride simulate`: executes a plan in MuJoCo with a tracking controller, as an independent
// judge of the plan (collision/include/terrastride/simulation/simulation.hpp).
#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/simulation_run.hpp"
#include "common/terrain_source.hpp"
#include "terrastride/simulation/simulation.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "common/plan_request.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/server.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;

// Exit code when the simulation ran and the plan failed (as `check`: 1 bad input, 2 usage).
constexpr int kSimulationFailed = 3;

std::string format_number(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

struct SimulateCliOptions {
  std::string plan;
  std::string robot;  // --robot: for a plan that carries no robot definition
  std::string terrain;
  double dt = 0.002;
  std::vector<std::string> pushes;
  double mass_scale = 1.0;
  double friction = 0.5;
  std::string force_distribution = "clipped";
  std::string out;
  bool json = false;
  bool margin = false;
  double margin_push_time = 0.5;
  double margin_push_duration = 0.2;
  // Closed loop.
  double replan_every = 0.0;
  std::string via = "in-process";
  double horizon = 1.0;
  double replan_latency = 0.0;
  double replan_from = 0.0;
  // A re-plan's deadline: in solver iterations by default (the closed loop's answers then do
  // not depend on the machine's load: a run is reproducible), or in wall-clock time as the
  // service's steps (--replan-budget, which takes precedence when > 0).
  int replan_budget_iterations = 5;
  double replan_budget_ms = 0.0;
  double connect_timeout = 10.0;
  double step_timeout = 120.0;
};

// --via tcp://HOST:PORT or unix:PATH: each run opens a planning session on the server with the
// simulated plan as its reference ("init") and sends each measured state as plan.session.step's
// start_state (simulation::start_state_json: the terms the in-process re-planner reads back the
// same way). The session ends with the connection (the server frees it on disconnect).
simulation::ReplannerFactory socket_replanner(const SimulateCliOptions& o,
                                             const planner::Trajectory& plan) {
  auto init = std::make_shared<const json>(planner::plan_to_json(plan));
  return [o, init, feet = plan.feet]() -> simulation::Replanner {
    auto client = std::make_shared<Client>(Client::connect(o.via, o.connect_timeout));
    client->set_timeout(o.step_timeout);
    const json opened = client->call_ok({{"op", "plan.session.open"},
                                         {"terrain", o.terrain},
                                         {"init", *init},
                                         {"horizon", o.horizon}});
    const std::string id = opened.at("session").get<std::string>();
    json budget = {{"budget_ms", o.replan_budget_ms}};
    if (o.replan_budget_ms <= 0 && o.replan_budget_iterations > 0)
      budget = {{"budget_ms", 0.0}, {"budget_iterations", o.replan_budget_iterations}};
    return [client, id, feet, budget](const simulation::MeasuredState& ms) {
      simulation::Replan out;
      out.start_time = ms.t;
      json request = {{"op", "plan.session.step"},
                      {"session", id},
                      {"time", ms.t},
                      {"start_state", simulation::start_state_json(ms, feet)}};
      request.update(budget);
      const protocol::Message reply = client->call(request);
      const std::string error = error_text(reply);
      if (!error.empty()) {
        out.message = error;
        return out;
      }
      const json& r = reply.header.at("result");
      try {
        out.plan = planner::plan_from_json(r, "plan.session.step reply");
      } catch (const planner::PlanFileError& e) {
        throw ClientError(std::string("plan.session.step: unreadable reply: ") + e.what());
      }
      out.start_time = r.value("start_time", ms.t);
      out.iterations = out.plan.solver.iterations;
      out.fallback = r.value("fallback", false);
      out.fallback_reason = r.value("fallback_reason", std::string());
      if (auto it = out.plan.extra.find("session"); it != out.plan.extra.end()) out.session = *it;
      out.success = true;
      return out;
    };
  };
}

// The closed loop's steps: how many fell back (and why), how many overran the budget, and the
// steps that did either.
void print_replan_steps(const simulation::SimulationReport& r, double budget_ms) {
  int deadline = 0, failed = 0, over = 0, own = 0;
  for (const auto& s : r.replan_records) {
    deadline += s.fallback == "deadline" || s.fallback == "iterations";
    failed += s.fallback == "solve_failed";
    over += budget_ms > 0 && 1e3 * s.wall_s > budget_ms;
  }
  std::cout << "          steps: " << r.replan_records.size() << ", fallbacks " << r.replan_fallbacks
            << " (" << deadline << " at the deadline, " << failed << " failed solves), "
            << over << " answered after the " << budget_ms << " ms budget\n";
  for (const auto& s : r.replan_records)
    if (s.fallback.empty()) ++own;
  std::cout << "          own solutions: " << own << " of " << r.replan_records.size() << "\n";
  for (const auto& s : r.replan_records)
    if (!s.fallback.empty() || (budget_ms > 0 && 1e3 * s.wall_s > budget_ms))
      std::cout << "            t = " << s.t << " s: " << 1e3 * s.wall_s << " ms, "
                << s.iterations << " iterations" << (s.fallback.empty() ? "" : ", fallback: ")
                << s.fallback << "\n";
}

void print_human(const simulation::SimulationReport& r, const robot::RobotModel& model,
                 const std::string& plan, const std::string& terrain, double budget_ms) {
  std::cout << std::fixed << std::setprecision(4);
  std::cout << "plan      " << plan << "\nterrain   " << terrain << "\n";
  std::cout << "simulated " << r.duration << " s in " << r.steps << " steps of " << r.dt << " s, "
            << std::setprecision(3) << r.wall_s << " s wall (" << std::setprecision(1)
            << r.realtime_factor << "x real time; " << r.duration / std::max(r.cpu_s, 1e-9)
            << "x per CPU second)\n"
            << std::setprecision(4);
  std::cout << "base      position error RMS " << r.position_rms << " m, max " << r.position_max
            << " m (t = " << r.position_max_t << " s); orientation error max "
            << r.tilt_max * 180 / M_PI << " deg\n";
  std::cout << "torques   saturated " << 100 * r.saturation_fraction
            << " % of the time; largest end-stop impulse " << r.joint_limit_impulse_max
            << " N m s\n";
  std::cout << "feet      slip max " << r.slip_max << " m (sphere centre drift max "
            << r.centre_drift_max << " m), touchdown error max " << r.touchdown_error_max << " m, "
            << r.missed_touchdowns << " missed touchdowns\n";
  std::cout << "leg   |tau| max (HAA HFE KFE) [N m]   shin impulse [N s]   thigh impulse [N s]\n";
  for (size_t i = 0; i < model.legs.size(); ++i)
    std::cout << std::left << std::setw(6) << model.legs[i].name << std::right << std::setw(8)
              << std::setprecision(1) << r.torque_max[i][0] << std::setw(8) << r.torque_max[i][1]
              << std::setw(8) << r.torque_max[i][2] << std::setprecision(3) << std::setw(20)
              << r.shin_impulse[i] << std::setw(22) << r.thigh_impulse[i] << "\n";
  std::cout << "trunk contact impulse " << r.trunk_impulse << " N s\n";
  if (r.replans > 0) {
    double total = 0.0;
    for (double w : r.replan_wall_s) total += w;
    std::cout << std::setprecision(3) << "re-plans  " << r.replans << " (" << r.replan_failures
              << " failed, the previous plan kept), planner per re-plan: wall median "
              << 1e3 * r.replan_wall_median << " ms, max " << 1e3 * r.replan_wall_max
              << " ms; this thread's CPU median " << 1e3 * r.replan_cpu_median << " ms, max "
              << 1e3 * r.replan_cpu_max << " ms; wall total " << total << " s (the simulation waits for it: simulated time "
              << "does not pass while the planner runs); base max " << r.reference_position_max
              << " m from the original plan\n";
    if (!r.replan_first_failure.empty())
      std::cout << "          first failure: " << r.replan_first_failure << "\n";
    print_replan_steps(r, budget_ms);
  }
  std::cout << "\n";
  if (r.verdict == "pass") {
    std::cout << "PASS: the plan executed within every threshold\n";
  } else {
    std::cout << (r.verdict == "fail" ? "FAIL" : "WARN") << ":\n";
    for (const auto& why : r.reasons) std::cout << "  - " << why << "\n";
  }
}

void print_margin(const json& m) {
  std::cout << std::setprecision(3) << std::defaultfloat;
  std::cout << "\nrobustness margin (survives = verdict not 'fail'; " << m["runs"] << " runs in "
            << m["wall_s"].get<double>() << " s)\n";
  if (m["nominal_verdict"] == "fail") {
    std::cout << "  none: the plan fails without any disturbance\n";
    return;
  }
  const json& p = m["push"];
  auto side = [](const json& s) {
    std::ostringstream o;
    o.precision(4);
    o << s["survived"].get<double>();
    if (s["failed"].is_null())
      o << " (no failure up to the ceiling)";
    else
      o << " (fails at " << s["failed"].get<double>() << ": " << s.value("failure", "") << ")";
    return o.str();
  };
  std::cout << "  lateral push of " << p["duration_s"].get<double>()
            << " s at t = " << p["t"].get<double>()
            << " s (perpendicular to the planned heading):\n"
            << "    left  " << side(p["left"]) << " N\n"
            << "    right " << side(p["right"]) << " N\n"
            << "    margin " << p["margin_N"].get<double>() << " N ("
            << p["margin_Ns"].get<double>() << " N s)"
            << (p["at_ceiling"].get<bool>() ? ", at the search's ceiling" : "") << "\n";
  if (m.contains("mass"))
    std::cout << "  trunk mass scale: heavier " << side(m["mass"]["heavier"]) << "\n"
              << "                    lighter " << side(m["mass"]["lighter"]) << "\n";
}

// The simulation's own options (--dt, --mass-scale, --friction, --push), each checked against the
// simulator's limits and named when out of them.
simulation::SimulationOptions simulation_options_from(const SimulateCliOptions& o) {
  simulation::SimulationOptions sim;
  sim.dt = o.dt;
  sim.mass_scale = o.mass_scale;
  sim.friction = o.friction;
  const auto spread = simulation::force_distribution_named(o.force_distribution);
  if (!spread) throw CommandError("--force-distribution: clipped or constrained");
  sim.controller.force_distribution = *spread;
  using Limits = simulation::SimulationLimits;
  if (!(o.dt >= Limits::kMinDt && o.dt <= Limits::kMaxDt))
    throw CommandError("--dt: must be in [0.0001, 0.01] s");
  if (!(o.mass_scale > Limits::kMinMassScale && o.mass_scale < Limits::kMaxMassScale))
    throw CommandError("--mass-scale: must be in (0.1, 10)");
  if (!(o.friction > 0 && o.friction < Limits::kMaxFriction))
    throw CommandError("--friction: must be in (0, 5)");
  if (o.pushes.size() > Limits::kMaxPushes)
    throw CommandError("--push: at most " + std::to_string(Limits::kMaxPushes) + " pushes");
  for (const auto& text : o.pushes) {
    const Eigen::VectorXd v = parse_numbers(text, 5, "--push");
    if (v[4] < 0 || v[4] > Limits::kMaxPushDuration)
      throw CommandError("--push " + text + ": the duration must be within [0, " +
                         format_number(Limits::kMaxPushDuration) + "] s");
    const Eigen::Vector3d force(v[1], v[2], v[3]);
    // MuJoCo's state turns non-finite under absurd forces (1e12 N): refused, not simulated.
    if (force.stableNorm() > Limits::kMaxPushForce)
      throw CommandError("--push " + text + ": a force of " + format_number(force.stableNorm()) +
                         " N, more than the " + format_number(Limits::kMaxPushForce) +
                         " N a push may have");
    sim.pushes.push_back({v[0], force, v[4]});
  }
  return sim;
}

// The closed loop's options (--replan-every and those it takes).
void check_closed_loop_options(const SimulateCliOptions& o) {
  if (!std::isfinite(o.replan_every) || o.replan_every < 0 || o.replan_every > 100)
    throw CommandError("--replan-every: must be within [0, 100] s (0 = open loop)");
  if (o.replan_every > 0 && o.replan_every < o.dt)
    throw CommandError("--replan-every: must be at least --dt");
  if (!std::isfinite(o.horizon) || o.horizon < 0 || o.horizon > planner::PlanLimits::kMaxDuration)
    throw CommandError("--horizon: must be within [0, " +
                       std::to_string(planner::PlanLimits::kMaxDuration) +
                       "] s (0 = every re-plan to the goal)");
  if (!std::isfinite(o.replan_latency) || o.replan_latency < 0 ||
      (o.replan_every > 0 && o.replan_latency >= o.replan_every))
    throw CommandError("--replan-latency: must be within [0, --replan-every)");
  if (!std::isfinite(o.replan_from) || o.replan_from < 0)
    throw CommandError("--replan-from: must be a time of the plan, at least 0 s");
  if (!(o.replan_budget_ms >= 0 && o.replan_budget_ms <= 60000))
    throw CommandError("--replan-budget: must be within [0, 60000] ms (0 = wait for each solve)");
}

// --via: in-process or a server's address (with its timeouts); true for a server.
bool check_via(const SimulateCliOptions& o) {
  const bool via_socket = o.via.rfind("tcp://", 0) == 0 || o.via.rfind("unix:", 0) == 0;
  if (o.via != "in-process" && !via_socket)
    throw CommandError("--via " + o.via + ": must be in-process, tcp://HOST:PORT or unix:PATH");
  if (via_socket) {
    if (!std::isfinite(o.connect_timeout) || o.connect_timeout <= 0 || o.connect_timeout > 600)
      throw CommandError("--connect-timeout: must be within (0, 600] s");
    if (!std::isfinite(o.step_timeout) || o.step_timeout <= 0 || o.step_timeout > 3600)
      throw CommandError("--step-timeout: must be within (0, 3600] s");
    try {
      parse_listen_address(o.via);
    } catch (const std::invalid_argument& e) {
      throw CommandError("--via " + o.via + ": " + e.what());
    }
  }
  return via_socket;
}

// --terrain: a scene (its exact boxes), a map folder or an OctoMap (the map's surface as a
// heightfield), opened as every command opens a terrain (terrain::open_terrain).
TerrainSource simulated_terrain(const SimulateCliOptions& o) {
  return load_terrain_source(o.terrain, /*smooth_scene=*/false,
                             "point clouds are not simulated on directly; run 'terrastride map " +
                                 o.terrain + " --out DIR' and pass --terrain DIR");
}

void check_margin_options(const SimulateCliOptions& o) {
  if (!o.margin) return;
  if (!std::isfinite(o.margin_push_time) || o.margin_push_time < 0 || o.margin_push_time >= 1)
    throw CommandError("--margin-push-time: must be in [0, 1)");
  if (!std::isfinite(o.margin_push_duration) || o.margin_push_duration <= 0 ||
      o.margin_push_duration > 2)
    throw CommandError("--margin-push-duration: must be in (0, 2] s");
}

// Closed loop: the re-planner in this process (the plan's options, planning on the 2 cm
// B-spline of a scene or the map's own field, checking on the exact terrain, as `plan` does) or
// through a server. The in-process one plans on `replan_terrain`, which must outlive the run.
void add_replanner(const SimulateCliOptions& o, const planner::Trajectory& traj,
                   const robot::RobotModel& model, bool via_socket,
                   simulation::SimulationOptions* sim,
                   std::unique_ptr<TerrainSource>* replan_terrain) {
  if (!(o.replan_every > 0)) return;
  sim->replan_every = o.replan_every;
  sim->replan_latency = o.replan_latency;
  sim->replan_from = o.replan_from;
  // No step is taken within a plan's last kNoReplanTail: a start after that would silently run
  // open loop.
  constexpr double tail = simulation::SimulationLimits::kNoReplanTail;
  if (o.replan_from > traj.duration - tail)
    throw CommandError("--replan-from " + format_number(o.replan_from) +
                       ": no re-plan is taken within the plan's last " + format_number(tail) +
                       " s (the plan lasts " + format_number(traj.duration) + " s)");
  if (via_socket) {
    sim->replanner = socket_replanner(o, traj);
    return;
  }
  *replan_terrain = std::make_unique<TerrainSource>(
      load_terrain_source(o.terrain, /*smooth_scene=*/true, "not a terrain directory"));
  PlanRequest req;
  try {
    req = read_plan_request({{"terrain", o.terrain}, {"init", planner::plan_to_json(traj)}},
                            model);
  } catch (const RequestFieldError& e) {
    throw CommandError(o.plan + ": as a re-planning session's reference: " + e.what());
  }
  sim->replanner = simulation::session_replanner(
      model, *(*replan_terrain)->smooth(), *(*replan_terrain)->exact(), req.options, traj,
      o.horizon, req.sample_dt, 1e-3 * o.replan_budget_ms, o.replan_budget_iterations);
}

// --margin: the robustness margin's search (its runs repeat the plan some 50 times, bisections on
// the verdict), as JSON.
json search_margin(const SimulateCliOptions& o, const robot::RobotModel& model,
                   const planner::Trajectory& traj, const terrain::HeightField& terrain,
                   const simulation::SimulationOptions& sim) {
  simulation::MarginOptions mo;
  mo.push_time_fraction = o.margin_push_time;
  mo.push_duration = o.margin_push_duration;
  const bool tty = isatty(STDERR_FILENO) && !o.json;
  if (tty) std::cerr << "searching the robustness margin (about 50 runs) ..." << std::flush;
  json margin;
  try {
    margin = margin_json(simulation::simulation_margin(model, traj, terrain, sim, mo));
  } catch (const simulation::SimulationError& e) {
    if (tty) std::cerr << "\n";
    throw CommandError("--margin: " + std::string(e.what()));
  } catch (const ClientError& e) {
    if (tty) std::cerr << "\n";
    throw CommandError("--margin: --via " + o.via + ": " + e.what());
  }
  if (tty) std::cerr << "\r" << std::string(52, ' ') << "\r" << std::flush;
  return margin;
}

// --out: the summary and the run's samples.
void write_simulation_file(const SimulateCliOptions& o, const json& summary,
                           const simulation::SimulationReport& rep,
                           const robot::RobotModel& model) {
  json full = summary;
  full["samples"] = simulation_samples_json(rep, model);
  try {
    perception::write_file_atomically(o.out, full.dump() + "\n");
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
}

void run_simulate(const SimulateCliOptions& o) {
  if (!o.out.empty()) {
    try {
      perception::check_output_file(o.out);
    } catch (const perception::InputError& e) {
      throw CommandError(std::string("--out: ") + e.what());
    }
  }
  simulation::SimulationOptions sim = simulation_options_from(o);
  check_closed_loop_options(o);
  const bool via_socket = check_via(o);
  PlanWithRobot loaded = read_plan_with_robot(o.plan, o.robot);
  const planner::Trajectory& traj = loaded.trajectory;
  const robot::RobotModel& model = loaded.robot;
  const TerrainSource terrain_source = simulated_terrain(o);
  const terrain::HeightField& terrain = *terrain_source.exact();
  check_margin_options(o);
  std::unique_ptr<TerrainSource> replan_terrain;
  add_replanner(o, traj, model, via_socket, &sim, &replan_terrain);
  simulation::SimulationReport rep;
  try {
    rep = simulation::simulate_plan(model, traj, terrain, sim);
  } catch (const simulation::SimulationError& e) {
    throw CommandError(o.plan + ": " + e.what());
  } catch (const ClientError& e) {
    throw CommandError("--via " + o.via + ": " + e.what());
  }
  json summary = simulation_summary_json(rep, model);
  summary["plan"] = o.plan;
  if (o.margin) summary["margin"] = search_margin(o, model, traj, terrain, sim);
  if (!o.out.empty()) write_simulation_file(o, summary, rep, model);
  if (o.json) {
    std::cout << summary.dump() << "\n";
  } else {
    print_human(rep, model, o.plan, rep.terrain, o.replan_every > 0 ? o.replan_budget_ms : 0.0);
    if (summary.contains("margin")) print_margin(summary["margin"]);
  }
  std::cout.flush();
  if (rep.verdict == "fail")
    throw CommandError("the plan failed in simulation: " +
                           (rep.reasons.empty() ? std::string("fall") : rep.reasons.front()),
                       kSimulationFailed);
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto opts = std::make_shared<SimulateCliOptions>();
  CLI::App* cmd = app.add_subcommand(
      "simulate",
      "Executes a plan in MuJoCo (model generated from the robot file; terrain: a scene's exact "
      "boxes or a map's elevation as a heightfield) with a tracking controller (leg "
      "gravity/Coriolis, planned forces, a trunk PD wrench "
      "over the stance feet, swing feed-forward, joint PD), as an independent judge.\n"
      "Verdict: fail on a fall (trunk 15 cm below the plan, 30 deg orientation error, trunk or "
      "thigh on the terrain); pass when base error RMS <= 2 cm and max <= 6 cm, torques saturated "
      "<= 1 % of the time, slip <= 1 cm per stance, touchdown error <= 3 cm, shin contact impulse "
      "< 5 N s, end-stop impulse of every joint <= 1 N m s; warn otherwise.\n"
      "Closed loop (--replan-every): the measured state is re-planned from at that period "
      "(in this process or through a server, --via) and the controller tracks each new plan; the "
      "verdict then judges tracking and falls against the plan being tracked at each instant.\n"
      "Exit codes: 0 pass or warn; 3 fail; 1 bad input or unreachable server; 2 usage.");
  cmd->add_option("plan", opts->plan, "plan.json written by 'terrastride plan'")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--robot", opts->robot,
                  "Robot name or file, for a plan written before plans carried their robot "
                  "(a plan that carries one is judged with it)");
  cmd->add_option("--terrain", opts->terrain,
                  "Terrain directory from 'terrastride map' or OctoMap file (.bt, .ot; its elevation "
                  "becomes a heightfield) "
                  "or a scene name (exact boxes: " + terrain::scene_names_text() + ")")
      ->required();
  cmd->add_option("--dt", opts->dt, "Simulation time step (s)")->capture_default_str();
  cmd->add_option("--push", opts->pushes,
                  "T,FX,FY,FZ,DURATION: a force (N, world frame) on the trunk from T for DURATION "
                  "seconds; repeatable");
  cmd->add_option("--mass-scale", opts->mass_scale,
                  "Trunk mass and inertia times this (an unplanned payload)")
      ->capture_default_str();
  cmd->add_option("--friction", opts->friction, "Terrain friction coefficient")
      ->capture_default_str();
  cmd->add_option("--force-distribution", opts->force_distribution,
                  "How the controller's stance feet share its trunk wrench: clipped (least-norm "
                  "forces, each clipped into its friction cone) or constrained (the wrench "
                  "nearest to it with every foot within its friction pyramid, a bounded "
                  "least-squares problem; keeps the feet loaded after a push)")
      ->check(CLI::IsMember({"clipped", "constrained"}))
      ->capture_default_str();
  cmd->add_option("--out", opts->out,
                  "Write the summary and per-sample actual vs planned base, joint torques, foot "
                  "contacts and forces, shin/thigh/trunk contact forces (every 10 ms) as JSON");
  cmd->add_flag("--json", opts->json, "Print the summary as one JSON object");
  cmd->add_flag("--margin", opts->margin,
                "Also search the robustness margin: the largest lateral push (left and right) "
                "and trunk mass error the plan survives (verdict not 'fail'), by bisection "
                "(about 50 runs)");
  cmd->add_option("--margin-push-time", opts->margin_push_time,
                  "With --margin: the push starts at this fraction of the plan's duration")
      ->capture_default_str();
  cmd->add_option("--margin-push-duration", opts->margin_push_duration,
                  "With --margin: the push lasts this long (s)")
      ->capture_default_str();
  cmd->add_option("--replan-every", opts->replan_every,
                  "Closed loop: every this many seconds of simulated time the measured state "
                  "(MuJoCo's trunk pose and twist, feet) goes to a planning session whose "
                  "reference is PLAN, and the controller tracks each new plan (0 = open loop). "
                  "The simulation waits for the planner: its compute time is reported, not "
                  "simulated (see --replan-latency)")
      ->capture_default_str();
  cmd->add_option("--via", opts->via,
                  "With --replan-every: in-process (a planning session in this process) or "
                  "tcp://HOST:PORT / unix:PATH of a 'terrastride serve' (plan.session.* with PLAN "
                  "as the reference; the server must know --terrain)")
      ->capture_default_str();
  cmd->add_option("--horizon", opts->horizon,
                  "With --replan-every: each re-plan's horizon (s; to the first contact switch "
                  "after it, the base held at PLAN's state there); 0 = every re-plan to the goal")
      ->capture_default_str();
  cmd->add_option("--replan-latency", opts->replan_latency,
                  "With --replan-every: a re-plan is tracked this much simulated time after the "
                  "state it starts from was measured (s)")
      ->capture_default_str();
  cmd->add_option("--replan-from", opts->replan_from,
                  "With --replan-every: re-plan from this time of the plan on (s; the first "
                  "period at or after it), tracking the plan open loop until then, as the push "
                  "benchmark does 0.5 s before its push")
      ->capture_default_str();
  cmd->add_option("--replan-iterations", opts->replan_budget_iterations,
                  "With --replan-every: each re-plan's budget in solver iterations (a deadline "
                  "that does not depend on the machine's load): a solve that has not converged "
                  "within it answers with the current plan from the measured time (a fallback, "
                  "reported per step) and its plan, if it converges later, is the next re-plan's "
                  "start; 0 = wait for each solve")
      ->check(CLI::Range(0, 1000))
      ->capture_default_str();
  cmd->add_option("--replan-budget", opts->replan_budget_ms,
                  "With --replan-every: each re-plan's wall-clock budget (ms) instead, as the "
                  "service's steps: it answers by then with its new plan or, when the solve has "
                  "not finished or failed, the current plan from the measured time; 0 = the "
                  "iteration budget (--replan-iterations)")
      ->capture_default_str();
  cmd->add_option("--connect-timeout", opts->connect_timeout,
                  "With --via tcp/unix: seconds to wait for the server's connection")
      ->capture_default_str();
  cmd->add_option("--step-timeout", opts->step_timeout,
                  "With --via tcp/unix: seconds to wait for one reply of the server")
      ->capture_default_str();
  cmd->callback([opts] { run_simulate(*opts); });
}

}  // namespace terrastride::service
