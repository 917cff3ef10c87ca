// Terrain benchmarks (Google Benchmark):
//   BM_GridInsert        points/s into the height grid (1 M points, with and without sensor origin)
//   BM_OctoMapScanXyz    OctoMap insertion of ../shared/scans/octomap/scan.xyz (points/s), with
//                        and without a max range
//   BM_MapCommand1M      the whole `terrastride map` of a 1 M-point simulated scan (wall time)
//   BM_QueryHeightGrad   one h + grad h query of the smoothed field (ns)
//   BM_Safety200         safety masks + margins for a 200 x 200 grid at three radii
// Run: ./build/tests/bench/bench_terrain (targets: >= 5 M points/s, <= 1 s, <= 50 ns, <= 5 ms).
#include <benchmark/benchmark.h>

#include <unistd.h>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <random>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/terrain/scan_sim.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;

namespace {

// 1 M points over 4 x 3 m: ground, a 15 cm pallet, 3 mm noise.
const std::vector<Eigen::Vector3f>& million_points() {
  static const std::vector<Eigen::Vector3f> pts = [] {
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> ux(-1.0f, 3.0f), uy(-1.5f, 1.5f);
    std::normal_distribution<float> noise(0.0f, 0.003f);
    auto scene = terrain::make_scene("pallet_15");
    std::vector<Eigen::Vector3f> p(1'000'000);
    for (auto& q : p) {
      const float x = ux(rng), y = uy(rng);
      q = Eigen::Vector3f(x, y, static_cast<float>(scene->height(x, y)) + noise(rng));
    }
    return p;
  }();
  return pts;
}

void BM_GridInsert(benchmark::State& state) {
  const auto& pts = million_points();
  std::optional<Eigen::Vector3d> origin;
  if (state.range(0)) origin = Eigen::Vector3d(-1.5, 0.0, 0.8);
  for (auto _ : state) {
    auto grid = terrain::build_height_grid({terrain::PointBatch{pts.data(), pts.size(), origin}});
    benchmark::DoNotOptimize(grid.elevation.data());
  }
  state.SetItemsProcessed(state.iterations() * pts.size());
  state.SetLabel(state.range(0) ? "with sensor origin (overhang test)" : "no origin");
}
BENCHMARK(BM_GridInsert)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Arg: OctoMap max range in m (0 = none; `terrastride map --octomap-max-range`). The scan reaches
// 29 m; half its points lie within 4.9 m, 83 % within 10 m.
void BM_OctoMapScanXyz(benchmark::State& state) {
  const auto cloud = perception::read_cloud(
      std::string(TERRASTRIDE_SHARED_DIR) + "/scans/octomap/scan.xyz", Eigen::Vector3d::Zero());
  perception::OctoMapOptions o;
  o.resolution = 0.05;
  if (state.range(0) > 0) o.max_range = static_cast<double>(state.range(0));
  for (auto _ : state) {
    auto tree = perception::build_octomap({cloud}, o);
    benchmark::DoNotOptimize(tree.get());
  }
  state.SetItemsProcessed(state.iterations() * cloud.points.size());
  state.SetLabel(state.range(0) > 0 ? "0.05 m voxels, rays from the origin cut at " +
                                          std::to_string(state.range(0)) + " m"
                                    : std::string("0.05 m voxels, rays from the origin"));
}
BENCHMARK(BM_OctoMapScanXyz)->Arg(0)->Arg(10)->Arg(5)->Unit(benchmark::kMillisecond)->Iterations(2);

// A 1 M-point simulated scan (three poses of a 1000 x 333 depth image over the pallet scene).
std::vector<std::string> million_point_scan(const std::filesystem::path& dir) {
  auto scene = terrain::make_scene("pallet_15");
  terrain::DepthSensorOptions o;
  o.columns = 1000;
  o.rows = 400;
  std::vector<std::string> files;
  size_t total = 0;
  auto scans = terrain::simulate_scans(*scene, o);
  for (size_t k = 0; k < scans.size(); ++k) {
    auto& c = scans[k].cloud;
    if (total + c.points.size() > 1'000'000) c.points.resize(1'000'000 - total);
    total += c.points.size();
    files.push_back((dir / ("scan" + std::to_string(k) + ".pcd")).string());
    perception::write_pcd(c, files.back());
  }
  return files;
}

void BM_MapCommand1M(benchmark::State& state) {
  namespace fs = std::filesystem;
  // BENCH_TERRAIN_KEEP_DIR=D: write the scan and the map into D and keep them (to profile or
  // compare the map command by hand on the very same input).
  const char* keep = std::getenv("BENCH_TERRAIN_KEEP_DIR");
  const fs::path dir =
      keep ? fs::path(keep)
           : fs::temp_directory_path() / ("bench_terrain_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const auto files = million_point_scan(dir);
  std::string cmd = std::string(TERRASTRIDE_BINARY) + " map";
  for (const auto& f : files) cmd += " " + f;
  cmd += " --out " + (dir / "map").string() + " --json > /dev/null 2>&1";
  // 0: no outlier removal; 1: defaults (removal judging 1 cm cells); 2: removal judging every
  // point.
  const char* extra[] = {" --outlier-k 0", "", " --outlier-voxel 0"};
  const std::string full = std::string(cmd).insert(cmd.find(" --out"), extra[state.range(0)]);
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    if (std::system(full.c_str()) != 0) state.SkipWithError("terrastride map failed");
    state.SetIterationTime(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  state.SetItemsProcessed(state.iterations() * 1'000'000);
  const char* label[] = {"--outlier-k 0", "defaults (outlier removal by 1 cm cell)",
                         "--outlier-voxel 0 (outlier removal per point)"};
  state.SetLabel(label[state.range(0)]);
  if (!keep) fs::remove_all(dir);
}
BENCHMARK(BM_MapCommand1M)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond)
    ->Iterations(2);

void BM_QueryHeightGrad(benchmark::State& state) {
  auto scene = terrain::make_scene("stairs");
  auto map = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> ux(-0.9, 2.4), uy(-0.9, 0.9);
  std::vector<Eigen::Vector2d> q(4096);
  for (auto& p : q) p = Eigen::Vector2d(ux(rng), uy(rng));
  size_t i = 0;
  Eigen::Vector2d g;
  for (auto _ : state) {
    const auto& p = q[i++ & 4095];
    benchmark::DoNotOptimize(map->height_gradient(p.x(), p.y(), &g));
    benchmark::DoNotOptimize(g);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_QueryHeightGrad)->Unit(benchmark::kNanosecond);

void BM_QueryFullSample(benchmark::State& state) {
  auto scene = terrain::make_scene("stairs");
  auto map = terrain::TerrainMap::from_scene(*scene, 0.02, {0.02});
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> ux(-0.9, 2.4), uy(-0.9, 0.9);
  std::vector<Eigen::Vector2d> q(4096);
  for (auto& p : q) p = Eigen::Vector2d(ux(rng), uy(rng));
  size_t i = 0;
  for (auto _ : state) {
    const auto& p = q[i++ & 4095];
    benchmark::DoNotOptimize(map->sample(p.x(), p.y()));
    benchmark::DoNotOptimize(map->safety_margin(p.x(), p.y(), 0.02));
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel("h, grad, Hessian and margin + grad");
}
BENCHMARK(BM_QueryFullSample)->Unit(benchmark::kNanosecond);

void BM_Safety200(benchmark::State& state) {
  auto scene = terrain::make_scene("eur_pallet");
  const auto grid = terrain::rasterize_scene(*scene, 0.02, Eigen::Vector2d(-0.8, -2.0),
                                             Eigen::Vector2d(3.2 - 1e-6, 2.0 - 1e-6));
  if (grid.geometry.nx != 200 || grid.geometry.ny != 200)
    state.SkipWithError("grid is not 200x200");
  for (auto _ : state) {
    auto layers = terrain::compute_safety(grid, {0.02, 0.05, 0.10});
    benchmark::DoNotOptimize(layers.back().margin.data());
  }
  state.SetLabel("200 x 200 cells, r = 0.02, 0.05, 0.10 m (masks and EDT margins)");
}
BENCHMARK(BM_Safety200)->Unit(benchmark::kMillisecond);

// The C2 interpolating spline of one margin layer (built once per radius when a map is loaded).
void BM_MarginSpline200(benchmark::State& state) {
  auto scene = terrain::make_scene("eur_pallet");
  const auto grid = terrain::rasterize_scene(*scene, 0.02, Eigen::Vector2d(-0.8, -2.0),
                                             Eigen::Vector2d(3.2 - 1e-6, 2.0 - 1e-6));
  const auto layer = terrain::compute_safety(grid, 0.02);
  for (auto _ : state) {
    terrain::BSplineField f(grid.geometry, layer.margin, true);
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_MarginSpline200)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
