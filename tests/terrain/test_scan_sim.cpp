// Simulated scans of the scenes, through the height grid and the safety masks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "terrastride/perception/filters.hpp"
#include "terrastride/terrain/scan_sim.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride::terrain;
using terrastride::perception::PointCloud;

namespace {

// As `terrastride map` does by default: statistical outlier removal (flying pixels) per cloud,
// judging 1 cm cells by their centroids (outlier_voxel = 0: every point, PCL's plain filter).
std::unique_ptr<TerrainMap> map_scene(const std::string& name, std::vector<double> radii,
                                      unsigned seed = 1, float outlier_voxel = 0.01f) {
  auto scene = make_scene(name);
  DepthSensorOptions o;
  o.seed = seed;
  terrastride::perception::CloudFilterOptions f;
  f.outlier_neighbours = 8;
  f.outlier_stddev = 2.0;
  f.outlier_voxel = outlier_voxel;
  std::vector<PointCloud> clouds;
  for (auto& s : simulate_scans(*scene, o))
    clouds.push_back(terrastride::perception::filter_cloud(s.cloud, f));
  return std::make_unique<TerrainMap>(build_height_grid(clouds), radii);
}

}  // namespace

TEST(ScanSim, DeterministicNoisyAndWithOrigins) {
  auto scene = make_scene("pallet_10");
  DepthSensorOptions o;
  const auto a = simulate_scans(*scene, o), b = simulate_scans(*scene, o);
  ASSERT_EQ(a.size(), 3u);
  for (size_t k = 0; k < a.size(); ++k) {
    ASSERT_EQ(a[k].cloud.points.size(), b[k].cloud.points.size());
    EXPECT_TRUE(a[k].cloud.points == b[k].cloud.points);
    ASSERT_TRUE(a[k].cloud.sensor_origin);
    EXPECT_NEAR(a[k].cloud.sensor_origin->z(), 0.8, 1e-12);
    EXPECT_GT(a[k].dropped, 0u);
    EXPECT_GT(a[k].mixed, 0u);  // the pallet edges make flying pixels
  }
  o.seed = 2;
  const auto c = simulate_scans(*scene, o);
  EXPECT_FALSE(a[0].cloud.points == c[0].cloud.points);
  // Noise: ground points near the sensor scatter by millimetres, not centimetres.
  double sum2 = 0;
  size_t n = 0;
  for (const auto& p : a[2].cloud.points)
    if (p.x() > 0.1 && p.x() < 0.45 && std::abs(p.y()) < 0.3) {
      sum2 += double(p.z()) * p.z();
      ++n;
    }
  ASSERT_GT(n, 100u);
  EXPECT_LT(std::sqrt(sum2 / n), 0.006);
  EXPECT_GT(std::sqrt(sum2 / n), 0.0005);
  o.pitch_deg = 120;
  EXPECT_THROW(simulate_scans(*scene, o), terrastride::perception::InputError);
}

TEST(ScanSim, PalletTopAndGroundWithinOneCentimetreEdgesUnsafe) {
  for (const float outlier_voxel : {0.01f, 0.0f})
    for (const std::string name : {"pallet_10", "pallet_15"}) {
      SCOPED_TRACE("outlier voxel " + std::to_string(outlier_voxel));
      auto scene = make_scene(name);
      const double r = 0.02;
      auto map = map_scene(name, {r}, 1, outlier_voxel);
      const auto& grid = map->grid();
      const auto& g = grid.geometry;
      size_t top_n = 0, ground_n = 0, edge_n = 0, away_n = 0, away_safe = 0;
      for (int i = 0; i < g.nx; ++i)
        for (int j = 0; j < g.ny; ++j) {
          const size_t k = g.index(i, j);
          const Eigen::Vector2d c = g.center(i, j);
          const double d = scene->edge_distance(c.x(), c.y());
          const bool in_view = c.x() > -0.4 && c.x() < 2.2 && std::abs(c.y()) < 0.8;
          if (!in_view || grid.observed[k] != 1) continue;
          // Heights away from the edges (mixed pixels live there).
          if (d > 0.06) {
            const double truth = scene->height(c.x(), c.y());
            EXPECT_NEAR(grid.elevation[k], truth, 0.01)
                << name << " at " << c.transpose() << " n " << grid.count[k] << " s "
                << grid.support[k];
            (truth > 0 ? top_n : ground_n)++;
          }
          if (d <= r) {
            ++edge_n;
            EXPECT_FALSE(map->layer(r).safe[k]) << name << " edge cell " << c.transpose();
          }
          bool disk_observed = i > 0 && j > 0 && i + 1 < g.nx && j + 1 < g.ny;
          for (int di = -1; di <= 1 && disk_observed; ++di)
            for (int dj = -1; dj <= 1; ++dj)
              disk_observed &= grid.observed[g.index(i + di, j + dj)] != 0;
          if (d >= r + 2 * g.resolution + 0.5 * g.resolution && disk_observed) {
            ++away_n;
            away_safe += map->layer(r).safe[k];
          }
        }
      EXPECT_GT(top_n, 600u) << name;
      EXPECT_GT(ground_n, 1000u) << name;
      EXPECT_GT(edge_n, 100u) << name;
      // Safe >= r + 2 cells away from the edges, wherever the disk was fully observed.
      EXPECT_GE(double(away_safe) / away_n, 0.97) << name;
    }
}

TEST(ScanSim, OtherScenesMapToTheirHeights) {
  for (const std::string name : {"stairs", "gap", "eur_pallet", "flat"}) {
    auto scene = make_scene(name);
    auto map = map_scene(name, {0.02});
    const auto& grid = map->grid();
    const auto& g = grid.geometry;
    size_t n = 0, ok = 0;
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        const size_t k = g.index(i, j);
        const Eigen::Vector2d c = g.center(i, j);
        if (grid.observed[k] != 1 || scene->edge_distance(c.x(), c.y()) < 0.06) continue;
        if (c.x() < -0.4 || c.x() > 2.2 || std::abs(c.y()) > 0.8) continue;
        ++n;
        ok += std::abs(grid.elevation[k] - scene->height(c.x(), c.y())) < 0.01;
      }
    ASSERT_GT(n, 500u) << name;
    EXPECT_GE(double(ok) / n, 0.97) << name;
  }
}

// A scan of shelf_60 sees the shelf: its top (z = 0.64) from the pose nearest it, and the ground
// beneath it (under the slab, between its legs); hardly any point lies inside the 4 cm slab.
TEST(ScanSim, AShelfScanSeesTheSlabAndTheGroundBeneathIt) {
  const auto scene = make_scene("shelf_60");
  const auto scans = simulate_scans(*scene, DepthSensorOptions{});
  ASSERT_EQ(scans.size(), 3u);
  size_t top = 0, under = 0, inside = 0;
  for (const auto& s : scans)
    for (const auto& p : s.cloud.points) {
      const bool over = p.x() > 0.41 && p.x() < 0.89 && std::abs(p.y()) < 0.7;
      top += over && std::abs(p.z() - 0.64f) < 0.01f;
      under += over && std::abs(p.z()) < 0.01f;
      inside += over && p.z() > 0.61f && p.z() < 0.625f;
    }
  EXPECT_GT(top, 1000u);
  EXPECT_GT(under, 1000u);
  EXPECT_LT(inside, top / 20);  // range noise and mixed pixels only
}
