// `terrastride demo`: the whole pipeline on the shipped pallet scan, into out/demo/:
//   scan (data/scans) -> map (terrain::build_terrain_map, written as `terrastride map` writes it)
//   -> plan (the request `terrastride plan` makes, every constraint set this build has) ->
//   post-hoc checks (collision module) -> simulated execution (MuJoCo, as `plan --simulate`)
//   -> report (HTML + JSON).
// Each stage calls the libraries its command calls; no command runs another.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/plan_request.hpp"
#include "report/report.hpp"
#include "report/terrain_input.hpp"
#include "common/simulation_run.hpp"
#include "common/solver_heap.hpp"
#include "common/terrain_source.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/simulation/simulation.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride::service {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

struct DemoOptions {
  std::string out = "out/demo";
  std::vector<std::string> scan;
  std::string constraints;
  double max_time = 60.0;
  bool json_output = false;
};

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string fixed(double v, int precision) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << v;
  return os.str();
}

// Progress lines: "[2/5] map     ... done in 0.41 s: <detail>" (overwritten in place on a
// terminal).
class Progress {
 public:
  Progress(int stages, bool quiet) : stages_(stages), quiet_(quiet), tty_(isatty(STDOUT_FILENO)) {}
  void start(const std::string& name, const std::string& what) {
    ++stage_;
    t0_ = Clock::now();
    name_ = name;
    if (quiet_) return;
    line_ = "[" + std::to_string(stage_) + "/" + std::to_string(stages_) + "] " + name;
    line_.resize(std::max<size_t>(line_.size() + 1, 14), ' ');
    line_ += what;
    std::cout << line_ << (tty_ ? " ..." : "") << std::flush;
  }
  double done(const std::string& detail) {
    const double s = seconds_since(t0_);
    timings_[name_] = s;
    if (!quiet_) {
      if (tty_) std::cout << "\r" << line_;
      std::cout << "  " << fixed(s, 2) << " s" << (detail.empty() ? "" : "  " + detail) << "\n"
                << std::flush;
    }
    return s;
  }
  void fail() {
    if (!quiet_) std::cout << (tty_ ? "\r" + line_ : std::string()) << "  FAILED\n" << std::flush;
  }
  const json& timings() const { return timings_; }

 private:
  int stages_;
  bool quiet_;
  bool tty_;
  int stage_ = 0;
  std::string name_, line_;
  Clock::time_point t0_;
  json timings_ = json::object();
};

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : sep) + s;
  return out;
}

// The shipped pallet scan: data/scans/pallet*.pcd, the 10 cm pallet first. The scan simulator
// writes one file per sensor pose (NAME.pcd, NAME.1.pcd, ...): all of them form the scan.
std::vector<std::string> find_pallet_scan() {
  const fs::path dir = fs::path(robot::data_dir()) / "scans";
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return {};
  std::vector<fs::path> found;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (e.is_regular_file() && name.rfind("pallet", 0) == 0 && e.path().extension() == ".pcd")
      found.push_back(e.path());
  }
  if (found.empty()) return {};
  std::sort(found.begin(), found.end());
  // The scan's name: the first file's name up to its first dot (pallet_10 before pallet_15).
  std::string stem = found.front().filename().string();
  for (const auto& p : found)
    if (p.filename().string().rfind("pallet_10", 0) == 0) stem = p.filename().string();
  stem = stem.substr(0, stem.find('.'));
  std::vector<std::string> files;
  for (const auto& p : found) {
    const std::string name = p.filename().string();
    if (name.substr(0, name.find('.')) == stem) files.push_back(p.string());
  }
  return files;
}

// What `demo --out` writes, for perception::AtomicOutputDir: outputs of versions before the marker
// file are recognised by their names (the map's folder inside included).
perception::OutputDirKind demo_output_kind() {
  return {"demo",
          {"plan.json", "report.html", "report.json", "terrain/terrain.json", "terrain/octomap.bt",
           "terrain/layers/"},
          {"plan.json", "report.html", "report.json", "terrain/", "terrain/terrain.json",
           "terrain/octomap.bt", "terrain/layers/", "terrain/layers/*.npy"},
          {}};
}

// The map stage's results: the map and its OctoMap (as octomap.bt holds it, what the checks of
// `plan --terrain DIR` read), terrain.json and the figures `map --json` prints.
struct DemoMap {
  std::shared_ptr<const terrain::TerrainMap> map;
  std::shared_ptr<const octomap::OcTree> octree;
  json terrain;
  json summary;
};

// 2. map: the scan mapped with `terrastride map`'s defaults, written into `terrain_dir`.
DemoMap map_scan(const std::vector<std::string>& scan, const fs::path& terrain_dir) {
  terrain::MapInput input = terrain::read_map_clouds(scan, std::nullopt);
  terrain::MapBuild build = terrain::build_terrain_map(std::move(input.clouds));
  DemoMap out;
  out.terrain = terrain::write_terrain_dir(build, input.sources, terrain_dir.string());
  out.summary = terrain::map_summary(build, out.terrain, terrain_dir.string());
  out.octree = terrain::octree_as_saved(*build.octree);
  out.map = std::move(build.map);
  return out;
}

// A plan request's field as the demo's flag ("max_time" -> "--max-time").
std::string flag_of(std::string field) {
  std::replace(field.begin(), field.end(), '_', '-');
  return "--" + field;
}

struct DemoPlan {
  planner::Trajectory trajectory;  // with the post-hoc checks' figures
  std::string problem;             // why it is not a usable plan; empty when it is
  // The exit code `plan` gives that problem: 3 not optimal, kExitChecksFailed (4) optimal but
  // failing a post-hoc check.
  int exit_code = 0;
};

// 3. plan: the request `terrastride plan --terrain TERRAIN_DIR --constraints C --max-time T`
// makes, read, checked and solved as it does on that folder's map, its post-hoc checks added,
// written to `plan_path` when it nearly satisfies its constraints (`plan`'s rule). A plan that
// is not usable (not optimal, or failing a check) is returned with the reason, which names
// `final_plan_path`; a plan not worth writing is a CommandError.
DemoPlan plan_on_map(const robot::RobotModel& model, const DemoMap& map,
                     const std::string& terrain_dir, const std::string& final_terrain_dir,
                     const std::string& constraints, double max_time, const fs::path& plan_path,
                     const std::string& final_plan_path) {
  const json fields = {
      {"terrain", terrain_dir}, {"constraints", constraints}, {"max_time", max_time}};
  PlanRequest request;
  try {
    request = read_plan_request(fields, model);
    check_stances_on_terrain(request, model, *map.map);
  } catch (const RequestFieldError& e) {
    throw CommandError(flag_of(e.field()) + ": " + e.problem());
  }
  planner::PlanOutcome out;
  serve_solver_workspace_from_heap();
  try {
    out = planner::plan_motion(model, *map.map, *map.map, request.options, request.sample_dt,
                               request.warm_start());
  } catch (const planner::RequestError& e) {
    throw CommandError(flag_of(e.field()) + ": " + e.problem());
  } catch (const planner::GaitError& e) {
    throw CommandError(std::string("--gait: ") + e.what());
  } catch (const std::invalid_argument& e) {
    throw CommandError(e.what());
  }
  // The map is read from the demo's temporary folder, which is renamed into place at the end: the
  // plan names the folder it will be found in (as `plan --terrain out/demo/terrain` would).
  out.trajectory.extra["terrain"] = final_terrain_dir;
  return_free_heap_pages();
  // The checks `plan` runs on a map folder: footholds on the map, leg capsules on its OctoMap.
  collision::CheckTerrain view;
  view.field = map.map.get();
  view.octree = map.octree;
  view.description = "map " + final_terrain_dir + " (scan OctoMap at " +
                     std::to_string(map.octree->getResolution()) + " m)";
  const std::vector<std::string> failures = add_post_hoc_checks(model, view, &out.trajectory);

  // `plan` writes a plan that is not optimal too when it nearly satisfies every constraint.
  const bool written = out.success || out.solve.max_violation <= 1e-3;
  DemoPlan plan;
  const std::string& status = out.trajectory.solver.status;
  if (status != "optimal") {
    plan.problem = out.message.empty() ? "status " + status : out.message;
    if (!written)
      throw CommandError(plan.problem +
                             "; no plan written (the goal may be unreachable with this gait and "
                             "duration)",
                         3);
    plan.problem += "; the plan was written to " + final_plan_path + " for inspection";
    plan.exit_code = kExitNotOptimal;
  } else if (!failures.empty()) {
    plan.problem = "the solver's plan fails " + std::to_string(failures.size()) +
                   " post-hoc check" + (failures.size() > 1 ? "s" : "") + ": ";
    for (size_t i = 0; i < failures.size(); ++i) plan.problem += (i ? "; " : "") + failures[i];
    plan.problem += "; the plan was written to " + final_plan_path + " for inspection";
    plan.exit_code = kExitChecksFailed;
  }
  perception::write_file_atomically(plan_path.string(),
                                    planner::plan_to_json(out.trajectory).dump(1) + "\n");
  plan.trajectory = std::move(out.trajectory);
  return plan;
}

// The checks' figures on the demo's progress line.
std::string check_detail(const std::map<std::string, double>& keys) {
  std::string check_detail;
  if (keys.count("torque_ratio_max"))
    check_detail += "torque ratio " + fixed(keys.at("torque_ratio_max"), 3);
  // Only certain collisions fail (docs/leg-check.md): the distance to certain voxels is the
  // figure that judges the plan; contacts with uncertain voxels are counted beside it.
  if (keys.count("shin_collisions_certain"))
    check_detail += ", shin certain collisions " + fixed(keys.at("shin_collisions_certain"), 0);
  if (keys.count("shin_min_certain_distance_m"))
    check_detail += ", shin min " + fixed(keys.at("shin_min_certain_distance_m") * 1000, 1) +
                    " mm to certain voxels";
  if (keys.count("shin_contacts_uncertain"))
    check_detail += ", " + fixed(keys.at("shin_contacts_uncertain"), 0) +
                    " shin contacts with voxels within the map's uncertainty (these fail nothing)";
  if (keys.count("unsafe_footholds"))
    check_detail += ", unsafe footholds " + fixed(keys.at("unsafe_footholds"), 0);
  return check_detail;
}

// The demo's summary for people: the terrain's safe fraction, the plan, its problems.
void print_text_summary(const json& rep, const planner::Trajectory& traj, double foot_radius,
                        double total, double cpu, const fs::path& html) {
  std::cout << "\nterrain: safe fraction "
            << fixed(rep["terrain"]["safe_fraction"].get<double>() * 100, 1)
            << " % of observed cells for the " << fixed(foot_radius * 1000, 0) << " mm foot\n";
  std::cout << "plan:    " << traj.solver.status << ", " << traj.samples.size() << " samples over "
            << fixed(traj.duration, 1) << " s\n";
  const json& post_hoc = traj.extra.value("post_hoc", json::object());
  if (post_hoc.contains("simulation") && post_hoc["simulation"].contains("verdict")) {
    const json& sim = post_hoc["simulation"];
    std::cout << "simulated execution: " << sim["verdict"].get<std::string>() << " (base error RMS "
              << fixed(sim["position_error_rms_m"].get<double>() * 1000, 1) << " mm, max "
              << fixed(sim["position_error_max_m"].get<double>() * 1000, 1) << " mm)\n";
  }
  if (rep["problems"].empty()) {
    std::cout << "checks:  no problems found\n";
  } else {
    std::cout << "checks:  " << rep["problems"].size() << " problems:\n";
    for (const json& p : rep["problems"])
      std::cout << "  - " << p["text"].get<std::string>() << "\n";
  }
  std::cout << "total " << fixed(total, 1) << " s (" << fixed(cpu, 1)
            << " s CPU)\nreport: " << html.string() << "\n";
}

// 1. scan: --scan, else the shipped pallet scan; every file must exist.
std::vector<std::string> scan_stage(const DemoOptions& o, Progress& progress) {
  progress.start("scan", "shipped pallet scan");
  const std::vector<std::string> scan = o.scan.empty() ? find_pallet_scan() : o.scan;
  if (scan.empty()) {
    progress.fail();
    throw CommandError(
        "stage 'scan' unavailable: no pallet scan (data/scans/pallet*.pcd) is shipped in " +
        (fs::path(robot::data_dir()) / "scans").string());
  }
  for (const auto& f : scan)
    if (!fs::exists(f)) {
      progress.fail();
      throw CommandError("stage 'scan': --scan " + f + ": no such file");
    }
  progress.done(join(scan, " "));
  return scan;
}

// 2. map, into `terrain_dir`.
DemoMap map_stage(const std::vector<std::string>& scan, const fs::path& terrain_dir,
                  Progress& progress, json& summary) {
  progress.start("map", "height grid, OctoMap, safety masks");
  DemoMap map;
  try {
    map = map_scan(scan, terrain_dir);
  } catch (const perception::InputError& e) {
    progress.fail();
    throw CommandError(std::string("stage 'map': ") + e.what());
  }
  summary["stages"]["map"] = map.summary;
  progress.done(std::to_string(map.summary["points_kept"].get<long>()) + " points kept, " +
                std::to_string(map.summary["cells"].get<long>()) + " cells");
  return map;
}

// --constraints, else every constraint set this build has ("all" when it has that name).
std::string demo_constraints(const DemoOptions& o) {
  const std::vector<std::string> available = planner::constraint_set_names();
  if (!o.constraints.empty()) return o.constraints;
  return std::find(available.begin(), available.end(), "all") != available.end()
             ? "all"
             : join(available, ",");
}

// 3. plan with `constraints`, written to work/plan.json; `model` gets the plan's robot
// (`terrastride plan`'s default).
DemoPlan plan_stage(const DemoOptions& o, const DemoMap& map, const fs::path& work,
                    const fs::path& final_dir, const std::string& constraints,
                    robot::RobotModel* model, Progress& progress, json& summary) {
  progress.start("plan", "crawl 1 m over the pallet, constraints: " + constraints);
  DemoPlan plan;
  try {
    *model = robot::load_robot(robot::resolve_robot_path("hyq"));
    plan = plan_on_map(*model, map, (work / "terrain").string(), (final_dir / "terrain").string(),
                       constraints, o.max_time, work / "plan.json",
                       (final_dir / "plan.json").string());
  } catch (const CommandError& e) {
    progress.fail();
    throw CommandError(std::string("stage 'plan' failed: ") + e.what(), e.exit_code());
  } catch (const std::exception& e) {
    progress.fail();
    throw CommandError(std::string("stage 'plan' failed: ") + e.what());
  }
  const planner::Trajectory& traj = plan.trajectory;
  summary["stages"]["plan"] = {{"constraints", constraints},
                               {"status", traj.solver.status},
                               {"iterations", traj.solver.iterations},
                               {"wall_s", traj.solver.wall_s}};
  progress.done(traj.solver.status + ", " + std::to_string(traj.solver.iterations) +
                " iterations, solver " + fixed(traj.solver.wall_s, 2) + " s");
  return plan;
}

// 4. post-hoc checks on the scan's own terrain: torques, FCL capsules vs the OctoMap, footholds.
// The report's view of the map goes to `view`.
std::shared_ptr<collision::CheckReport> checks_stage(const robot::RobotModel& model,
                                                     const DemoMap& map,
                                                     const planner::Trajectory& traj,
                                                     const fs::path& final_dir,
                                                     report::TerrainView* view_out,
                                                     Progress& progress, json& summary) {
  progress.start("checks", "joint torques, shin capsules vs OctoMap, footholds");
  report::TerrainInputOptions topts;
  topts.foot_radius = model.foot_radius;
  report::TerrainView& view = *view_out;
  view = report::map_view(map.map, map.octree, map.terrain, topts);
  view.source = (final_dir / "terrain").string();
  collision::CheckTerrain ct;
  ct.field = view.field.get();
  ct.octree = view.octree;
  ct.description = view.source;
  auto checks = std::make_shared<collision::CheckReport>();
  try {
    *checks = collision::run_checks(model, traj, ct);
  } catch (const std::exception& e) {
    progress.fail();
    throw CommandError(std::string("stage 'checks': ") + e.what());
  }
  const auto keys = checks->keys();
  summary["stages"]["checks"] = keys;
  progress.done(check_detail(keys));
  return checks;
}

// 5. simulate: the plan executed in MuJoCo on the map's planning surface (a heightfield), its
// verdict added to plan.json as `plan --simulate` adds it. The run's report when it ran.
std::shared_ptr<simulation::SimulationReport> simulate_stage(const robot::RobotModel& model,
                                                             const DemoMap& map,
                                                             const fs::path& work,
                                                             DemoPlan& plan, Progress& progress,
                                                             json& summary) {
  progress.start("simulate", "MuJoCo, the plan on the map's surface as a heightfield");
  planner::Trajectory& traj = plan.trajectory;
  auto simulation = std::make_shared<simulation::SimulationReport>();
  std::vector<std::string> sim_failures;
  try {
    sim_failures = add_simulation_check(model, *map.map, simulation::SimulationOptions{}, &traj,
                                        simulation.get());
    perception::write_file_atomically((work / "plan.json").string(),
                                      planner::plan_to_json(traj).dump(1) + "\n");
  } catch (const std::exception& e) {
    progress.fail();
    throw CommandError(std::string("stage 'simulate': ") + e.what());
  }
  // A "fail" is a post-hoc failure of the plan, as for `plan --simulate`.
  for (const auto& f : sim_failures) plan.problem += (plan.problem.empty() ? "" : "; ") + f;
  if (!sim_failures.empty() && plan.exit_code == 0) plan.exit_code = kExitChecksFailed;
  const json& sim_json = traj.extra["post_hoc"]["simulation"];
  summary["stages"]["simulate"] = sim_json;
  if (sim_json.contains("verdict")) {
    std::string detail = sim_json["verdict"].get<std::string>() + ", base error RMS " +
                         fixed(simulation->position_rms * 1000, 1) + " mm, " +
                         fixed(simulation->realtime_factor, 0) + "x real time";
    if (!simulation->reasons.empty()) detail += " (" + simulation->reasons.front() + ")";
    progress.done(detail);
  } else {
    simulation.reset();
    progress.done(sim_failures.empty() ? std::string() : sim_failures.front());
  }
  return simulation;
}

// 6. report: HTML and JSON into `work`; the report's data.
json report_stage(const report::TerrainView& view, const DemoPlan& plan,
                  std::shared_ptr<collision::CheckReport> checks,
                  std::shared_ptr<simulation::SimulationReport> simulation,
                  const std::vector<std::string>& scan, const std::string& constraints,
                  const fs::path& work, const fs::path& final_dir, Progress& progress) {
  progress.start("report", "self-contained HTML + JSON");
  report::PlanInput input;
  input.name = "plan.json";
  input.path = (final_dir / "plan.json").string();
  input.trajectory = plan.trajectory;
  input.checks = std::move(checks);
  input.simulation = std::move(simulation);
  report::ReportOptions ropts;
  ropts.title = "terrastride demo: " + fs::path(scan.front()).filename().string();
  ropts.robot = plan.trajectory.robot;
  json rep = report::build_report(view, {input}, ropts);
  rep["demo"] = {{"scan", scan}, {"constraints", constraints}, {"stage_s", progress.timings()}};
  report::write_report(rep, (work / "report.html").string());
  progress.done("");
  return rep;
}

void run_demo(const DemoOptions& o) {
  const auto t_all = Clock::now();
  const std::clock_t cpu0 = std::clock();
  // Before any stage: an --out folder holding anything but an earlier demo, or an unwritable one,
  // fails now rather than after the map and the solve.
  try {
    perception::check_output_dir(o.out, demo_output_kind());
  } catch (const perception::InputError& e) {
    throw CommandError(std::string("--out: ") + e.what());
  }
  Progress progress(6, o.json_output);
  json summary{{"stages", json::object()}};
  const std::vector<std::string> scan = scan_stage(o, progress);
  summary["scan"] = scan;

  // Everything goes into a temporary folder beside out/demo, renamed into place at the end.
  fs::create_directories(fs::absolute(o.out).parent_path());
  perception::AtomicOutputDir out_dir(o.out, demo_output_kind());
  const fs::path work = out_dir.path();
  const fs::path final_dir = o.out;
  const DemoMap map = map_stage(scan, work / "terrain", progress, summary);
  const std::string constraints = demo_constraints(o);
  robot::RobotModel model;
  DemoPlan plan =
      plan_stage(o, map, work, final_dir, constraints, &model, progress, summary);
  report::TerrainView view;
  auto checks = checks_stage(model, map, plan.trajectory, final_dir, &view, progress, summary);
  auto simulation = simulate_stage(model, map, work, plan, progress, summary);
  const json rep = report_stage(view, plan, checks, simulation, scan, constraints, work, final_dir,
                                progress);
  out_dir.commit();

  const fs::path html = final_dir / "report.html";
  const double total = seconds_since(t_all);
  summary["report"] = html.string();
  summary["report_json"] = (final_dir / "report.json").string();
  summary["problems"] = rep["problems"];
  summary["safe_fraction"] = rep["terrain"]["safe_fraction"];
  const double cpu = static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC;
  summary["total_s"] = total;
  summary["cpu_s"] = cpu;
  summary["stage_s"] = progress.timings();
  if (o.json_output) {
    std::cout << summary.dump() << "\n";
  } else {
    print_text_summary(rep, plan.trajectory, model.foot_radius, total, cpu, html);
  }
  if (!plan.problem.empty())
    throw CommandError(plan.exit_code == kExitNotOptimal
                           ? "the plan is not optimal (" + plan.problem + "); the report shows it"
                           : plan.problem + "; the report shows it",
                       plan.exit_code);
}

}  // namespace

void add_demo_command(CLI::App& app) {
  auto o = std::make_shared<DemoOptions>();
  CLI::App* cmd = app.add_subcommand(
      "demo",
      "The whole pipeline on the shipped pallet scan: map -> plan -> checks -> simulated "
      "execution (MuJoCo) -> report, into out/demo/");
  cmd->add_option("--out", o->out, "Output folder")->capture_default_str();
  cmd->add_option(
      "--scan", o->scan,
      "Other cloud files instead of the shipped pallet scan (data/scans/pallet_10*.pcd)");
  cmd->add_option("--constraints", o->constraints,
                  "Planner constraint sets (default: all that this build has)");
  cmd->add_option("--max-time", o->max_time, "Time limit of the solve (s)")->capture_default_str();
  cmd->add_flag("--json", o->json_output, "Print the summary as one JSON object");
  cmd->callback([o] { run_demo(*o); });
}

}  // namespace terrastride::service
