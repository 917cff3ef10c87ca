// `terrastride plan`: SRBD trajectory optimisation from a start to a goal over a terrain.
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <future>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "common/plan_request.hpp"
#include "common/simulation_run.hpp"
#include "common/solver_heap.hpp"
#include "common/terrain_source.hpp"
#include "pasteable.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/json_input.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/joint_points.hpp"
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
  std::string goal;
  std::string start;
  std::string constraints = "all";  // planner::kDefaultRequestConstraints
  std::vector<std::string> feasibility;  // NAME=VALUE settings of the constraint sets
  double sample_dt = 0.01;
  double max_time = 0.0;
  std::string init;
  double start_time = 0.0;
  std::string start_state;  // measured state to re-plan from (JSON file), with init
  bool optimize_timing = false;
  bool simulate = false;
  bool verbose = false;
  bool json = false;
  std::string out;
  std::set<std::string> flags;  // the flags on the command line
  bool given(const std::string& flag) const { return flags.count(flag) > 0; }
};

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

// A plan request's field as this command names it: "sample_dt" -> "--sample-dt"; "init" and
// "start_state" (and their sub-fields) by the flag and the file they came from.
std::string cli_field(const std::string& field, const PlanCliOptions& o) {
  const auto dot = field.find('.');
  const std::string head = field.substr(0, dot);
  const std::string rest = dot == std::string::npos ? "" : ": " + field.substr(dot + 1);
  if (head == "init") return "--init " + o.init + rest;
  if (head == "start_state") return "--start-state " + o.start_state + rest;
  std::string flag = "--" + head;
  std::replace(flag.begin(), flag.end(), '_', '-');
  return flag + rest;
}

nlohmann::json numbers(const Eigen::VectorXd& v) {
  return std::vector<double>(v.data(), v.data() + v.size());
}

// A JSON file named on the command line ("PATH: cannot open WHAT", "PATH: not valid JSON: ...").
nlohmann::json read_json_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open " + what);
  try {
    return perception::parse_json_input(in);
  } catch (const nlohmann::json::exception& e) {  // parse errors, and numbers beyond double
    throw std::runtime_error(path + ": not valid JSON: " + e.what());
  }
}

// The reader's messages name other fields as the socket does ("init"); here they are flags.
std::string cli_text(std::string problem) {
  for (const char* field : {"init", "start_state", "start_time", "goal", "duration", "gait"}) {
    std::string flag = std::string("--") + field;
    std::replace(flag.begin(), flag.end(), '_', '-');
    const std::string quoted = std::string("\"") + field + "\"";
    for (auto at = problem.find(quoted); at != std::string::npos; at = problem.find(quoted))
      problem.replace(at, quoted.size(), flag);
  }
  return problem;
}

// --feasibility NAME=VALUE[,NAME=VALUE] (repeatable) as the request's {"NAME": value}.
nlohmann::json feasibility_fields(const std::vector<std::string>& items) {
  nlohmann::json settings = nlohmann::json::object();
  for (const auto& item : items)
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
      settings[name] = value;
    }
  return settings;
}

// The robot to plan with: --robot, or for a re-plan (--init) without it, the robot the previous
// plan carries.
robot::RobotModel plan_robot(const PlanCliOptions& o) {
  try {
    if (!o.given("--robot") && !o.init.empty())
      return planner::robot_of_plan(planner::read_plan_file(o.init), o.init);
    return robot::load_robot(robot::resolve_robot_path(o.robot));
  } catch (const planner::PlanFileError& e) {
    throw CommandError(std::string("--init: ") + e.what());
  } catch (const robot::RobotFileError& e) {
    throw CommandError(std::string(o.given("--robot") ? "--robot: " : "--init: ") + e.what());
  }
}

// The flags given become the request's fields, read by the socket's reader (plan_request.hpp):
// one set of checks, limits and defaults. Flags left out are left out, so a re-plan keeps what
// --init was planned with.
nlohmann::json request_fields(const PlanCliOptions& o) {
  nlohmann::json fields = {{"terrain", o.terrain}};
  if (o.given("--gait")) fields["gait"] = o.gait;
  if (o.given("--cycles")) fields["cycles"] = o.cycles;
  if (o.given("--duration")) fields["duration"] = o.duration;
  if (o.given("--goal")) fields["goal"] = numbers(parse_numbers(o.goal, 3, "--goal"));
  if (o.given("--start")) fields["start"] = numbers(parse_numbers(o.start, 3, "--start"));
  if (o.given("--constraints")) fields["constraints"] = o.constraints;
  if (o.given("--sample-dt")) fields["sample_dt"] = o.sample_dt;
  if (o.given("--max-time")) fields["max_time"] = o.max_time;
  if (o.given("--optimize-timing")) fields["optimize_timing"] = o.optimize_timing;
  if (!o.feasibility.empty()) fields["feasibility"] = feasibility_fields(o.feasibility);
  // --init and --start-state name files; their contents are the request's "init" and
  // "start_state", and errors in them name the flag and the file.
  try {
    if (!o.init.empty()) fields["init"] = read_json_file(o.init, "plan file");
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("--init: ") + e.what());
  }
  if (o.given("--start-time")) fields["start_time"] = o.start_time;
  try {
    // Without --init the reader refuses --start-state before the file matters.
    if (!o.start_state.empty())
      fields["start_state"] = o.init.empty() ? nlohmann::json::object()
                                             : read_json_file(o.start_state, "start-state file");
  } catch (const std::runtime_error& e) {
    throw CommandError(std::string("--start-state: ") + e.what());
  }
  return fields;
}

// The planner on the request, its errors named by the flags.
planner::PlanOutcome solve_request(const robot::RobotModel& model, const TerrainSource& terrains,
                                   const PlanRequest& req, const planner::WarmStart& warm,
                                   const PlanCliOptions& o) {
  serve_solver_workspace_from_heap();
  try {
    return planner::plan_motion(model, *terrains.smooth(), *terrains.exact(), req.options,
                                req.sample_dt, warm);
  } catch (const planner::GaitError& e) {
    throw CommandError(std::string("--gait: ") + e.what());
  } catch (const planner::RequestError& e) {
    throw CommandError(cli_field(e.field(), o) + ": " + e.problem());
  } catch (const std::invalid_argument& e) {
    throw CommandError(e.what());
  }
}

// The post-hoc checks (as `terrastride check` at its default resolution) judge every plan: a plan
// that fails one is not a usable plan, whatever the solver says. Their failures.
std::vector<std::string> post_hoc_failures(const robot::RobotModel& model,
                                           const TerrainSource& terrains,
                                           planner::Trajectory* trajectory) {
  try {
    return add_post_hoc_checks(
        model,
        check_terrain_for(terrains, model, *trajectory, kPostHocVoxel, /*require_octomap=*/false),
        trajectory);
  } catch (const collision::TrajectoryError& e) {
    return {std::string("the post-hoc checks could not read the plan: ") + e.what()};
  }
}

// A re-plan's inputs, in the plan: the files it started from and the corrections of its
// start state's stance feet.
void record_replan_inputs(const PlanCliOptions& o, const planner::WarmStart& warm,
                          const nlohmann::json& stance_corrections,
                          planner::Trajectory* trajectory) {
  trajectory->extra["init"] = o.init;
  trajectory->extra["start_time"] = o.start_time;
  if (warm.start) trajectory->extra["start_state"] = o.start_state;
  if (!stance_corrections.empty())
    trajectory->extra["start_state_corrections"] = stance_corrections;
}

// --out: atomic for files (through symbolic links), written through for pipes and devices; the
// samples as serialised on the second core.
void write_plan(const PlanCliOptions& o, const planner::Trajectory& trajectory,
                std::future<planner::SerialisedSamples>& samples_text) {
  try {
    std::cout.flush();
    const planner::SerialisedSamples samples = samples_text.get();
    planner::write_plan_file(o.out, trajectory, &samples);
  } catch (const std::exception& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
}

// The summary, as --json prints it.
nlohmann::json plan_summary(const planner::PlanOutcome& out,
                            const std::vector<std::string>& failures,
                            const nlohmann::json& simulation, bool useful,
                            const PlanCliOptions& o) {
  const planner::Trajectory& traj = out.trajectory;
  nlohmann::json summary = {{"status", traj.solver.status},
                            {"iterations", traj.solver.iterations},
                            {"wall_s", traj.solver.wall_s},
                            {"n_variables", traj.solver.n_variables},
                            {"n_constraints", traj.solver.n_constraints},
                            {"max_violation", out.solve.max_violation},
                            {"checks", traj.checks},
                            {"checks_passed", failures.empty()},
                            {"failures", failures},
                            {"simulation", simulation},
                            {"written", useful ? o.out : ""}};
  // A cold solve that failed with the path-shape rows and was solved again without them.
  const nlohmann::json shape_fallback = traj.extra.value("path_shape_fallback", nlohmann::json());
  if (!shape_fallback.is_null()) summary["path_shape_fallback"] = shape_fallback;
  return summary;
}

// The summary for people.
// The verdict of a plan that exits 0, and the commands that judge it further, to paste as printed.
// The collision counts above include contacts within the map's uncertainty, which fail nothing.
void print_plan_passed(std::ostream& summary_out, const planner::Trajectory& traj,
                       const PlanCliOptions& o) {
  int uncertain = 0;
  for (const char* key :
       {"shin_contacts_uncertain", "thigh_contacts_uncertain", "trunk_contacts_uncertain"}) {
    const auto it = traj.checks.find(key);
    if (it != traj.checks.end()) uncertain += static_cast<int>(it->second);
  }
  summary_out << "PASS: optimal, every post-hoc check clean (joint ranges and torques, leg and "
                 "trunk clearance, footholds)";
  if (uncertain > 0)
    summary_out << "; the " << uncertain
                << " leg or trunk contacts counted above are within the map's uncertainty and "
                   "fail nothing (only *_collisions_certain do, docs/leg-check.md)";
  summary_out << "\n";
  if (o.out.rfind("/dev/", 0) == 0) return;  // the plan went to a stream: nothing to judge by name
  const std::string program = pasteable_program();
  const std::string args = shell_word(o.out) + " --terrain " + shell_word(o.terrain);
  summary_out << "next: " << program << " check " << args << "\n      " << program << " simulate "
              << args << " --out sim.json\n";
}

void print_plan_summary(std::ostream& summary_out, const planner::Trajectory& traj,
                        const std::vector<std::string>& failures,
                        const nlohmann::json& simulation, bool useful, const PlanCliOptions& o) {
  summary_out << "plan: " << traj.solver.status << " after " << traj.solver.iterations
              << " iterations in " << traj.solver.wall_s << " s (" << traj.solver.n_variables
              << " variables, " << traj.solver.n_constraints << " constraints)\n";
  const nlohmann::json shape_fallback = traj.extra.value("path_shape_fallback", nlohmann::json());
  if (!shape_fallback.is_null())
    summary_out << "  path shape: the solve with the path-shape rows ended '"
                << shape_fallback["shaped_status"].get<std::string>() << "' after "
                << shape_fallback["shaped_iterations"].get<int>()
                << " iterations (counted above); solved again without them\n";
  for (const auto& [k, v] : traj.checks) summary_out << "  " << k << " = " << v << "\n";
  if (simulation.contains("verdict")) {
    summary_out << "  simulation: " << simulation["verdict"].get<std::string>();
    for (const auto& why : simulation["reasons"]) summary_out << "; " << why.get<std::string>();
    summary_out << "\n";
  }
  for (const auto& f : failures) summary_out << "  FAILED: " << f << "\n";
  if (useful) summary_out << "wrote " << o.out << "\n";
  if (traj.solver.status == "optimal" && failures.empty()) print_plan_passed(summary_out, traj, o);
}

// The exit: 3 when the solver's plan is not optimal, kExitChecksFailed when it fails a post-hoc
// check (or the simulation), 0 otherwise.
void throw_plan_problems(const planner::PlanOutcome& out, const std::vector<std::string>& failures,
                         bool useful, const PlanCliOptions& o) {
  if (out.trajectory.solver.status != "optimal") {
    std::string msg = out.message.empty() ? "status " + out.trajectory.solver.status : out.message;
    // The planner's message names the constraint families still violated, their feet and times.
    msg += useful ? "; the plan was written to " + o.out + " for inspection" : "; no plan written";
    throw CommandError(msg, 3);
  }
  if (!failures.empty()) {
    std::string msg = "the solver's plan fails " + std::to_string(failures.size()) +
                      " post-hoc check" + (failures.size() > 1 ? "s" : "") + ": ";
    for (std::size_t i = 0; i < failures.size(); ++i) msg += (i ? "; " : "") + failures[i];
    // Why the joints' and torques' rows did not hold between the constraint points.
    const auto refinement = out.trajectory.extra.find("joint_refinement");
    if (refinement != out.trajectory.extra.end()) {
      const std::string clause = planner::joint_refinement_stop_clause(*refinement);
      if (!clause.empty()) msg += "; " + clause;
    }
    throw CommandError(msg + "; the plan was written to " + o.out + " for inspection",
                       kExitChecksFailed);
  }
}

void run_plan(const PlanCliOptions& o) {
  const robot::RobotModel model = plan_robot(o);
  const nlohmann::json fields = request_fields(o);
  PlanRequest req;
  try {
    req = read_plan_request(fields, model);
  } catch (const RequestFieldError& e) {
    throw CommandError(cli_field(e.field(), o) + ": " + cli_text(e.problem()));
  }
  req.options.verbose = o.verbose;
  const planner::WarmStart warm = req.warm_start();
  const TerrainSource terrains =
      load_terrain_source(o.terrain, /*smooth_scene=*/true, map_it_first(o.terrain));
  nlohmann::json stance_corrections;
  try {
    check_stances_on_terrain(req, model, *terrains.exact());
    stance_corrections = settle_stance_feet(&req, *terrains.smooth());
  } catch (const RequestFieldError& e) {
    // A start or goal off the safe ground: `regions` lists the ones that are on it.
    const bool pose = e.field() == "start" || e.field() == "goal";
    std::string robot = o.robot == "hyq" ? "" : " --robot " + shell_word(o.robot);
    throw CommandError(cli_field(e.field(), o) + ": " + cli_text(e.problem()) +
                       (pose ? "; `" + pasteable_program() + " regions --terrain " +
                                   shell_word(o.terrain) + robot +
                                   "` lists starts and goals on safe ground with plan commands"
                             : ""));
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

  planner::PlanOutcome out = solve_request(model, terrains, req, warm, o);
  out.trajectory.extra["terrain"] = o.terrain;
  return_free_heap_pages();
  // The samples are final: serialise them (two thirds of plan.json) on the second core while
  // this one voxelises the terrain and runs the checks' one-thread parts (plan_io.hpp). The
  // checks only read the samples. Pallet_15 baseline: see docs/design.md §12.6.
  std::future<planner::SerialisedSamples> samples_text =
      std::async(std::launch::async, [&samples = out.trajectory.samples] {
        return planner::serialise_samples(samples);
      });
  std::vector<std::string> failures = post_hoc_failures(model, terrains, &out.trajectory);
  if (warm.previous) record_replan_inputs(o, warm, stance_corrections, &out.trajectory);
  // A non-optimal plan is still written when it nearly satisfies every constraint (useful as a
  // warm start or for inspection); the exit code says it is not optimal either way.
  const bool useful = out.success || out.solve.max_violation <= 1e-3;
  // --simulate: MuJoCo executes the plan on the exact terrain (a scene's boxes, a map's planning
  // surface); a "fail" verdict is a post-hoc failure (exit 4), a "warn" is reported only.
  if (o.simulate && useful && !out.trajectory.samples.empty()) {
    const auto sim = add_simulation_check(model, *terrains.exact(), simulation::SimulationOptions{},
                                          &out.trajectory);
    failures.insert(failures.end(), sim.begin(), sim.end());
  }
  if (useful) write_plan(o, out.trajectory, samples_text);
  const nlohmann::json post_hoc = out.trajectory.extra.value("post_hoc", nlohmann::json());
  const nlohmann::json simulation =
      post_hoc.is_object() ? post_hoc.value("simulation", nlohmann::json()) : nlohmann::json();
  if (o.json)
    summary_out << plan_summary(out, failures, simulation, useful, o).dump() << "\n";
  else
    print_plan_summary(summary_out, out.trajectory, failures, simulation, useful, o);
  throw_plan_problems(out, failures, useful, o);
}

}  // namespace

void add_plan_command(CLI::App& app) {
  auto o = std::make_shared<PlanCliOptions>();
  CLI::App* cmd = app.add_subcommand(
      "plan", "Plan base motion, footholds, contact forces and timing (SRBD optimisation, Ipopt)");
  cmd->add_option("--terrain", o->terrain,
                  "terrain directory (from 'terrastride map'), OctoMap file (.bt, .ot) or scene name (" +
                      terrain::scene_names_text() + ")")
      ->required();
  cmd->add_option("--robot", o->robot, "robot name or robot file")->capture_default_str();
  cmd->add_option("--gait", o->gait, "gait name (data/gaits) or gait file")->capture_default_str();
  cmd->add_option("--cycles", o->cycles,
                  "number of gait cycles (default: 3, more when the goal is farther than 3 of the "
                  "robot's strides, the length of its range-of-motion box: Go2 4 for 1 m)");
  cmd->add_option("--duration", o->duration, "total duration in s (default: the gait's)");
  cmd->add_option("--goal", o->goal,
                  "goal X,Y,YAW of the base (m, m, rad; default 1,0,0; a re-plan: --init's goal)");
  cmd->add_option("--start", o->start,
                  "start X,Y,YAW of the base (m, m, rad), the nominal stance placed on the "
                  "terrain there (default 0,0,0)");
  cmd->add_option("--constraints", o->constraints,
                  "constraint sets, comma separated: baseline, foot (foot radius), shin (shin "
                  "collision, the paper's fixed-angle model), shin_ik (shin collision on the leg's "
                  "IK shin), thigh (thigh collision where the terrain is tall), trunk (trunk box above "
                  "tall terrain), polytope (force "
                  "polytopes in stance; implies swing), swing (swing "
                  "foot acceleration bound), joints (joint ranges from IK), force_ramp (contact "
                  "forces zero at touch-down and lift-off, rate bounded), monotone_progress, "
                  "lateral_corridor, swing_apex (the base's and swing feet's path shape, each on "
                  "while its --feasibility setting is non-zero: by default monotone_progress=1, "
                  "lateral_corridor=0.02, swing_apex_rise=0.1; plans from rest only unless "
                  "replan_path_shape=1; a solve they make fail is solved again without them), all "
                  "(= foot,shin_ik,thigh,trunk,polytope,joints,force_ramp,monotone_progress,"
                  "lateral_corridor,swing_apex). Default: all (a re-plan: --init's); "
                  "--constraints baseline is the paper's formulation alone")
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
  cmd->add_flag("--simulate", o->simulate,
                "also execute the plan in MuJoCo (as 'terrastride simulate' on the same terrain); "
                "the verdict joins plan.json's checks (sim_*) and post_hoc.simulation; a 'fail' "
                "is a post-hoc failure (exit 4), a 'warn' is reported only");
  cmd->add_flag("--verbose", o->verbose, "show Ipopt's output");
  cmd->add_flag("--json", o->json, "print the summary as one JSON object");
  cmd->add_option("--out", o->out,
                  "plan.json to write (a symbolic link: its target; /dev/stdout: the plan on "
                  "standard output and the summary on standard error)")
      ->required();
  cmd->callback([o, cmd]() {
    for (const CLI::Option* opt : cmd->get_options())
      if (opt->count() > 0) o->flags.insert(opt->get_name());
    run_plan(*o);
  });
}

}  // namespace terrastride::service
