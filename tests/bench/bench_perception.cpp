// Perception benchmarks: cloud reading speed per format, OctoMap insertion of OctoMap's own
// laser scan (88,206 points, sensor at the origin) and the dominant-plane estimate of `map`'s up
// check. Figures are items (points) per second.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <string>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/perception/support_plane.hpp"

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

// The up check of `map` on a cloud nobody posed (voxel grid + PCL's RANSAC plane), sensor at the
// origin; the PCL module is loaded before timing.
void plane_bench(benchmark::State& state, const std::string& file) {
  const tp::PointCloud c = tp::read_cloud(scan(file));
  tp::SupportPlane p = tp::estimate_support_plane(c.points, Eigen::Vector3d::Zero());
  for (auto _ : state) {
    p = tp::estimate_support_plane(c.points, Eigen::Vector3d::Zero());
    benchmark::DoNotOptimize(p.coefficients.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * c.points.size()));
  state.counters["points"] = static_cast<double>(c.points.size());
  state.counters["tilt_deg"] = p.tilt_deg;
}
void BM_SupportPlaneScanXyz(benchmark::State& s) { plane_bench(s, "octomap/scan.xyz"); }
void BM_SupportPlaneMaze(benchmark::State& s) {
  plane_bench(s, "anybotics_samples/elevation_mapping_maze.ply");
}
BENCHMARK(BM_SupportPlaneScanXyz)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SupportPlaneMaze)->Unit(benchmark::kMillisecond);

// Args: resolution in mm, discretize (0/1). Ray casting from the origin, as docs/design.md §5.1
// requires.
void BM_OctoMapInsertScanXyz(benchmark::State& state) {
  const tp::PointCloud cloud = tp::read_cloud(scan("octomap/scan.xyz"), Eigen::Vector3d::Zero());
  tp::OctoMapOptions options;
  options.resolution = static_cast<double>(state.range(0)) / 1000.0;
  options.discretize = state.range(1) != 0;
  size_t leaves = 0;
  for (auto _ : state) {
    auto tree = tp::build_octomap({cloud}, options);
    leaves = tree->getNumLeafNodes();
    state.PauseTiming();  // freeing the tree is not part of insertion
    tree.reset();
    state.ResumeTiming();
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * cloud.points.size()));
  state.counters["leaves"] = static_cast<double>(leaves);
}
// At 2 cm the unbounded 30 m rays of this scan make 18 M leaves and take about a minute, so
// the 2 cm case is benchmarked on the dense robot-scale cloud below instead.
BENCHMARK(BM_OctoMapInsertScanXyz)
    ->ArgNames({"res_mm", "discretize"})
    ->Args({100, 0})
    ->Args({100, 1})
    ->Args({50, 1})
    ->Unit(benchmark::kMillisecond);

// What `map` sees: 1 M points of a 4 m x 4 m floor with a 0.15 m box, from a sensor 1.5 m up,
// at the default 2 cm. Args: discretize (0/1).
void BM_OctoMapInsertDense1M(benchmark::State& state) {
  tp::PointCloud cloud;
  cloud.sensor_origin = Eigen::Vector3d(0, 0, 1.5);
  const int side = 1000;
  cloud.points.reserve(side * side);
  uint32_t rng = 12345;
  const auto noise = [&rng] {
    rng = rng * 1664525u + 1013904223u;
    return (static_cast<float>(rng >> 8) / 16777216.0f - 0.5f) * 0.004f;
  };
  for (int i = 0; i < side; ++i) {
    for (int j = 0; j < side; ++j) {
      const float x = -2.0f + 4.0f * i / side, y = -2.0f + 4.0f * j / side;
      const float z = (std::abs(x - 0.5f) < 0.4f && std::abs(y) < 0.6f) ? 0.15f : 0.0f;
      cloud.points.emplace_back(x, y, z + noise());
    }
  }
  tp::OctoMapOptions options;
  options.discretize = state.range(0) != 0;
  for (auto _ : state) {
    auto tree = tp::build_octomap({cloud}, options);
    benchmark::DoNotOptimize(tree.get());
    state.PauseTiming();  // freeing the tree is not part of insertion
    tree.reset();
    state.ResumeTiming();
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * cloud.points.size()));
}
BENCHMARK(BM_OctoMapInsertDense1M)
    ->ArgName("discretize")
    ->Arg(1)
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);

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

// Outlier removal as `terrastride map` runs it (no downsampling, k = 8): per point (arg 0) or
// judging 1 cm cells by their centroids (arg 10, in mm; the map default).
void BM_OutlierRemoval(benchmark::State& state) {
  const tp::PointCloud cloud = tp::read_cloud(scan("octomap/scan.xyz"));
  tp::CloudFilterOptions options;
  options.outlier_neighbours = 8;
  options.outlier_voxel = static_cast<float>(state.range(0)) * 1e-3f;
  tp::FilterStats stats;
  for (auto _ : state) {
    const tp::PointCloud out = tp::filter_cloud(cloud, options, &stats);
    benchmark::DoNotOptimize(out.points.data());
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations() * cloud.points.size()));
  state.counters["kept"] = static_cast<double>(stats.after_outliers);
  state.counters["cells"] = static_cast<double>(stats.outlier_cells);
}
BENCHMARK(BM_OutlierRemoval)->Arg(0)->Arg(10)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
