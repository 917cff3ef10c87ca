// The force-polytope fit `robot import` runs: one robot's every leg, with the default options
// (planner::PolytopeFitOptions), on the shipped robot files. Counters: the fit's quality on
// held-out foot positions (rho_out median / max, rho_in median; polytope_fit.hpp) beside the
// time, so a faster fit that fits worse shows.
//
// import_*: the whole `robot import` of a real URDF (/work/shared/robots, or
// $TERRASTRIDE_SHARED_DIR/robots): URDF import, the robot file read back, the fit, both files
// written to a temporary folder; five runs, each with its wall time ("Time") and the process's
// CPU time over all threads ("CPU"), the Ceres iterations summed over the legs, and how many legs
// were fitted and how many copied from a mirror twin. `import_go2_fit_all` fits every leg
// (copy_legs off) for comparison. Run from the build directory:
//   ./tests/bench/bench_polytope_fit [--benchmark_filter=import]
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/robot/urdf_import.hpp"

using namespace terrastride;

namespace {

void add_held_out_quality(benchmark::State& state, const robot::RobotModel& model,
                          const planner::RobotPolytopeModel& fitted) {
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

void fit_robot(benchmark::State& state, const std::string& name) {
  const robot::RobotModel model = robot::load_robot(robot::resolve_robot_path(name));
  planner::PolytopeFitOptions options;
  planner::RobotPolytopeModel fitted;
  for (auto _ : state) {
    fitted = planner::fit_robot_polytopes(model, options, nullptr);
    benchmark::DoNotOptimize(fitted);
  }
  add_held_out_quality(state, model, fitted);
}

// The shared data folder: $TERRASTRIDE_SHARED_DIR, else `shared` beside the repository that
// holds this build (BUILD/tests/bench/bench_polytope_fit -> REPO/../shared).
std::filesystem::path shared_dir() {
  if (const char* env = std::getenv("TERRASTRIDE_SHARED_DIR")) return env;
  std::error_code ec;
  const auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {};
  return exe.parent_path() / ".." / ".." / ".." / ".." / "shared";
}

struct ImportCase {
  std::string name;  // the robot's name and the folder below shared/robots
  std::string urdf;  // file in that folder
  std::map<std::string, std::pair<double, double>> joint_range_deg;
  bool copy_legs = true;
};

void import_robot(benchmark::State& state, const ImportCase& c) {
  const std::filesystem::path urdf = shared_dir() / "robots" / c.name / c.urdf;
  if (!std::filesystem::exists(urdf)) {
    state.SkipWithError(("no " + urdf.string() + " (set TERRASTRIDE_SHARED_DIR)").c_str());
    return;
  }
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("bench_polytope_fit_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string out = (dir / (c.name + ".yaml")).string();
  robot::UrdfImportOptions o;
  o.name = c.name;
  o.joint_range_deg = c.joint_range_deg;
  planner::PolytopeFitOptions options;
  options.copy_legs = c.copy_legs;
  robot::RobotModel model;
  planner::RobotPolytopeModel fitted;
  std::vector<planner::LegFitReport> reports;
  for (auto _ : state) {
    const robot::UrdfImport result = robot::import_urdf(urdf.string(), o);
    model = robot::parse_robot(result.yaml, out);
    fitted = planner::fit_robot_polytopes(model, options, &reports);
    fitted.fit_summary = planner::describe_fit(options);
    planner::save_polytope_model(fitted, model, planner::polytope_path_for(model));
    std::ofstream(out) << result.yaml;
  }
  int iterations = 0, copied = 0;
  for (const auto& r : reports) {
    iterations += r.iterations;
    copied += r.copied_from.empty() ? 0 : 1;
  }
  state.counters["ceres_iterations"] = iterations;
  state.counters["legs_fitted"] = static_cast<double>(reports.size()) - copied;
  state.counters["legs_copied"] = copied;
  add_held_out_quality(state, model, fitted);
  std::filesystem::remove_all(dir);
}

const ImportCase kGo2{"go2", "go2_description.urdf", {}, true};
const ImportCase kGo2FitAll{"go2", "go2_description.urdf", {}, false};
// ANYmal C's URDF gives +-540 deg placeholders for HFE and KFE: the ranges
// data/robots/anymal_c.yaml was imported with.
const ImportCase kAnymalC{"anymal_c",
                          "anymal.urdf",
                          {{"LF_HFE", {-90, 90}},
                           {"RF_HFE", {-90, 90}},
                           {"LH_HFE", {-90, 90}},
                           {"RH_HFE", {-90, 90}},
                           {"LF_KFE", {-150, -10}},
                           {"RF_KFE", {-150, -10}},
                           {"LH_KFE", {10, 150}},
                           {"RH_KFE", {10, 150}}},
                          true};

}  // namespace

BENCHMARK_CAPTURE(fit_robot, go2, std::string("go2"))->Unit(benchmark::kSecond)->Iterations(1);
BENCHMARK_CAPTURE(fit_robot, anymal_c, std::string("anymal_c"))
    ->Unit(benchmark::kSecond)
    ->Iterations(1);
BENCHMARK_CAPTURE(fit_robot, hyq, std::string("hyq"))->Unit(benchmark::kSecond)->Iterations(1);

#define IMPORT_BENCHMARK(label, c)                  \
  BENCHMARK_CAPTURE(import_robot, label, c)         \
      ->Unit(benchmark::kMillisecond)               \
      ->Iterations(1)                               \
      ->Repetitions(5)                              \
      ->MeasureProcessCPUTime()                     \
      ->UseRealTime()
IMPORT_BENCHMARK(go2, kGo2);
IMPORT_BENCHMARK(go2_fit_all, kGo2FitAll);
IMPORT_BENCHMARK(anymal_c, kAnymalC);

BENCHMARK_MAIN();
