// Perception benchmarks: cloud reading speed per format and OctoMap insertion of OctoMap's own
// laser scan (88,206 points, sensor at the origin). Figures are items (points) per second.
#include <benchmark/benchmark.h>

#include <string>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/octomap_fusion.hpp"

namespace tp = terrastride::perception;

namespace {

std::string scan(const std::string& relative) {
  return std::string(TERRASTRIDE_SHARED_DIR) + "/scans/" + relative;
}

void read_bench(benchmark::State& state, const std::string& file) {
  const std::string path = scan(file);
  size_t points = 0;
  for (auto _ : state) {
    const tp::PointCloud c = tp::read_cloud(path);
    points = c.points.size();
    benchmark::DoNotOptimize(c.points.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * points));
  state.counters["points"] = static_cast<double>(points);
}

void BM_ReadPcdBinary(benchmark::State& s) {
  read_bench(s, "anybotics_samples/grid_map_pcl_input_cloud.pcd");
}
void BM_ReadPlyBinary(benchmark::State& s) {
  read_bench(s, "anybotics_samples/elevation_mapping_maze.ply");
}
void BM_ReadNpyFloat32(benchmark::State& s) {
  read_bench(s, "terrain_understanding_mit/grid_stairs.npy");
}
void BM_ReadXyzText(benchmark::State& s) {
  read_bench(s, "octomap/scan.xyz");
}
BENCHMARK(BM_ReadPcdBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadPlyBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadNpyFloat32)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadXyzText)->Unit(benchmark::kMillisecond);

// Args: resolution in mm, discretize (0/1). Ray casting from the origin, as DESIGN.md requires.
void BM_OctoMapInsertScanXyz(benchmark::State& state) {
  const tp::PointCloud cloud = tp::read_cloud(scan("octomap/scan.xyz"), Eigen::Vector3d::Zero());
  tp::OctoMapOptions options;
  options.resolution = static_cast<double>(state.range(0)) / 1000.0;
  options.discretize = state.range(1) != 0;
  size_t leaves = 0;
  for (auto _ : state) {
    const auto tree = tp::build_octomap({cloud}, options);
    leaves = tree->getNumLeafNodes();
    benchmark::DoNotOptimize(leaves);
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * cloud.points.size()));
  state.counters["leaves"] = static_cast<double>(leaves);
}
BENCHMARK(BM_OctoMapInsertScanXyz)
    ->ArgNames({"res_mm", "discretize"})
    ->Args({100, 0})
    ->Args({100, 1})
    ->Args({20, 0})
    ->Args({20, 1})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(1.0);

// The default cleaning chain (voxel 2 cm + outlier removal) on the OctoMap scan.
void BM_FilterVoxelAndOutliers(benchmark::State& state) {
  const tp::PointCloud cloud = tp::read_cloud(scan("octomap/scan.xyz"));
  tp::CloudFilterOptions options;
  options.voxel_size = 0.02f;
  options.outlier_neighbours = static_cast<int>(state.range(0));
  for (auto _ : state) {
    const tp::PointCloud out = tp::filter_cloud(cloud, options);
    benchmark::DoNotOptimize(out.points.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * cloud.points.size()));
}
BENCHMARK(BM_FilterVoxelAndOutliers)->Arg(0)->Arg(20)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
