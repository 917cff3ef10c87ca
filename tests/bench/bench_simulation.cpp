// Scenario runner for the simulated execution: the paper's experiments judged by
// MuJoCo (simulation::simulate_plan), one row per plan and terrain, and the simulation's speed.
//   bench_simulation [--only GROUP,...] [--repeat N] [--json]
// Groups:
//   flat    flat 1 m crawl in 2.4 s, `baseline` vs `polytope` (torque saturation, tracking error)
//   pallet  pallet_10 and pallet_15 11 s crawls with baseline, foot, foot,shin, all
//   wrong   plans run on the wrong terrain (pallet_15/all on flat and on pallet_10, flat on
//           pallet_15)
//   scenes  stairs, eur_pallet and gap (exact boxes), baseline and all
//   scans   the shipped scans (data/scans) mapped as `terrastride map` maps them, planned with
//           `all` on the map (pallet_10 is the demo's plan) and run on the map's planning surface
//           as a heightfield
//   speed   simulated seconds per wall second at dt 2 ms: the flat crawl on boxes and on a 2 cm
//           heightfield, median of --repeat runs (wall and CPU), with the machine's load
//   process (only when named) the whole `terrastride simulate PLAN --terrain pallet_15 --out F`
//           process on the 11 s pallet_15 `all` plan (planned once by `terrastride plan`):
//           simulated seconds per CPU second and per wall second of the process (start-up,
//           plan.json, model, physics, sim.json), median of --repeat runs; --binary (default
//           ./terrastride, the build directory's)
//   closed_loop  (only when named) pallet_15 `all`: open loop vs re-planning at the
//           --rates (Hz; default 10,20) over a --horizon (s; default 1) planning session: the
//           largest lateral push (0.2 s, left and right, bisection to 20 N) survived at mid-climb
//           (the time the planned base is halfway up), and pass/fail at trunk mass x0.8 and x1.2
//           and friction 0.4. Re-plans wait for the planner (simulated time stands still).
// Plans come from the planner library with `terrastride plan`'s request (3 crawl cycles, goal 1 m
// ahead, 2 cm B-spline of a scene; a map's own field).
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/simulation/simulation.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;
namespace fs = std::filesystem;

namespace {

struct Row {
  std::string group, plan, terrain;
  std::string status;  // solver
  simulation::SimulationReport sim;
};

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) out.push_back(item);
  return out;
}

planner::PlannerOptions plan_options(const Eigen::Vector2d& goal, double duration,
                                     const std::string& sets) {
  planner::PlannerOptions o;
  o.gait = "crawl";
  o.cycles = 3;
  o.duration = duration;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(goal.x(), goal.y(), 0.0);
  o.constraints = split(sets);
  o.max_time = 120.0;
  return o;
}

planner::Trajectory plan_on(const robot::RobotModel& robot, const terrain::HeightField& smooth,
                            const terrain::HeightField& exact, const Eigen::Vector2d& goal,
                            double duration, const std::string& sets) {
  auto out =
      planner::plan_motion(robot, smooth, exact, plan_options(goal, duration, sets), 0.01);
  return out.trajectory;
}

// The first time the planned base is halfway between its start and end heights (the middle of
// a climb), as a fraction of the plan's duration.
double mid_climb_fraction(const planner::Trajectory& plan) {
  const double z0 = plan.samples.front().base.position.z();
  const double z1 = plan.samples.back().base.position.z();
  for (const auto& s : plan.samples)
    if (std::abs(s.base.position.z() - z0) >= 0.5 * std::abs(z1 - z0))
      return s.t / plan.samples.back().t;
  return 0.5;
}

// One configuration of the closed-loop table: push margin and the model-error runs.
void closed_loop_row(const robot::RobotModel& robot, const planner::Trajectory& plan,
                     const terrain::Scene& scene, const terrain::HeightField& smooth,
                     const planner::PlannerOptions& options, double rate_hz, double horizon,
                     nlohmann::json* rows, bool json) {
  simulation::SimulationOptions sim;
  sim.record_dt = 0.0;
  if (rate_hz > 0) {
    sim.replan_every = 1.0 / rate_hz;
    sim.replanner =
        simulation::session_replanner(robot, smooth, scene, options, plan, horizon, 0.01);
  }
  simulation::MarginOptions mo;
  mo.push_time_fraction = mid_climb_fraction(plan);
  mo.push_tolerance = 20.0;
  mo.mass = false;
  const double cpu0 = static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
  const auto wall0 = std::chrono::steady_clock::now();
  const auto nominal = simulation::simulate_plan(robot, plan, scene, sim);
  const auto margin = simulation::simulation_margin(robot, plan, scene, sim, mo);
  auto verdict_at = [&](double mass_scale, double friction) {
    simulation::SimulationOptions o = sim;
    o.mass_scale = mass_scale;
    o.friction = friction;
    const auto r = simulation::simulate_plan(robot, plan, scene, o);
    return r.verdict + (r.fell ? " (fall " + std::to_string(r.fall_t).substr(0, 5) + " s)" : "") +
           (r.replans > 0 ? " [" + std::to_string(r.replan_failures) + "/" +
                                std::to_string(r.replans) + " re-plans failed]"
                          : "");
  };
  const std::string heavy = verdict_at(1.2, sim.friction), light = verdict_at(0.8, sim.friction),
                    slippery = verdict_at(1.0, 0.4);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  const double cpu = static_cast<double>(std::clock()) / CLOCKS_PER_SEC - cpu0;
  const std::string config =
      rate_hz > 0 ? "re-plan " + std::to_string(static_cast<int>(rate_hz)) + " Hz" : "open loop";
  auto side = [](const simulation::MarginSide& s) {
    std::ostringstream o;
    o << s.survived << (s.failed < 0 ? "+" : "");
    return o.str();
  };
  if (!json) {
    std::printf("%-13s push %.2f s at t = %.2f s (%.2f of the plan): left %s N, right %s N, margin "
                "%.0f N (%.0f N s); nominal %s", config.c_str(), mo.push_duration, margin.push_t,
                mo.push_time_fraction, side(margin.push_left).c_str(),
                side(margin.push_right).c_str(), margin.push_margin_N, margin.push_margin_Ns,
                nominal.verdict.c_str());
    if (nominal.replans > 0)
      std::printf(" (%d re-plans, %d failed, planner CPU %.0f ms median, %.0f ms max; wall %.0f "
                  "ms median)",
                  nominal.replans, nominal.replan_failures, 1e3 * nominal.replan_cpu_median,
                  1e3 * nominal.replan_cpu_max, 1e3 * nominal.replan_wall_median);
    std::printf("\n              mass x1.2: %s; mass x0.8: %s; friction 0.4: %s; %d runs, %.0f s "
                "wall, %.0f s CPU\n",
                heavy.c_str(), light.c_str(), slippery.c_str(), margin.runs + 4, wall, cpu);
    if (!margin.push_left.failure.empty())
      std::printf("              left fails: %s\n", margin.push_left.failure.c_str());
    if (!margin.push_right.failure.empty())
      std::printf("              right fails: %s\n", margin.push_right.failure.c_str());
    if (!nominal.replan_first_failure.empty())
      std::printf("              first re-plan failure: %s\n",
                  nominal.replan_first_failure.c_str());
    std::fflush(stdout);
  }
  rows->push_back({{"group", "closed_loop"},
                   {"config", config},
                   {"rate_hz", rate_hz},
                   {"horizon_s", horizon},
                   {"push_t", margin.push_t},
                   {"push_duration_s", mo.push_duration},
                   {"push_left_survived_N", margin.push_left.survived},
                   {"push_left_failed_N", margin.push_left.failed},
                   {"push_right_survived_N", margin.push_right.survived},
                   {"push_right_failed_N", margin.push_right.failed},
                   {"push_margin_N", margin.push_margin_N},
                   {"nominal_verdict", nominal.verdict},
                   {"nominal_replans", nominal.replans},
                   {"nominal_replan_failures", nominal.replan_failures},
                   {"planner_wall_median_s", nominal.replan_wall_median},
                   {"planner_wall_max_s", nominal.replan_wall_max},
                   {"planner_cpu_median_s", nominal.replan_cpu_median},
                   {"planner_cpu_max_s", nominal.replan_cpu_max},
                   {"mass_1_2", heavy},
                   {"mass_0_8", light},
                   {"friction_0_4", slippery},
                   {"runs", margin.runs + 4},
                   {"wall_s", wall},
                   {"cpu_s", cpu}});
}

struct ScenePlans {
  std::unique_ptr<terrain::Scene> scene;
  std::unique_ptr<terrain::TerrainMap> smooth;
};

ScenePlans scene(const std::string& name) {
  ScenePlans s;
  s.scene = terrain::make_scene(name);
  s.smooth = terrain::TerrainMap::from_scene(*s.scene, 0.02, {});
  return s;
}

double load1() {
  std::ifstream in("/proc/loadavg");
  double l = -1;
  in >> l;
  return l;
}

void print_header() {
  std::printf("%-7s %-22s %-34s %-7s %-5s %7s %7s %6s %6s %6s %7s %7s %7s %6s %6s\n", "group",
              "plan", "simulated on", "solver", "sim", "rms_mm", "max_mm", "sat_%", "slip",
              "td_mm", "shin_Ns", "shin_s", "shin_N", "fall_t", "x_rt");
}

void print_row(const Row& r) {
  const auto& s = r.sim;
  // Longest shin contact of one leg (s): the time with shin force over the recorded samples.
  double shin_s = 0.0;
  if (!s.samples.empty()) {
    const double dt = s.samples.size() > 1 ? s.samples[1].t - s.samples[0].t : s.dt;
    for (size_t i = 0; i < s.shin_impulse.size(); ++i) {
      double leg = 0.0;
      for (const auto& smp : s.samples) leg += smp.shin_force[i] > 0 ? dt : 0.0;
      shin_s = std::max(shin_s, leg);
    }
  }
  double shin_peak = 0.0;
  for (const auto& smp : s.samples)
    for (double f : smp.shin_force) shin_peak = std::max(shin_peak, f);
  std::printf(
      "%-7s %-22s %-34s %-7s %-5s %7.1f %7.1f %6.2f %6.1f %6.1f %7.2f %7.2f %7.0f %6s %6.1f\n",
      r.group.c_str(), r.plan.c_str(), r.terrain.substr(0, 34).c_str(),
      r.status.substr(0, 7).c_str(), s.verdict.c_str(), 1000 * s.position_rms,
      1000 * s.position_max, 100 * s.saturation_fraction, 1000 * s.slip_max,
      1000 * s.touchdown_error_max, s.shin_impulse_max, shin_s, shin_peak,
      s.fell ? std::to_string(s.fall_t).substr(0, 5).c_str() : "-", s.realtime_factor);
  if (s.verdict != "pass")
    for (const auto& why : s.reasons) std::printf("          - %s\n", why.c_str());
}

nlohmann::json row_json(const Row& r) {
  const auto& s = r.sim;
  double shin_peak = 0.0;
  for (const auto& smp : s.samples)
    for (double f : smp.shin_force) shin_peak = std::max(shin_peak, f);
  return {{"group", r.group},
          {"plan", r.plan},
          {"terrain", r.terrain},
          {"solver_status", r.status},
          {"verdict", s.verdict},
          {"reasons", s.reasons},
          {"position_error_rms_m", s.position_rms},
          {"position_error_max_m", s.position_max},
          {"saturation_fraction", s.saturation_fraction},
          {"slip_max_m", s.slip_max},
          {"touchdown_error_max_m", s.touchdown_error_max},
          {"shin_impulse_max_Ns", s.shin_impulse_max},
          {"shin_force_peak_N", shin_peak},
          {"fell", s.fell},
          {"fall_t", s.fall_t},
          {"realtime_factor", s.realtime_factor},
          {"cpu_s", s.cpu_s},
          {"wall_s", s.wall_s}};
}

}  // namespace

// `binary ARGS` as a child process with its output discarded: its exit code, wall seconds and
// the child's user and system CPU seconds.
struct ChildRun {
  int code = -1;
  double wall_s = 0, user_s = 0, sys_s = 0;
};
ChildRun run_child(const std::string& command) {
  rusage before{}, after{};
  getrusage(RUSAGE_CHILDREN, &before);
  const auto t0 = std::chrono::steady_clock::now();
  const int status = std::system((command + " > /dev/null 2>&1").c_str());
  ChildRun r;
  r.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  getrusage(RUSAGE_CHILDREN, &after);
  const auto seconds = [](const timeval& a, const timeval& b) {
    return (b.tv_sec - a.tv_sec) + 1e-6 * (b.tv_usec - a.tv_usec);
  };
  r.user_s = seconds(before.ru_utime, after.ru_utime);
  r.sys_s = seconds(before.ru_stime, after.ru_stime);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// The whole `simulate` process on the 11 s pallet_15 `all` plan, median of `repeat` runs.
nlohmann::json process_speed(const std::string& binary, int repeat) {
  const fs::path dir = fs::temp_directory_path() / ("bench_simulation_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string plan = (dir / "plan.json").string(), out = (dir / "sim.json").string();
  const ChildRun planned =
      run_child(binary + " plan --terrain pallet_15 --constraints all --out " + plan);
  if (planned.code != 0) {
    std::fprintf(stderr, "process: `%s plan --terrain pallet_15 --constraints all` exit %d\n",
                 binary.c_str(), planned.code);
    fs::remove_all(dir);
    return nullptr;
  }
  const double duration = planner::read_plan_file(plan).duration;
  std::vector<double> cpu, user, sys, wall;
  const double load_before = load1();
  for (int r = 0; r < repeat; ++r) {
    const ChildRun run =
        run_child(binary + " simulate " + plan + " --terrain pallet_15 --out " + out);
    if (run.code != 0) {
      std::fprintf(stderr, "process: simulate exit %d\n", run.code);
      fs::remove_all(dir);
      return nullptr;
    }
    cpu.push_back(run.user_s + run.sys_s);
    user.push_back(run.user_s);
    sys.push_back(run.sys_s);
    wall.push_back(run.wall_s);
  }
  fs::remove_all(dir);
  const auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  return {{"terrain", "pallet_15"},
          {"plan", "pallet_15/all (terrastride plan)"},
          {"process", "terrastride simulate PLAN --terrain pallet_15 --out sim.json"},
          {"plan_duration_s", duration},
          {"repeat", repeat},
          {"cpu_s_median", median(cpu)},
          {"user_s_median", median(user)},
          {"sys_s_median", median(sys)},
          {"wall_s_median", median(wall)},
          {"realtime_cpu_median", duration / median(cpu)},
          {"realtime_wall_median", duration / median(wall)},
          {"load1_before", load_before},
          {"load1_after", load1()}};
}

int main(int argc, char** argv) {
  std::vector<std::string> only;
  int repeat = 3;
  bool json = false;
  std::vector<double> rates = {10.0, 20.0};
  double horizon = 1.0;
  std::string binary = "./terrastride";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--only" && i + 1 < argc) {
      only = split(argv[++i]);
    } else if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--json") {
      json = true;
    } else if (a == "--rates" && i + 1 < argc) {
      rates.clear();
      for (const auto& r : split(argv[++i])) rates.push_back(std::atof(r.c_str()));
    } else if (a == "--horizon" && i + 1 < argc) {
      horizon = std::atof(argv[++i]);
    } else if (a == "--binary" && i + 1 < argc) {
      binary = argv[++i];
    } else {
      std::cerr << "usage: bench_simulation [--only flat,pallet,wrong,scenes,scans,speed,closed_loop] "
                   "[--repeat N] [--json] [--rates HZ,...] [--horizon S] [--binary B]\n";
      return 2;
    }
  }
  auto want = [&](const std::string& g) {
    return only.empty() || std::find(only.begin(), only.end(), g) != only.end();
  };
  const auto robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  nlohmann::json rows = nlohmann::json::array();
  if (!json) print_header();
  auto emit = [&](Row r) {
    if (!json) {
      print_row(r);
      std::fflush(stdout);
    }
    rows.push_back(row_json(r));
  };
  simulation::SimulationOptions sim;  // defaults: dt 2 ms, mu 0.5, the thresholds

  if (want("flat")) {
    auto flat = scene("flat");
    for (const char* sets : {"baseline", "polytope"}) {
      const auto plan = plan_on(robot, *flat.smooth, *flat.scene, flat.scene->goal(), 2.4, sets);
      emit({"flat", std::string("flat_2.4s/") + sets, "scene flat (boxes)", plan.solver.status,
            simulation::simulate_plan(robot, plan, *flat.scene, sim)});
    }
  }
  std::unique_ptr<planner::Trajectory> p15_all;
  if (want("pallet") || want("wrong")) {
    for (const char* name : {"pallet_10", "pallet_15"}) {
      auto sc = scene(name);
      for (const char* sets : {"baseline", "foot", "foot,shin", "all"}) {
        const bool needed = want("pallet") || (std::string(name) == "pallet_15" &&
                                               std::string(sets) == "all");
        if (!needed) continue;
        const auto plan = plan_on(robot, *sc.smooth, *sc.scene, sc.scene->goal(), 11.0, sets);
        if (std::string(name) == "pallet_15" && std::string(sets) == "all")
          p15_all = std::make_unique<planner::Trajectory>(plan);
        if (want("pallet"))
          emit({"pallet", std::string(name) + "/" + sets, std::string("scene ") + name + " (boxes)",
                plan.solver.status, simulation::simulate_plan(robot, plan, *sc.scene, sim)});
      }
    }
  }
  if (want("wrong") && p15_all) {
    for (const char* name : {"flat", "pallet_10"}) {
      auto sc = scene(name);
      emit({"wrong", "pallet_15/all", std::string("scene ") + name + " (wrong terrain)",
            p15_all->solver.status, simulation::simulate_plan(robot, *p15_all, *sc.scene, sim)});
    }
    auto flat = scene("flat");
    const auto plan = plan_on(robot, *flat.smooth, *flat.scene, flat.scene->goal(), 11.0, "all");
    auto p15 = scene("pallet_15");
    emit({"wrong", "flat_11s/all", "scene pallet_15 (wrong terrain)", plan.solver.status,
          simulation::simulate_plan(robot, plan, *p15.scene, sim)});
  }
  if (want("scenes")) {
    for (const char* name : {"stairs", "eur_pallet", "gap"}) {
      auto sc = scene(name);
      for (const char* sets : {"baseline", "all"}) {
        const auto plan = plan_on(robot, *sc.smooth, *sc.scene, sc.scene->goal(), 11.0, sets);
        emit({"scenes", std::string(name) + "/" + sets, std::string("scene ") + name + " (boxes)",
              plan.solver.status, simulation::simulate_plan(robot, plan, *sc.scene, sim)});
      }
    }
  }
  if (want("scans")) {
    const fs::path dir = fs::path(robot::data_dir()) / "scans";
    for (const char* name : {"pallet_10", "stairs", "eur_pallet", "gap"}) {
      std::vector<std::string> files;
      for (const auto& e : fs::directory_iterator(dir)) {
        const std::string f = e.path().filename().string();
        if (f.substr(0, f.find('.')) == name && e.path().extension() == ".pcd")
          files.push_back(e.path().string());
      }
      std::sort(files.begin(), files.end());
      if (files.empty()) {
        std::fprintf(stderr, "no scan %s in %s: skipped\n", name, dir.string().c_str());
        continue;
      }
      auto input = terrain::read_map_clouds(files, std::nullopt);
      auto build = terrain::build_terrain_map(std::move(input.clouds));
      const terrain::TerrainMap& map = *build.map;
      const auto plan = plan_on(robot, map, map, Eigen::Vector2d(1.0, 0.0), 11.0, "all");
      const std::string label = std::string(name) + (std::string(name) == "pallet_10"
                                                         ? " scan/all (demo)"
                                                         : " scan/all");
      emit({"scans", label, std::string("map of data/scans/") + name + "*.pcd (hfield)",
            plan.solver.status, simulation::simulate_plan(robot, plan, map, sim)});
      // The same plan on the exact scene it was scanned from.
      auto sc = scene(name);
      emit({"scans", label, std::string("scene ") + name + " (boxes)", plan.solver.status,
            simulation::simulate_plan(robot, plan, *sc.scene, sim)});
    }
  }
  if (std::find(only.begin(), only.end(), "closed_loop") != only.end()) {
    auto sc = scene("pallet_15");
    const auto options = plan_options(sc.scene->goal(), 11.0, "all");
    const auto plan = planner::plan_motion(robot, *sc.smooth, *sc.scene, options, 0.01).trajectory;
    if (!json)
      std::printf("closed_loop: pallet_15/all (%s, %.1f s), horizon %.2f s, load %.1f\n",
                  plan.solver.status.c_str(), plan.duration, horizon, load1());
    closed_loop_row(robot, plan, *sc.scene, *sc.smooth, options, 0.0, horizon, &rows, json);
    for (double rate : rates)
      closed_loop_row(robot, plan, *sc.scene, *sc.smooth, options, rate, horizon, &rows, json);
  }
  nlohmann::json speed = nlohmann::json::array();
  if (want("speed")) {
    auto flat = scene("flat");
    const auto plan = plan_on(robot, *flat.smooth, *flat.scene, flat.scene->goal(), 2.4, "baseline");
    const auto hfield = terrain::TerrainMap::from_scene(*flat.scene, 0.02, {0.02});
    simulation::SimulationOptions fast = sim;
    fast.record_dt = 0.0;  // the judge's own cost, not the recording's
    for (const char* kind : {"boxes", "heightfield 2 cm"}) {
      std::vector<double> wall_x, cpu_x;
      const double load_before = load1();
      for (int r = 0; r < repeat; ++r) {
        const auto rep = std::string(kind) == "boxes"
                             ? simulation::simulate_plan(robot, plan, *flat.scene, fast)
                             : simulation::simulate_plan(robot, plan, *hfield, fast);
        wall_x.push_back(rep.realtime_factor);
        cpu_x.push_back(rep.duration / rep.cpu_s);
      }
      std::sort(wall_x.begin(), wall_x.end());
      std::sort(cpu_x.begin(), cpu_x.end());
      nlohmann::json s = {{"terrain", kind},
                          {"plan", "flat_2.4s/baseline"},
                          {"dt", fast.dt},
                          {"repeat", repeat},
                          {"realtime_wall_min", wall_x.front()},
                          {"realtime_wall_median", wall_x[wall_x.size() / 2]},
                          {"realtime_wall_max", wall_x.back()},
                          {"realtime_cpu_median", cpu_x[cpu_x.size() / 2]},
                          {"load1_before", load_before},
                          {"load1_after", load1()}};
      speed.push_back(s);
      if (!json)
        std::printf(
            "speed  %-17s dt 2 ms: %.1fx real time per wall second (median of %d; %.1f..%.1f), "
            "%.1fx per CPU second; load %.1f -> %.1f\n",
            kind, wall_x[wall_x.size() / 2], repeat, wall_x.front(), wall_x.back(),
            cpu_x[cpu_x.size() / 2], load_before, load1());
    }
  }
  if (std::find(only.begin(), only.end(), "process") != only.end()) {
    const nlohmann::json p = process_speed(binary, repeat);
    if (p.is_null()) return 1;
    speed.push_back(p);
    if (!json)
      std::printf(
          "process simulate pallet_15/all (%.1f s): %.1fx real time per CPU second (median of %d: "
          "%.3f s CPU, %.3f s user, %.3f s sys), %.1fx per wall second (%.3f s); load %.1f -> %.1f\n",
          p["plan_duration_s"].get<double>(), p["realtime_cpu_median"].get<double>(), repeat,
          p["cpu_s_median"].get<double>(), p["user_s_median"].get<double>(),
          p["sys_s_median"].get<double>(), p["realtime_wall_median"].get<double>(),
          p["wall_s_median"].get<double>(), p["load1_before"].get<double>(),
          p["load1_after"].get<double>());
  }
  if (json) std::cout << nlohmann::json{{"rows", rows}, {"speed", speed}}.dump(1) << "\n";
  return 0;
}
