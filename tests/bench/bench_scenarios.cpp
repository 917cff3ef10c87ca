// Scenario runner for the planner (docs/design.md §11): one row per scenario with problem size,
// iterations, wall time (median of --repeat runs), peak memory and the dense checks.
//   bench_scenarios [--repeat 3] [--only NAME[,NAME...]] [--feasibility] [--json] [--original]
//                   [--settings NAME=VALUE,...] [--add-sets SET,...]
// Each row is followed by its quality figures (plan.json "quality", planner/quality.hpp).
// --objective-scale S plans with the tuned objective weights (ObjectiveWeights{}) times S.
// --original plans as the original design did, for before/after comparisons in one binary: no
// objective, no rest rows at the ends, and "all" without "force_ramp" and the path-shape sets
// (monotone_progress, lateral_corridor, swing_apex).
// --settings passes feasibility settings (`terrastride plan --feasibility`) to every row, e.g.
// monotone_progress=1,lateral_corridor=0.02,swing_apex_rise=0.1; --add-sets adds constraint sets
// to every row (the standard rows plan with "baseline" alone).
// --feasibility (or --only naming them) adds the feasibility-variant rows SCENE/SETS (baseline,
// foot, foot,shin, all on pallet_10 and pallet_15) with their own columns: rows and
// Jacobian nonzeros, iterations, wall and user CPU s, the post-hoc checks on the exact scene
// (worst joint torque ratio over the whole plan, capsule collisions and minimum distance, unsafe
// footholds) and the worst quasi-static stance torque ratio max |J_i^T f| / tau_i.
// Session rows (pallet_15_all_session[_h1|_h2]): 20 x --repeat re-plans 0.1 s apart
// from states 1 cm and 0.05 m/s off the plan; BENCH_SESSION_DETAIL=1 prints each step on stderr.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/planning_session.hpp"
#include "terrastride/planner/quality.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;

namespace {

std::string fixed1(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", v);
  return buf;
}

struct Scenario {
  std::string name;
  std::string scene;
  double duration;
  bool optimize_timing;
  double warm_shift = -1.0;  // >= 0: re-plan from the cold plan's state at this time
  // With warm_shift: the base starts this far (m) to the side of the plan and 0.05 m/s faster
  // along it, as a robot's measured state would (0: exactly on the plan).
  double warm_base_offset = 0.0;
  std::vector<std::string> constraints{"baseline"};
  bool feasibility_row = false;  // printed with the feasibility columns; run on request only
  // >= 0: a planning session (planning_session.hpp) with this horizon (0 = to the goal) after the
  // cold plan; `session_steps` steps 0.1 s apart, each from the previous plan's state 1 cm to the
  // side and 0.05 m/s faster (a stand-in for a measured state); the row gives the median and p99.
  double session_horizon = -1.0;
};

// Session rows: cold plan, then steps every 0.1 s from an offset state; walls of whole steps.
nlohmann::json run_session_row(const Scenario& sc, const robot::RobotModel& robot,
                               const terrain::HeightField& smooth, const terrain::HeightField& scene,
                               const planner::PlannerOptions& o, int steps, bool print) {
  const auto cold = planner::plan_motion(robot, smooth, scene, o, 0.01);
  planner::PlanningSession session(robot, smooth, scene, o, cold.trajectory, sc.session_horizon,
                                   0.01);
  std::vector<double> walls, solves;
  int iterations = 0, failures = 0, max_iterations = 0;
  for (int k = 1; k <= steps; ++k) {
    const double t = 0.1 * k;
    planner::SrbdProblem::StartState measured = session.planned_state(t);
    measured.position.y() += 0.01;
    measured.linear_velocity.x() += 0.05;
    const auto t0 = std::chrono::steady_clock::now();
    const auto step = session.step(measured, t);
    walls.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    solves.push_back(step.outcome.solve.wall_s);
    iterations += step.outcome.solve.iterations;
    max_iterations = std::max(max_iterations, step.outcome.solve.iterations);
    failures += !step.outcome.success;
    if (std::getenv("BENCH_SESSION_DETAIL"))
      std::fprintf(stderr, "t %.1f end %.2f it %d build %.3f solve %.3f total %.3f vars %d rows %d %s\n", t,
                   step.end_time, step.outcome.solve.iterations, step.build_s,
                   step.outcome.solve.wall_s, walls.back(), step.outcome.trajectory.solver.n_variables,
                   step.outcome.trajectory.solver.n_constraints, step.outcome.solve.status.c_str());
    if (std::getenv("BENCH_SESSION_DETAIL") && !step.outcome.success)
      std::fprintf(stderr, "  %s\n", step.outcome.message.c_str());
  }
  auto quantile = [](std::vector<double> v, double q) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(q * v.size())) - 1)];
  };
  const double cold_wall = cold.trajectory.extra["timings"].value("total_s", 0.0);
  nlohmann::json row = {{"scenario", sc.name},
                        {"horizon_s", sc.session_horizon},
                        {"cold_total_s", cold_wall},
                        {"cold_iterations", cold.solve.iterations},
                        {"steps", steps},
                        {"step_median_s", quantile(walls, 0.5)},
                        {"step_p99_s", quantile(walls, 0.99)},
                        {"solve_median_s", quantile(solves, 0.5)},
                        {"iterations_mean", static_cast<double>(iterations) / steps},
                        {"iterations_max", max_iterations},
                        {"failures", failures},
                        {"median_over_cold", quantile(walls, 0.5) / cold_wall}};
  if (print) {
    std::printf("%-22s horizon %.1f s: cold %.3f s (%d it); %d steps: median %.4f s, p99 %.4f s "
                "(%.3f of cold), %.2f it/step (max %d), %d failed\n",
                sc.name.c_str(), sc.session_horizon, cold_wall, cold.solve.iterations, steps,
                quantile(walls, 0.5), quantile(walls, 0.99), quantile(walls, 0.5) / cold_wall,
                static_cast<double>(iterations) / steps, max_iterations, failures);
    std::fflush(stdout);
  }
  return row;
}

double user_cpu_s() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + 1e-6 * u.ru_utime.tv_usec;
}

// Worst quasi-static stance torque ratio max_i |J_i^T f_b| / tau_i (exact polytope at IK).
double stance_torque_ratio(const robot::RobotModel& r, const planner::Trajectory& t) {
  double worst = 0.0;
  for (const auto& s : t.samples) {
    const Eigen::Matrix3d R = collision::rotation_zyx(s.base.euler_zyx);
    for (std::size_t f = 0; f < s.feet.size(); ++f) {
      if (!s.feet[f].contact) continue;
      const Eigen::Vector3d pb = R.transpose() * (s.feet[f].position - s.base.position);
      const auto ik = robot::inverse_kinematics(r.legs[f], pb);
      if (ik.status == robot::IkStatus::unreachable) continue;
      worst = std::max(worst, robot::exact_force_polytope(r.legs[f], ik.q)
                                  .torque_ratio(-(R.transpose() * s.feet[f].force)));
    }
  }
  return worst;
}

double peak_mb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;  // kB on Linux
}

}  // namespace

int main(int argc, char** argv) {
  int repeat = 3;
  bool json = false;
  bool feasibility = false;
  bool original = false;
  double objective_scale = 0.0;  // > 0: the tuned objective weights times this (off by default)
  std::vector<std::string> only, add_sets;
  std::vector<std::pair<std::string, double>> settings;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--only" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      while (std::getline(ss, item, ',')) only.push_back(item);
    } else if (a == "--feasibility") {
      feasibility = true;
    } else if (a == "--json") {
      json = true;
    } else if (a == "--objective-scale" && i + 1 < argc) {
      objective_scale = std::atof(argv[++i]);
    } else if (a == "--original") {
      original = true;
    } else if (a == "--settings" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      while (std::getline(ss, item, ',')) {
        const auto eq = item.find('=');
        if (eq == std::string::npos) {
          std::cerr << "--settings: '" << item << "' is not NAME=VALUE\n";
          return 2;
        }
        settings.emplace_back(item.substr(0, eq), std::atof(item.c_str() + eq + 1));
      }
      try {
        planner::feasibility_options(settings);
      } catch (const std::invalid_argument& e) {
        std::cerr << "--settings: " << e.what() << "\n";
        return 2;
      }
    } else if (a == "--add-sets" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      while (std::getline(ss, item, ',')) add_sets.push_back(item);
    } else {
      std::cerr << "usage: bench_scenarios [--repeat N] [--only NAME,...] [--feasibility] [--json] "
                   "[--original] [--objective-scale S] [--settings NAME=VALUE,...] "
                   "[--add-sets SET,...]\n";
      return 2;
    }
  }
  std::vector<Scenario> scenarios = {
      {"flat_2.4s", "flat", 2.4, false},
      {"flat_2.4s_timing", "flat", 2.4, true},
      {"pallet_10", "pallet_10", 11.0, false},
      {"pallet_10_timing", "pallet_10", 11.0, true},
      {"pallet_15", "pallet_15", 11.0, false},
      {"pallet_15_timing", "pallet_15", 11.0, true},
      {"stairs", "stairs", 11.0, false},
      {"stairs_timing", "stairs", 11.0, true},
      {"pallet_15_warm_0.1s", "pallet_15", 11.0, false, 0.1},
      {"pallet_15_warm_0.1s_off", "pallet_15", 11.0, false, 0.1, 0.01},
  };
  // Planning sessions on pallet_15 with every constraint set: to the goal, and with
  // a 2 s receding horizon.
  for (double horizon : {0.0, 2.0, 1.0}) {
    Scenario sc{horizon > 0 ? "pallet_15_all_session_h" + std::to_string(static_cast<int>(horizon))
                            : "pallet_15_all_session",
                "pallet_15",
                11.0, false};
    sc.constraints = {"all"};
    sc.session_horizon = horizon;
    scenarios.push_back(sc);
  }
  for (const char* scene : {"pallet_10", "pallet_15"})
    for (const char* sets : {"baseline", "foot", "foot,shin", "all"}) {
      Scenario sc{std::string(scene) + "/" + sets, scene, 11.0, false};
      sc.constraints.clear();
      std::stringstream ss(sets);
      std::string item;
      while (std::getline(ss, item, ',')) sc.constraints.push_back(item);
      sc.feasibility_row = true;
      scenarios.push_back(sc);
    }
  const auto robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  if (!json && feasibility)
    std::printf("%-20s %6s %7s %5s %7s %7s %-10s (post-hoc on the exact scene)\n", "scenario/sets",
                "rows", "nnz", "iter", "wall_s", "user_s", "status");
  if (!json && !feasibility)
    std::printf("%-22s %6s %6s %5s %8s %7s %-10s %8s %8s %8s %8s %8s %8s %6s\n", "scenario", "vars",
                "cons", "iter", "wall_s", "peakMB", "status", "lin_N", "ang_Nm", "pen_mm",
                "fric_N", "slip_mm", "rom_mm", "goal");
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& sc : scenarios) {
    if (!only.empty() && std::find(only.begin(), only.end(), sc.name) == only.end()) continue;
    if (only.empty() && sc.feasibility_row && !feasibility) continue;
    if (only.empty() && !sc.feasibility_row && feasibility) continue;
    auto scene = terrain::make_scene(sc.scene);
    auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
    planner::PlannerOptions o;
    o.gait = "crawl";
    o.cycles = 3;
    o.duration = sc.duration;
    o.optimize_timing = sc.optimize_timing;
    o.has_goal = true;
    o.goal = Eigen::Vector3d(scene->goal().x(), scene->goal().y(), 0.0);
    o.constraints = sc.constraints;
    o.constraints.insert(o.constraints.end(), add_sets.begin(), add_sets.end());
    o.feasibility_settings = settings;
    if (objective_scale > 0.0) {
      o.objective = planner::ObjectiveWeights{};
      o.objective.scale(objective_scale);
    }
    if (original) {
      o.objective = planner::ObjectiveWeights::none();
      o.rest_boundaries = false;
      std::vector<std::string> sets;
      for (const auto& c : o.constraints)
        if (c == "all") {
          for (const char* set : planner::kAllFeasibilitySets)
            if (std::strcmp(set, "force_ramp") != 0 && std::strcmp(set, "monotone_progress") != 0 &&
                std::strcmp(set, "lateral_corridor") != 0 && std::strcmp(set, "swing_apex") != 0)
              sets.push_back(set);
        } else
          sets.push_back(c);
      o.constraints = sets;
    }
    if (sc.session_horizon >= 0.0) {
      rows.push_back(run_session_row(sc, robot, *smooth, *scene, o, 20 * repeat, !json));
      continue;
    }
    planner::Trajectory cold;
    if (sc.warm_shift >= 0.0) {
      const auto c = planner::plan_motion(robot, *smooth, *scene, o, 0.01);
      cold = c.trajectory;
    }
    std::vector<double> walls, users;
    planner::PlanOutcome out;
    planner::SrbdProblem::StartState measured;
    if (sc.warm_shift >= 0.0) {
      measured = planner::start_state_of(cold, sc.warm_shift);
      measured.position.y() += sc.warm_base_offset;
      if (sc.warm_base_offset != 0.0) measured.linear_velocity.x() += 0.05;
    }
    for (int r = 0; r < repeat; ++r) {
      planner::WarmStart warm;
      if (sc.warm_shift >= 0.0) {
        warm.previous = &cold;
        warm.shift = sc.warm_shift;
        warm.start = &measured;
      }
      const double u0 = user_cpu_s();
      out = planner::plan_motion(robot, *smooth, *scene, o, 0.01, warm);
      users.push_back(user_cpu_s() - u0);
      walls.push_back(out.trajectory.solver.wall_s);
    }
    std::sort(walls.begin(), walls.end());
    std::sort(users.begin(), users.end());
    const double wall = walls[walls.size() / 2];
    const double user = users[users.size() / 2];
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
    const planner::PlanQuality quality = planner::plan_quality(t);
    row["quality"] = planner::quality_to_json(quality, t.feet);
    auto print_quality = [&] {
      if (json) return;
      std::printf("%-22s quality: path %.3f back %.1f mm sway %.1f mm dz %.1f mm jerk99 %.2f "
                  "fstep %.1f N/10ms acc0 %.3f accT %.3f ang0 %.3f angT %.3f rise %.1f mm%s%s\n",
                  "", quality.path_ratio, 1e3 * quality.backward_max_m,
                  1e3 * quality.lateral_sway_m, 1e3 * quality.body_height_variation_m,
                  quality.jerk_p99, quality.force_step_max_N, quality.start_acceleration,
                  quality.end_acceleration, quality.start_angular_acceleration,
                  quality.end_angular_acceleration, 1e3 * quality.swing_rise_max_m,
                  quality.has_support_margin
                      ? (" margin min " + fixed1(1e3 * quality.support_margin_min_m) + " p10 " +
                         fixed1(1e3 * quality.support_margin_p10_m) + " mm")
                            .c_str()
                      : "",
                  t.extra.contains("objective")
                      ? (" objective " + std::to_string(t.extra["objective"].get<double>())).c_str()
                      : "");
      std::fflush(stdout);
    };
    if (sc.feasibility_row) {
      // Problem size (the same problem plan_motion built), the post-hoc checks of `terrastride
      // plan` (capsules against the scene voxelised at 1 cm) and the stance torque ratio.
      std::vector<std::string> feet;
      for (const auto& leg : robot.legs) feet.push_back(leg.name);
      const planner::PhaseTimeline tl = planner::make_timeline(
          planner::load_gait(planner::resolve_gait_path(o.gait)), feet, o.cycles, o.duration);
      const planner::SrbdProblem problem(robot, *smooth, tl, o);
      row["n_rows"] = problem.num_constraints();
      row["jacobian_nonzeros"] = problem.jacobian_nonzeros();
      row["user_s_median"] = user;
      row["stance_torque_ratio"] = stance_torque_ratio(robot, t);
      Eigen::Vector2d lo, hi;
      collision::trajectory_extent(robot, t, 0.1, &lo, &hi);
      collision::CheckTerrain view;
      view.field = scene.get();
      collision::VoxeliseOptions vo;
      vo.resolution = 0.01;
      view.octree = collision::voxelise_scene(*scene, lo, hi, vo);
      const auto keys = collision::run_checks(robot, t, view).keys();
      for (const auto& [k, v] : keys) row["post_hoc"][k] = v;
      auto key = [&](const char* k) { return keys.count(k) ? keys.at(k) : -1.0; };
      if (!json) {
        std::printf("%-20s %6d %7d %5d %7.2f %7.2f %-10s tau %5.2f stance %5.3f shin %7.4f m "
                    "coll %3.0f unsafe %2.0f\n",
                    sc.name.c_str(), problem.num_constraints(), problem.jacobian_nonzeros(),
                    t.solver.iterations, wall, user, t.solver.status.c_str(),
                    key("torque_ratio_max"), static_cast<double>(row["stance_torque_ratio"]),
                    key("shin_min_distance_m"), key("shin_collisions"), key("unsafe_footholds"));
        std::fflush(stdout);
        row["quality"]["energy_proxy_J"] = key("energy_proxy_J");
        print_quality();
        std::printf("%-22s energy proxy %.1f J\n", "", key("energy_proxy_J"));
      }
      rows.push_back(row);
      continue;
    }
    rows.push_back(row);
    if (!json) {
      std::printf("%-22s %6d %6d %5d %8.3f %7.1f %-10s %8.3g %8.3g %8.3g %8.3g %8.3g %8.3g %6.3f\n",
                  sc.name.c_str(), t.solver.n_variables, t.solver.n_constraints,
                  t.solver.iterations, wall, peak_mb(), t.solver.status.c_str(),
                  chk("dynamics_linear_max_N"), chk("dynamics_angular_max_Nm"),
                  1e3 * chk("penetration_max_m"), chk("friction_violation_max_N"),
                  1e3 * chk("slip_max_m"), 1e3 * chk("range_of_motion_excess_max_m"), goal_err);
      print_quality();
      if (sc.warm_shift >= 0.0)
        std::printf("%-22s cold solve %.3f s; warm/cold = %.2f\n", "", cold.solver.wall_s,
                    wall / std::max(1e-9, cold.solver.wall_s));
      std::fflush(stdout);
    }
  }
  if (json) std::cout << rows.dump(2) << "\n";
  return 0;
}
