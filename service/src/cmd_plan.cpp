// `terrastride plan`: SRBD trajectory optimisation from a start to a goal over a terrain.
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "terrain_source.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {
namespace {

struct PlanCliOptions {
  std::string terrain;
  std::string robot = "hyq";
  std::string gait = "crawl";
  int cycles = 3;
  double duration = 0.0;
  bool duration_given = false;
  std::string goal;
  std::string constraints = "baseline";
  std::vector<std::string> feasibility;  // NAME=VALUE settings of the constraint sets
  double sample_dt = 0.01;
  double max_time = 0.0;
  std::string init;
  double start_time = 0.0;
  std::string start_state;  // measured state to re-plan from (JSON file), with init
  bool optimize_timing = false;
  bool verbose = false;
  bool json = false;
  std::string out;
};

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

// A plan request's field as this command names it: "sample_dt" -> "--sample-dt",
// "init.duration" -> "--init: duration".
std::string cli_field(const std::string& field) {
  const auto dot = field.find('.');
  std::string flag = "--" + field.substr(0, dot);
  std::replace(flag.begin(), flag.end(), '_', '-');
  return dot == std::string::npos ? flag : flag + ": " + field.substr(dot + 1);
}

// The post-hoc checks (DESIGN.md; the same as `terrastride check` at its default resolution):
// joint torques, leg capsules (a scene voxelised, a map's octomap.bt when it has one) and
// footholds, added to plan.json "checks"; their failures and terrain under "post_hoc".
void run_post_hoc_checks(const robot::RobotModel& model, const TerrainSource& terrains,
                         planner::Trajectory* traj) {
  if (traj->samples.empty()) return;
  constexpr double kVoxel = 0.01;  // `terrastride check --resolution` default
  try {
    const collision::CheckTerrain view =
        check_terrain_for(terrains, model, *traj, kVoxel, /*require_octomap=*/false);
    const collision::CheckReport rep = collision::run_checks(model, *traj, view);
    for (const auto& [k, v] : rep.keys()) traj->checks[k] = v;
    traj->extra["post_hoc"] = {
        {"terrain", view.description}, {"failures", rep.failures()}, {"wall_s", rep.wall_s}};
  } catch (const collision::TrajectoryError& e) {
    // A plan the checks cannot interpret (e.g. non-finite numbers from a failed solve): the
    // keys stay absent (never faked) and the reason is recorded.
    traj->extra["post_hoc"] = {{"error", e.what()}};
  }
}

void run_plan(const PlanCliOptions& o) {
  robot::RobotModel model;
  try {
    model = robot::load_robot(robot::resolve_robot_path(o.robot));
  } catch (const robot::RobotFileError& e) {
    throw CommandError(std::string("--robot: ") + e.what());
  }
  // "Leave it out for the gait's default": an explicit 0 is a mistake, not a request.
  if (o.duration_given && !(o.duration > 0.0))
    throw CommandError("--duration: must be > 0 s (leave it out for the gait's default)");
  planner::PlannerOptions po;
  po.gait = o.gait;
  po.cycles = o.cycles;
  po.duration = o.duration;
  po.optimize_timing = o.optimize_timing;
  po.max_time = o.max_time;
  po.verbose = o.verbose;
  try {
    planner::check_plan_request(po, o.sample_dt);  // the limits the socket's plan has too
  } catch (const planner::RequestError& e) {
    throw CommandError(cli_field(e.field()) + ": " + e.problem());
  }
  const TerrainSource terrains =
      load_terrain_source(o.terrain, /*smooth_scene=*/true,
                          "point clouds are not planned on directly; run 'terrastride map " +
                              o.terrain + " --out DIR' and pass --terrain DIR");

  po.constraints = split_list(o.constraints);
  if (po.constraints.empty()) throw CommandError("--constraints: empty list");
  const auto available = planner::constraint_set_names();
  for (const auto& c : po.constraints)
    if (std::find(available.begin(), available.end(), c) == available.end()) {
      std::string list;
      for (const auto& n : available) list += (list.empty() ? "" : ", ") + n;
      throw CommandError("--constraints: '" + c +
                         "' is not available in this build (available: " + list + ")");
    }

  for (const auto& item : o.feasibility)
    for (const auto& setting : split_list(item)) {
      const auto eq = setting.find('=');
      if (eq == std::string::npos || eq == 0)
        throw CommandError("--feasibility: '" + setting + "' is not NAME=VALUE");
      const std::string name = setting.substr(0, eq), text = setting.substr(eq + 1);
      double value = 0.0;
      std::size_t used = 0;
      try {
        value = std::stod(text, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != text.size())
        throw CommandError("--feasibility: " + name + " = '" + text + "' is not a number");
      po.feasibility_settings.emplace_back(name, value);
    }
  try {
    planner::feasibility_options(po.feasibility_settings);  // validated before the solve
  } catch (const std::invalid_argument& e) {
    throw CommandError(std::string("--feasibility: ") + e.what());
  }

  planner::Trajectory previous;
  planner::SrbdProblem::StartState measured;
  planner::WarmStart warm;
  if (!o.init.empty()) {
    try {
      previous = planner::read_plan_file(o.init);
    } catch (const std::exception& e) {
      throw CommandError(std::string("--init: ") + e.what());
    }
    if (previous.robot != model.name)
      throw CommandError("--init " + o.init + ": plan is for robot '" + previous.robot +
                         "', not '" + model.name + "'");
    try {
      planner::timeline_of(previous);  // the contact schedule the re-plan continues
    } catch (const std::invalid_argument& e) {
      throw CommandError("--init " + o.init + ": " + e.what());
    }
    if (!(o.start_time >= 0.0 && o.start_time < previous.duration))
      throw CommandError("--start-time: must be in [0, " + std::to_string(previous.duration) +
                         ") for " + o.init);
    warm.previous = &previous;
    warm.shift = o.start_time;
    if (!o.start_state.empty()) {
      try {
        measured = planner::read_start_state_file(o.start_state, previous, o.start_time);
      } catch (const planner::PlanFileError& e) {
        throw CommandError(std::string("--start-state: ") + e.what());
      }
      warm.start = &measured;
    }
    po.gait = previous.gait;
    po.has_goal = true;
    po.goal = planner::goal_of(previous);
  } else if (o.start_time != 0.0) {
    throw CommandError("--start-time: needs --init");
  } else if (!o.start_state.empty()) {
    throw CommandError("--start-state: needs --init (the plan it continues; fields left out of " +
                       o.start_state + " are that plan's state at --start-time)");
  }
  if (!o.goal.empty()) {
    const Eigen::VectorXd g = parse_numbers(o.goal, 3, "--goal");
    po.goal = g;
    po.has_goal = true;
  } else if (!warm.previous) {
    po.goal = Eigen::Vector3d(1.0, 0.0, 0.0);  // DESIGN.md scenarios: 1 m ahead
    po.has_goal = true;
  }

  // --out is checked before the solve (a probe file in its folder), so a missing or read-only
  // folder, or a directory or socket at the path, fails in milliseconds instead of after it.
  try {
    perception::check_output_file(o.out);
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
  // With --out /dev/stdout (or the file or terminal standard output is) the plan owns standard
  // output; the summary, --json or not, goes to standard error so the two never interleave.
  std::ostream& summary_out =
      perception::same_file_as_descriptor(o.out, STDOUT_FILENO) ? std::cerr : std::cout;

  planner::PlanOutcome out;
  try {
    out = planner::plan_motion(model, *terrains.smooth(), *terrains.exact(), po, o.sample_dt, warm);
  } catch (const planner::GaitError& e) {
    throw CommandError(std::string("--gait: ") + e.what());
  } catch (const planner::RequestError& e) {
    throw CommandError(cli_field(e.field()) + ": " + e.problem());
  } catch (const std::invalid_argument& e) {
    throw CommandError(e.what());
  }
  out.trajectory.extra["terrain"] = o.terrain;
  run_post_hoc_checks(model, terrains, &out.trajectory);
  if (warm.previous) {
    out.trajectory.extra["init"] = o.init;
    out.trajectory.extra["start_time"] = o.start_time;
    if (warm.start) out.trajectory.extra["start_state"] = o.start_state;
  }
  const double violation = out.solve.max_violation;
  // A non-optimal plan is still written when it nearly satisfies every constraint (useful as a
  // warm start or for inspection); the exit code says it is not optimal either way.
  const bool useful = out.success || violation <= 1e-3;
  if (useful) {
    // The same text as planner::write_plan_file, written by perception::write_file_atomically:
    // atomic for files (through symbolic links), written through for pipes and devices.
    try {
      std::cout.flush();
      perception::write_file_atomically(o.out,
                                        planner::plan_to_json(out.trajectory).dump(1) + "\n");
    } catch (const std::exception& e) {
      throw CommandError(std::string("--out: ") + e.what());
    }
  }
  nlohmann::json summary = {{"status", out.trajectory.solver.status},
                            {"iterations", out.trajectory.solver.iterations},
                            {"wall_s", out.trajectory.solver.wall_s},
                            {"n_variables", out.trajectory.solver.n_variables},
                            {"n_constraints", out.trajectory.solver.n_constraints},
                            {"max_violation", violation},
                            {"checks", out.trajectory.checks},
                            {"written", useful ? o.out : ""}};
  if (o.json) {
    summary_out << summary.dump() << "\n";
  } else {
    summary_out << "plan: " << out.trajectory.solver.status << " after "
                << out.trajectory.solver.iterations << " iterations in "
                << out.trajectory.solver.wall_s << " s (" << out.trajectory.solver.n_variables
                << " variables, " << out.trajectory.solver.n_constraints << " constraints)\n";
    for (const auto& [k, v] : out.trajectory.checks) summary_out << "  " << k << " = " << v << "\n";
    if (useful) summary_out << "wrote " << o.out << "\n";
  }
  if (out.trajectory.solver.status != "optimal") {
    std::string msg = out.message.empty() ? "status " + out.trajectory.solver.status : out.message;
    msg += useful ? "; the plan was written to " + o.out + " for inspection"
                  : "; no plan written (the goal may be unreachable with this gait and duration)";
    throw CommandError(msg, 3);
  }
}

}  // namespace

void add_plan_command(CLI::App& app) {
  auto o = std::make_shared<PlanCliOptions>();
  CLI::App* cmd = app.add_subcommand(
      "plan", "Plan base motion, footholds, contact forces and timing (SRBD optimisation, Ipopt)");
  cmd->add_option("--terrain", o->terrain,
                  "terrain directory (from 'terrastride map') or scene name (flat, pallet_10, "
                  "pallet_15, eur_pallet, stairs, gap)")
      ->required();
  cmd->add_option("--robot", o->robot, "robot name or robot file")->capture_default_str();
  cmd->add_option("--gait", o->gait, "gait name (data/gaits) or gait file")->capture_default_str();
  cmd->add_option("--cycles", o->cycles, "number of gait cycles")->capture_default_str();
  cmd->add_option("--duration", o->duration, "total duration in s (default: the gait's)");
  cmd->add_option("--goal", o->goal, "goal X,Y,YAW of the base (default 1,0,0)");
  cmd->add_option("--constraints", o->constraints,
                  "constraint sets, comma separated: baseline, foot (foot radius), shin (shin "
                  "collision, the paper's fixed-angle model), shin_ik (shin collision on the leg's "
                  "IK shin), polytope (force polytopes in stance; implies swing), swing (swing "
                  "foot acceleration bound), joints (joint ranges from IK), all "
                  "(= foot,shin_ik,polytope,joints)")
      ->capture_default_str();
  {
    std::string names;
    for (const auto& n : planner::feasibility_option_names())
      names += (names.empty() ? "" : ", ") + n;
    cmd->add_option(
        "--feasibility", o->feasibility,
        "settings of the constraint sets, NAME=VALUE (comma separated or repeated): " + names);
  }
  cmd->add_option("--sample-dt", o->sample_dt, "sampling period of plan.json in s")
      ->capture_default_str();
  cmd->add_option("--max-time", o->max_time, "time limit of the solve in s (0 = none)");
  cmd->add_option("--init", o->init, "previous plan.json to warm start from");
  cmd->add_option("--start-time", o->start_time,
                  "with --init: start the new plan from the previous plan's state at this time");
  cmd->add_option("--start-state", o->start_state,
                  "with --init: JSON file with the measured state to start from, in plan.json's "
                  "terms: {\"base\": {\"position\", \"euler_zyx\", \"linear_velocity\", "
                  "\"angular_velocity\"}, \"feet\": {NAME: {\"position\", \"velocity\"}}} "
                  "(world frame); fields left out are the previous plan's at --start-time");
  cmd->add_flag("--optimize-timing", o->optimize_timing, "optimise the phase durations too");
  cmd->add_flag("--verbose", o->verbose, "show Ipopt's output");
  cmd->add_flag("--json", o->json, "print the summary as one JSON object");
  cmd->add_option("--out", o->out,
                  "plan.json to write (a symbolic link: its target; /dev/stdout: the plan on "
                  "standard output and the summary on standard error)")
      ->required();
  cmd->callback([o, cmd]() {
    o->duration_given = cmd->count("--duration") > 0;
    run_plan(*o);
  });
}

}  // namespace terrastride::service
