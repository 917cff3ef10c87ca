// The force-polytope fit `robot import` runs: one robot's every leg, with the default options
// (planner::PolytopeFitOptions), on the shipped robot files. Counters: the fit's quality on
// held-out foot positions (rho_out median / max, rho_in median; polytope_fit.hpp) beside the
// time, so a faster fit that fits worse shows. Run from the build directory:
//   ./tests/bench/bench_polytope_fit [--benchmark_filter=go2]
#include <benchmark/benchmark.h>

#include <algorithm>
#include <string>
#include <vector>

#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/robot/robot_model.hpp"

using namespace terrastride;

namespace {

void fit_robot(benchmark::State& state, const std::string& name) {
  const robot::RobotModel model = robot::load_robot(robot::resolve_robot_path(name));
  planner::PolytopeFitOptions options;
  planner::RobotPolytopeModel fitted;
  for (auto _ : state) {
    fitted = planner::fit_robot_polytopes(model, options, nullptr);
    benchmark::DoNotOptimize(fitted);
  }
  double out_median = 0, out_max = 0, in_median = 1;
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const auto held_out = planner::sample_leg_workspace(model.legs[i], 300, 424242 + i);
    const auto q = planner::evaluate_polytope_quality(fitted.legs[i], model.legs[i], held_out);
    out_median = std::max(out_median, q.rho_out_median);
    out_max = std::max(out_max, q.rho_out_max);
    in_median = std::min(in_median, q.rho_in_median);
  }
  state.counters["rho_out_median"] = out_median;
  state.counters["rho_out_max"] = out_max;
  state.counters["rho_in_median"] = in_median;
}

}  // namespace

BENCHMARK_CAPTURE(fit_robot, go2, std::string("go2"))->Unit(benchmark::kSecond)->Iterations(1);
BENCHMARK_CAPTURE(fit_robot, anymal_c, std::string("anymal_c"))
    ->Unit(benchmark::kSecond)
    ->Iterations(1);
BENCHMARK_CAPTURE(fit_robot, hyq, std::string("hyq"))->Unit(benchmark::kSecond)->Iterations(1);

BENCHMARK_MAIN();
