// Scenario runner: push recovery of the pallet_15 `all` crawl, open loop against re-planning.
//   bench_push_recovery [--runs N] [--replan-every S] [--horizon H] [--iterations K]
//                       [--replan-before S] [--phases F,F,...]
//                       [--directions left,right,forward,backward] [--check-ratio R] [--json]
//                       [--limits-only] [--plan-out FILE]
//                       [--force-distribution clipped|constrained]
// For each phase (a time of the 11 s plan) and push direction (relative to the planned heading
// there: left, right, forward, backward; 0.2 s on the trunk) the largest push survived (verdict
// not "fail"), open loop and closed loop (a planning session re-planning every --replan-every s
// over --horizon, each re-plan's deadline --iterations solver iterations: the simulation's
// deterministic budget; re-planning from --replan-before s before the push, default 0.5, < 0 from
// the start: the earlier re-plans only follow the undisturbed plan). Each cell is
// simulation::simulation_margin's search (doubling, then bisection of the bracket, survived = not
// "fail"), made coarse for a 2-core machine: --runs simulations per cell, from 200 N, in all four
// directions. Phases by default: six evenly spaced, the middle of the climb, and the middle of the
// swing that steps onto the pallet; the table names the swinging foot at each. The target: the
// closed loop survives at least 1.5x the open loop's push at every phase and direction.
// --check-ratio R answers that target directly and more finely: each cell's open-loop margin is
// searched with --runs simulations (from 200 N, so 8 runs resolve it to about 1/64 of its
// bracket), then the closed loop is simulated once at R times it.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "blas_kernel.hpp"
#include "push_reference.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/simulation/simulation.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;
using bench::leg_step_reach;
using bench::outward_step_reach;
using bench::OutwardStep;
using bench::push_limit;
using bench::support_edge;
using bench::support_reach;

namespace {

struct Args {
  int runs = 5;
  double replan_every = 0.1, horizon = 1.0;
  int iterations = 5;
  // Re-plans start this long before the push (< 0: from the plan's start). Earlier ones follow
  // the undisturbed plan, and they cost about half of a closed-loop run's time.
  double replan_before = 0.5;
  std::vector<double> phases;  // fractions of the plan; empty: the default eight
  std::vector<std::string> directions = {"left", "right", "forward", "backward"};
  double check_ratio = 0.0;  // > 0: the closed loop is run once at this multiple of the open loop's
  bool json = false;
  bool limits_only = false;  // the no-step limits of each cell, without simulating
  // Where to write the plan the cells run on, so that `terrastride simulate FILE --push ...
  // --replan-from ...` replays one cell on exactly it; empty: not written.
  std::string plan_out;
  // The controller's stance-force distribution (simulate --force-distribution) in both loops.
  std::string force_distribution = "clipped";
};

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) out.push_back(item);
  return out;
}

Args parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(k + ": needs a value");
      return argv[++i];
    };
    if (k == "--runs")
      a.runs = std::stoi(value());
    else if (k == "--replan-every")
      a.replan_every = std::stod(value());
    else if (k == "--horizon")
      a.horizon = std::stod(value());
    else if (k == "--iterations")
      a.iterations = std::stoi(value());
    else if (k == "--replan-before")
      a.replan_before = std::stod(value());
    else if (k == "--phases")
      for (const auto& f : split(value())) a.phases.push_back(std::stod(f));
    else if (k == "--directions")
      a.directions = split(value());
    else if (k == "--check-ratio")
      a.check_ratio = std::stod(value());
    else if (k == "--json")
      a.json = true;
    else if (k == "--limits-only")
      a.limits_only = true;
    else if (k == "--force-distribution") {
      a.force_distribution = value();
      if (!simulation::force_distribution_named(a.force_distribution))
        throw std::invalid_argument("--force-distribution: clipped or constrained, got " +
                                    a.force_distribution);
    } else if (k == "--plan-out")
      a.plan_out = value();
    else
      throw std::invalid_argument("unknown option " + k);
  }
  if (!(a.check_ratio >= 0 && a.check_ratio <= 10))
    throw std::invalid_argument("--check-ratio: within [0, 10]");
  if (a.runs < 2 || a.runs > 20) throw std::invalid_argument("--runs: must be within [2, 20]");
  for (const auto& d : a.directions)
    if (d != "left" && d != "right" && d != "forward" && d != "backward")
      throw std::invalid_argument("--directions: left, right, forward or backward, got " + d);
  for (double f : a.phases)
    if (!(f >= 0 && f < 1)) throw std::invalid_argument("--phases: fractions in [0, 1)");
  return a;
}

// The middle of the climb (the first time the base is halfway between its start and end
// heights) and the middle of the first swing whose touch-down is 5 cm above its lift-off (the
// step onto the pallet), as fractions of the plan.
std::pair<double, double> climb_phases(const planner::Trajectory& plan) {
  const double T = plan.samples.back().t;
  const double z0 = plan.samples.front().base.position.z();
  const double z1 = plan.samples.back().base.position.z();
  double mid_climb = 0.5;
  for (const auto& s : plan.samples)
    if (std::abs(s.base.position.z() - z0) >= 0.5 * std::abs(z1 - z0)) {
      mid_climb = s.t / T;
      break;
    }
  const planner::PhaseTimeline tl = planner::timeline_of(plan);
  double step_on = mid_climb;
  double best = T;
  for (std::size_t f = 0; f < tl.feet.size(); ++f)
    for (int j = 0; j < tl.num_intervals(); ++j) {
      if (tl.contact[f][j]) continue;
      const double lift = tl.events[j];
      int k = j;
      while (k + 1 < tl.num_intervals() && !tl.contact[f][k + 1]) ++k;
      const double land = tl.events[k + 1];
      const double z_lift = planner::interpolate_plan(plan, lift).feet[f].position.z();
      const double z_land = planner::interpolate_plan(plan, std::min(land, T)).feet[f].position.z();
      if (z_land - z_lift > 0.05 && lift < best) {
        best = lift;
        step_on = 0.5 * (lift + land) / T;
      }
    }
  return {mid_climb, step_on};
}

// The feet in the air at time t (the swing under way), "-" when all stand.
std::string swinging(const planner::Trajectory& plan, double t) {
  std::string out;
  const auto s = planner::interpolate_plan(plan, t);
  for (std::size_t f = 0; f < s.feet.size(); ++f)
    if (!s.feet[f].contact) out += (out.empty() ? "" : "+") + plan.feet[f];
  return out.empty() ? "-" : out;
}

// The largest push along `dir` at t survived, in `runs` simulations: doubling from 200 N until
// one fails (at most to 3200 N), then bisecting the bracket with the runs left.
bool survives_push(const robot::RobotModel& robot, const planner::Trajectory& plan,
                   const terrain::Scene& scene, const simulation::SimulationOptions& sim, double t,
                   const Eigen::Vector3d& force, std::string* failure) {
  simulation::SimulationOptions o = sim;
  o.pushes.push_back({t, force, 0.2});
  const auto r = simulation::simulate_plan(robot, plan, scene, o);
  if (r.verdict == "fail") *failure = r.reasons.empty() ? "fail" : r.reasons.front();
  return r.verdict != "fail";
}

double largest_push(const robot::RobotModel& robot, const planner::Trajectory& plan,
                    const terrain::Scene& scene, const simulation::SimulationOptions& sim, double t,
                    const Eigen::Vector3d& dir, int runs, std::string* failure) {
  auto survives = [&](double force) {
    return survives_push(robot, plan, scene, sim, t, force * dir, failure);
  };
  double lo = 0.0, hi = -1.0, a = 200.0;
  int used = 0;
  while (used < runs) {
    ++used;
    if (survives(a)) {
      lo = a;
      if (a >= 3200.0) return lo;
      a *= 2;
    } else {
      hi = a;
      break;
    }
  }
  while (used < runs && hi > 0) {
    ++used;
    const double mid = 0.5 * (lo + hi);
    (survives(mid) ? lo : hi) = mid;
  }
  return lo;
}

// The push along `dir` at time t of `plan`: the support of the feet standing then (kind "landed":
// and of the swing under way at its planned foothold; "one-step": those standing, and a foot
// landing at the edge of any leg's range of motion kOutwardStepTime after the push began;
// "foot-step": the best of one named foot stepping, landing then at the edge of its own range of
// motion, a standing one leaving the support when the push is seen, kPushSeenAfter, so that the
// feet left carry the body while it swings), h the base's height above them. *stepping_foot: the
// foot-step's foot ("-": no step does better).
enum class Support { no_step, landed, one_step, foot_step };
// A push is seen at the next 10 Hz re-plan at the latest, and the session's capture step lands
// 0.2 s after that (planning_session.cpp, kCaptureTouchdown).
constexpr double kPushSeenAfter = 0.1;
constexpr double kOutwardStepTime = 0.3;

double plan_push_limit(const robot::RobotModel& robot, const planner::Trajectory& plan, double mu,
                       double t, const Eigen::Vector3d& dir, Support kind,
                       std::string* stepping_foot = nullptr) {
  const auto s = planner::interpolate_plan(plan, t);
  const planner::PhaseTimeline tl = planner::timeline_of(plan);
  std::vector<Eigen::Vector2d> support;
  std::vector<std::size_t> standing;
  double ground = 0.0;
  for (std::size_t f = 0; f < s.feet.size(); ++f) {
    Eigen::Vector3d p = s.feet[f].position;
    if (!s.feet[f].contact) {
      if (kind != Support::landed) continue;
      double land = plan.duration;
      for (int j = 0; j < tl.num_intervals(); ++j)
        if (tl.events[j] > t && tl.contact[f][j]) {
          land = tl.events[j];
          break;
        }
      p = planner::interpolate_plan(plan, land).feet[f].position;
    } else {
      standing.push_back(f);
    }
    support.push_back(p.head<2>());
    ground += p.z();
  }
  if (support.empty()) return 0.0;
  const double h = s.base.position.z() - ground / support.size();
  const Eigen::Vector2d c = s.base.position.head<2>();
  const Eigen::Vector2d d = dir.head<2>().normalized();
  const double reach = support_reach(support, c, d);
  const double yaw = s.base.euler_zyx[0];
  if (kind == Support::one_step)
    return robot.mass *
           push_limit(reach, h, mu, 0.2, {kOutwardStepTime, outward_step_reach(robot, yaw, dir)});
  double best = robot.mass * push_limit(reach, h, mu, 0.2);
  if (stepping_foot) *stepping_foot = "-";
  if (kind != Support::foot_step) return best;
  for (std::size_t f = 0; f < s.feet.size() && f < robot.legs.size(); ++f) {
    if (robot.legs[f].name != plan.feet[f]) continue;  // the plan's feet in the robot's leg order
    OutwardStep step{kOutwardStepTime, leg_step_reach(robot.legs[f], yaw, dir)};
    if (s.feet[f].contact) {
      std::vector<Eigen::Vector2d> others;
      for (std::size_t g : standing)
        if (g != f) others.push_back(s.feet[g].position.head<2>());
      step.lift = kPushSeenAfter;
      step.edge_while_lifted = support_edge(others, c, d);
    }
    const double limit = robot.mass * push_limit(reach, h, mu, 0.2, step);
    if (limit > best) {
      best = limit;
      if (stepping_foot) *stepping_foot = plan.feet[f];
    }
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  bench::pin_blas_kernel(argv);
  Args args;
  try {
    args = parse(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "bench_push_recovery: " << e.what() << "\n";
    return 2;
  }
  const auto robot = robot::load_robot(robot::resolve_robot_path("hyq"));
  const auto scene = terrain::make_scene("pallet_15");
  const auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  planner::PlannerOptions po;
  po.gait = "crawl";
  po.cycles = 3;
  po.duration = 11.0;
  po.has_goal = true;
  po.goal = Eigen::Vector3d(scene->goal().x(), scene->goal().y(), 0.0);
  po.constraints = {"all"};
  po.max_time = 120.0;
  const auto planned = planner::plan_motion(robot, *smooth, *scene, po, 0.01);
  if (!planned.success) {
    std::cerr << "bench_push_recovery: the pallet_15 all plan failed: " << planned.message << "\n";
    return 1;
  }
  const planner::Trajectory& plan = planned.trajectory;
  if (!args.plan_out.empty()) planner::write_plan_file(args.plan_out, plan);
  const double T = plan.samples.back().t;
  std::vector<std::pair<double, std::string>> phases;
  if (args.phases.empty()) {
    for (int k = 1; k <= 6; ++k) phases.push_back({k / 7.0, "even"});
    const auto [mid_climb, step_on] = climb_phases(plan);
    phases.push_back({mid_climb, "mid-climb"});
    phases.push_back({step_on, "step onto the pallet (mid-swing)"});
    std::sort(phases.begin(), phases.end());
  } else {
    for (double f : args.phases) phases.push_back({f, "given"});
  }
  simulation::SimulationOptions open;
  open.record_dt = 0.0;
  open.controller.force_distribution =
      *simulation::force_distribution_named(args.force_distribution);
  const simulation::ReplannerFactory sessions = simulation::session_replanner(
      robot, *smooth, *scene, po, plan, args.horizon, 0.01, 0.0, args.iterations);
  // The closed loop of a push at t: a session's re-plans from t - replan_before on (before it
  // the run tracks the plan open loop).
  auto closed_loop = [&](double t) {
    simulation::SimulationOptions closed = open;
    closed.replan_every = args.replan_every;
    closed.replanner = sessions;
    closed.replan_from = args.replan_before < 0 ? 0.0 : t - args.replan_before;
    return closed;
  };
  const auto wall0 = std::chrono::steady_clock::now();
  nlohmann::json rows = nlohmann::json::array();
  if (!args.json)
    std::printf(
        "pallet_15 all (%.2f s), pushes of 0.2 s; closed loop: re-plan every %.2f s, "
        "horizon %.1f s, %d-iteration budget, from %.1f s before the push; %d runs per "
        "cell; stance forces %s; BLAS kernel %s\n"
        "%-6s %-7s %-34s %-9s %9s %9s %6s %9s %9s %9s %9s %-3s  %s\n",
        T, args.replan_every, args.horizon, args.iterations, args.replan_before, args.runs,
        args.force_distribution.c_str(), bench::blas_kernel_name().c_str(),
        "t (s)", "swing", "phase", "push", "open (N)",
        "closed(N)", "ratio", "no-step", "landed", "one-step", "foot-step", "by",
        "closed loop's failure");
  int met = 0, cells = 0;
  // Cells missed whose 1.5 x target is beyond the physical references (plan_push_limit).
  int beyond_no_step = 0, beyond_landed = 0, beyond_one_step = 0, beyond_foot_step = 0;
  for (const auto& [fraction, label] : phases) {
    const double t = fraction * T;
    const double yaw = planner::interpolate_plan(plan, t).base.euler_zyx[0];
    const Eigen::Vector3d ahead(std::cos(yaw), std::sin(yaw), 0.0);
    const Eigen::Vector3d left(-std::sin(yaw), std::cos(yaw), 0.0);
    for (const auto& d : args.directions) {
      const Eigen::Vector3d dir = d == "left"      ? left
                                  : d == "right"   ? Eigen::Vector3d(-left)
                                  : d == "forward" ? ahead
                                                   : Eigen::Vector3d(-ahead);
      std::string open_failure, closed_failure;
      const double no_step = plan_push_limit(robot, plan, open.friction, t, dir, Support::no_step);
      const double landed = plan_push_limit(robot, plan, open.friction, t, dir, Support::landed);
      const double one_step =
          plan_push_limit(robot, plan, open.friction, t, dir, Support::one_step);
      std::string stepper;
      const double foot_step =
          plan_push_limit(robot, plan, open.friction, t, dir, Support::foot_step, &stepper);
      if (args.limits_only) {
        std::printf("%-6.2f %-7s %-34s %-9s %9s %9s %6s %9.0f %9.0f %9.0f %9.0f %-3s\n", t,
                    swinging(plan, t).c_str(), label.c_str(), d.c_str(), "-", "-", "-", no_step,
                    landed, one_step, foot_step, stepper.c_str());
        continue;
      }
      const double o = largest_push(robot, plan, *scene, open, t, dir, args.runs, &open_failure);
      double c = 0.0;
      if (args.check_ratio > 0) {
        // One closed-loop run at the target: it survives R x the open loop's push or it does not.
        const double target = args.check_ratio * o;
        c = survives_push(robot, plan, *scene, closed_loop(t), t, target * dir, &closed_failure)
                ? target
                : 0.0;
      } else {
        c = largest_push(robot, plan, *scene, closed_loop(t), t, dir, args.runs, &closed_failure);
      }
      const double ratio = o > 0 ? c / o : (c > 0 ? INFINITY : 1.0);
      ++cells;
      met += ratio >= 1.5;
      const double target = 1.5 * o;
      beyond_no_step += ratio < 1.5 && target > no_step;
      beyond_landed += ratio < 1.5 && target > landed;
      beyond_one_step += ratio < 1.5 && target > one_step;
      beyond_foot_step += ratio < 1.5 && target > foot_step;
      rows.push_back({{"t", t},
                      {"fraction", fraction},
                      {"phase", label},
                      {"swing", swinging(plan, t)},
                      {"direction", d},
                      {"open_N", o},
                      {"closed_N", c},
                      {"ratio", ratio},
                      {"open_failure", open_failure},
                      {"closed_failure", closed_failure},
                      {"no_step_limit_N", no_step},
                      {"landed_limit_N", landed},
                      {"one_step_limit_N", one_step},
                      {"foot_step_limit_N", foot_step},
                      {"foot_step_foot", stepper}});
      if (!args.json) {
        std::printf("%-6.2f %-7s %-34s %-9s %9.0f %9.0f %6.2f %9.0f %9.0f %9.0f %9.0f %-3s  %s\n",
                    t, swinging(plan, t).c_str(), label.c_str(), d.c_str(), o, c, ratio, no_step,
                    landed, one_step, foot_step, stepper.c_str(), closed_failure.c_str());
        std::fflush(stdout);
      }
    }
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  if (args.json) {
    std::cout << nlohmann::json{{"plan_duration", T},
                                {"replan_every", args.replan_every},
                                {"horizon", args.horizon},
                                {"iterations", args.iterations},
                                {"runs", args.runs},
                                {"check_ratio", args.check_ratio},
                                {"rows", rows},
                                {"cells_met", met},
                                {"missed_beyond_no_step_limit", beyond_no_step},
                                {"missed_beyond_landed_limit", beyond_landed},
                                {"missed_beyond_one_step_limit", beyond_one_step},
                                {"missed_beyond_foot_step_limit", beyond_foot_step},
                                {"cells", cells},
                                {"wall_s", wall},
                                {"blas_kernel", bench::blas_kernel_name()},
                                {"force_distribution", args.force_distribution}}
                     .dump(1)
              << "\n";
  } else {
    std::printf(
        "closed loop >= 1.5x open loop in %d of %d cells; of the %d missed, %d ask for "
        "more than the no-step limit, %d more than the landed one, %d more than the "
        "one-step one, %d more than the foot-step one; %.0f s wall\n",
        met, cells, cells - met, beyond_no_step, beyond_landed, beyond_one_step, beyond_foot_step,
        wall);
  }
  return 0;
}
