// Scenario runner for the planner (DESIGN.md, Scenarios): one row per scenario with problem size,
// iterations, wall time (median of --repeat runs), peak memory and the dense checks.
//   bench_scenarios [--repeat 3] [--only NAME[,NAME...]] [--json]
#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;

namespace {

struct Scenario {
  std::string name;
  std::string scene;
  double duration;
  bool optimize_timing;
  double warm_shift = -1.0;  // >= 0: re-plan from the cold plan's state at this time
};

double peak_mb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;  // kB on Linux
}

}  // namespace

int main(int argc, char** argv) {
  int repeat = 3;
  bool json = false;
  std::vector<std::string> only;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--only" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      while (std::getline(ss, item, ',')) only.push_back(item);
    } else if (a == "--json") {
      json = true;
    } else {
      std::cerr << "usage: bench_scenarios [--repeat N] [--only NAME,...] [--json]\n";
      return 2;
    }
  }
  const std::vector<Scenario> scenarios = {
      {"flat_2.4s", "flat", 2.4, false},
      {"flat_2.4s_timing", "flat", 2.4, true},
      {"pallet_10", "pallet_10", 11.0, false},
      {"pallet_10_timing", "pallet_10", 11.0, true},
      {"pallet_15", "pallet_15", 11.0, false},
      {"pallet_15_timing", "pallet_15", 11.0, true},
      {"stairs", "stairs", 11.0, false},
      {"stairs_timing", "stairs", 11.0, true},
      {"pallet_15_warm_0.1s", "pallet_15", 11.0, false, 0.1},
  };
  const auto robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  if (!json)
    std::printf("%-22s %6s %6s %5s %8s %7s %-10s %8s %8s %8s %8s %8s %8s %6s\n", "scenario", "vars",
                "cons", "iter", "wall_s", "peakMB", "status", "lin_N", "ang_Nm", "pen_mm",
                "fric_N", "slip_mm", "rom_mm", "goal");
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& sc : scenarios) {
    if (!only.empty() && std::find(only.begin(), only.end(), sc.name) == only.end()) continue;
    auto scene = terrain::make_scene(sc.scene);
    auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
    planner::PlannerOptions o;
    o.gait = "crawl";
    o.cycles = 3;
    o.duration = sc.duration;
    o.optimize_timing = sc.optimize_timing;
    o.has_goal = true;
    o.goal = Eigen::Vector3d(scene->goal().x(), scene->goal().y(), 0.0);
    planner::Trajectory cold;
    if (sc.warm_shift >= 0.0) {
      const auto c = planner::plan_motion(robot, *smooth, *scene, o, 0.01);
      cold = c.trajectory;
    }
    std::vector<double> walls;
    planner::PlanOutcome out;
    for (int r = 0; r < repeat; ++r) {
      planner::WarmStart warm;
      if (sc.warm_shift >= 0.0) {
        warm.previous = &cold;
        warm.shift = sc.warm_shift;
      }
      out = planner::plan_motion(robot, *smooth, *scene, o, 0.01, warm);
      walls.push_back(out.trajectory.solver.wall_s);
    }
    std::sort(walls.begin(), walls.end());
    const double wall = walls[walls.size() / 2];
    const auto& t = out.trajectory;
    const auto& last = t.samples.back().base.position;
    const double goal_err = std::hypot(last.x() - o.goal.x(), last.y() - o.goal.y());
    auto chk = [&](const char* k) { return t.checks.count(k) ? t.checks.at(k) : -1.0; };
    nlohmann::json row = {{"scenario", sc.name},
                          {"n_variables", t.solver.n_variables},
                          {"n_constraints", t.solver.n_constraints},
                          {"iterations", t.solver.iterations},
                          {"wall_s_median", wall},
                          {"repeat", repeat},
                          {"peak_mb", peak_mb()},
                          {"status", t.solver.status},
                          {"goal_error_m", goal_err},
                          {"checks", t.checks}};
    if (sc.warm_shift >= 0.0) row["cold_wall_s"] = cold.solver.wall_s;
    rows.push_back(row);
    if (!json) {
      std::printf("%-22s %6d %6d %5d %8.3f %7.1f %-10s %8.3g %8.3g %8.3g %8.3g %8.3g %8.3g %6.3f\n",
                  sc.name.c_str(), t.solver.n_variables, t.solver.n_constraints,
                  t.solver.iterations, wall, peak_mb(), t.solver.status.c_str(),
                  chk("dynamics_linear_max_N"), chk("dynamics_angular_max_Nm"),
                  1e3 * chk("penetration_max_m"), chk("friction_violation_max_N"),
                  1e3 * chk("slip_max_m"), 1e3 * chk("range_of_motion_excess_max_m"), goal_err);
      if (sc.warm_shift >= 0.0)
        std::printf("%-22s cold solve %.3f s; warm/cold = %.2f\n", "", cold.solver.wall_s,
                    wall / std::max(1e-9, cold.solver.wall_s));
      std::fflush(stdout);
    }
  }
  if (json) std::cout << rows.dump(2) << "\n";
  return 0;
}
