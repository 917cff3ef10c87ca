// Post-hoc check timings over an 11 s crawl sampled every 2 ms (5,501 samples, 4 legs) onto the
// 10 cm pallet scene: the scene's voxelisation, the leg kinematics + torques, the FCL capsule
// queries (shin and thigh per leg and sample) and the foothold margins, separately and together.
// Run: ./tests/collision/bench_checks from the build directory.
#include <benchmark/benchmark.h>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "trajectories.hpp"

namespace tc = terrastride::collision;

namespace {

struct Fixture {
  terrastride::robot::RobotModel model = tc::test::hyq();
  std::unique_ptr<terrastride::terrain::Scene> scene =
      terrastride::terrain::make_scene("pallet_10");
  terrastride::planner::Trajectory traj = tc::test::synthetic_crawl(
      model, [this](double x, double y) { return scene->height(x, y); }, 11.0, 0.002, 3);
  Eigen::Vector2d lo, hi;
  std::shared_ptr<octomap::OcTree> tree;
  tc::TrajectoryKinematics kin;
  Fixture() {
    tc::trajectory_extent(model, traj, 0.1, &lo, &hi);
    tree = tc::voxelise_scene(*scene, lo, hi);
    kin = tc::leg_kinematics(model, traj);
  }
};

Fixture& fixture() {
  static Fixture f;
  return f;
}

void BM_VoxeliseScene(benchmark::State& state) {
  Fixture& f = fixture();
  tc::VoxeliseOptions vo;
  vo.resolution = state.range(0) / 1000.0;
  size_t nodes = 0;
  for (auto _ : state) nodes = tc::voxelise_scene(*f.scene, f.lo, f.hi, vo)->size();
  state.counters["octree_nodes"] = static_cast<double>(nodes);
}

void BM_KinematicsAndTorques(benchmark::State& state) {
  Fixture& f = fixture();
  for (auto _ : state) {
    const auto kin = tc::leg_kinematics(f.model, f.traj);
    benchmark::DoNotOptimize(tc::check_joint_torques(f.model, f.traj, kin).ratio_max);
  }
  state.SetItemsProcessed(state.iterations() * f.traj.samples.size());
}

void BM_LegCapsules(benchmark::State& state) {
  Fixture& f = fixture();
  tc::ClearanceOptions options;
  options.check_thigh = state.range(0) != 0;
  long queries = 0;
  for (auto _ : state)
    queries = tc::check_leg_clearance(f.model, f.traj, f.kin, *f.tree, options).fcl_queries;
  state.SetItemsProcessed(state.iterations() * f.traj.samples.size());
  state.counters["fcl_queries"] = static_cast<double>(queries);
  state.counters["capsule_samples"] = static_cast<double>(
      f.traj.samples.size() * f.model.legs.size() * (options.check_thigh ? 2 : 1));
}

void BM_Footholds(benchmark::State& state) {
  Fixture& f = fixture();
  for (auto _ : state)
    benchmark::DoNotOptimize(
        tc::check_footholds(f.traj, *f.scene, f.model.foot_radius).worst_margin);
}

// Everything `terrastride check` does after reading the plan: voxelise the scene, run all checks.
void BM_AllChecksIncludingVoxelisation(benchmark::State& state) {
  Fixture& f = fixture();
  for (auto _ : state) {
    tc::CheckTerrain terrain;
    terrain.field = f.scene.get();
    terrain.octree = tc::voxelise_scene(*f.scene, f.lo, f.hi);
    benchmark::DoNotOptimize(tc::run_checks(f.model, f.traj, terrain).torque.ratio_max);
  }
}

}  // namespace

BENCHMARK(BM_VoxeliseScene)->Arg(10)->Arg(20)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_KinematicsAndTorques)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LegCapsules)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Footholds)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AllChecksIncludingVoxelisation)->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
