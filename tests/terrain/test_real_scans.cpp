// The terrain module on real scans (../shared/scans, see its README).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride;
using terrain::TerrainMap;

namespace {

// These tests skip, with a message, where ../shared is absent (a user's clone).
#define REQUIRE_SHARED_SCANS()                                                        \
  if (!std::filesystem::is_directory(std::string(TERRASTRIDE_SHARED_DIR) + "/scans")) \
  GTEST_SKIP() << "no " << TERRASTRIDE_SHARED_DIR                                     \
               << "/scans (the shared scans folder is not "                           \
                  "beside this clone)"

std::string scan(const std::string& rel) {
  return std::string(TERRASTRIDE_SHARED_DIR) + "/scans/" + rel;
}

TerrainMap map_of(const std::string& rel, std::vector<double> radii) {
  auto cloud = perception::read_cloud(scan(rel));
  return TerrainMap(terrain::build_height_grid(std::vector<perception::PointCloud>{cloud}), radii);
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

TEST(RealScans, NoisyFlatPlaneIsSafeAwayFromItsBorder) {
  REQUIRE_SHARED_SCANS();
  const TerrainMap m = map_of("anybotics_samples/grid_map_pcl_input_cloud.pcd", {0.02, 0.05});
  const auto& g = m.grid().geometry;
  EXPECT_GT(m.grid().noise_sigma, 0.01);  // this sample is a noisy plane (sigma about 2 cm)
  for (double r : {0.02, 0.05}) {
    size_t interior = 0, safe = 0;
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j) {
        const Eigen::Vector2d c = g.center(i, j);
        const double border = std::min({c.x() - g.origin.x(), g.max_corner().x() - c.x(),
                                        c.y() - g.origin.y(), g.max_corner().y() - c.y()});
        if (border < 0.10) continue;
        ++interior;
        safe += m.layer(r).safe[g.index(i, j)];
        EXPECT_GT(m.safety_margin(c.x(), c.y(), r).margin, -1.0);
      }
    ASSERT_GT(interior, 5000u);
    EXPECT_GE(double(safe) / interior, 0.97) << "r = " << r;
  }
  // Cells on the border itself are unsafe: the foot disk is not fully observed there.
  EXPECT_FALSE(m.layer(0.02).safe[g.index(0, g.ny / 2)]);
}

TEST(RealScans, CurbEdgeUnsafeBothLevelsSafeRiseMeasured) {
  REQUIRE_SHARED_SCANS();
  const double r = 0.02;
  const TerrainMap m = map_of("terrain_understanding_mit/curb_w_grass.npy", {r});
  const auto& grid = m.grid();
  const auto& g = grid.geometry;
  const auto& safe = m.layer(r).safe;
  // Levels from the README: pavement about -0.636, curb top about -0.478 (then grass).
  std::vector<double> low, high;
  for (int i = 0; i < g.nx; ++i)
    for (int j = 2; j <= g.ny - 3; ++j) {
      const double x = g.center(i, j).x();
      if (x > -0.45 && x < -0.25) low.push_back(grid.elevation[g.index(i, j)]);
      if (x > -0.05 && x < 0.10) high.push_back(grid.elevation[g.index(i, j)]);
    }
  const double z_low = median(low), z_high = median(high);
  EXPECT_NEAR(z_high - z_low, 0.16, 0.015);
  // Per inner column, the curb edge band: from the end of the last pavement cell to the start of
  // the first curb-top cell (cells in between hold the curb face).
  size_t low_n = 0, low_safe = 0, high_n = 0, high_safe = 0, band_cells = 0;
  for (int j = 2; j <= g.ny - 3; ++j) {
    int last_low = -1, first_high = -1;
    for (int i = 0; i < g.nx && first_high < 0; ++i) {
      const double z = grid.elevation[g.index(i, j)];
      if (std::abs(z - z_low) < 0.03) last_low = i;
      if (last_low >= 0 && std::abs(z - z_high) < 0.03) first_high = i;
    }
    ASSERT_GE(last_low, 0);
    ASSERT_GT(first_high, last_low);
    const double band_lo = g.origin.x() + (last_low + 1) * g.resolution;
    const double band_hi = g.origin.x() + first_high * g.resolution;
    EXPECT_NEAR(0.5 * (band_lo + band_hi), -0.11, 0.04) << "column " << j;
    for (int i = 0; i < g.nx; ++i) {
      const Eigen::Vector2d c = g.center(i, j);
      const bool s = safe[g.index(i, j)];
      if (c.x() >= band_lo - r && c.x() <= band_hi + r) {
        ++band_cells;
        EXPECT_FALSE(s) << "cell at x = " << c.x() << " is within r of the curb edge";
        EXPECT_LT(m.safety_margin(c.x(), c.y(), r).margin, 0.0) << c.x();
      }
      const double away = r + 2.5 * g.resolution;  // r + 2 cells, between centres and the band
      if (c.x() < band_lo - away && c.x() > -0.55) {
        ++low_n;
        low_safe += s;
      }
      if (c.x() > band_hi + away && c.x() < 0.15) {
        ++high_n;
        high_safe += s;
      }
    }
  }
  EXPECT_GT(band_cells, 14u);
  ASSERT_GT(low_n, 50u);
  ASSERT_GT(high_n, 30u);
  EXPECT_GE(double(low_safe) / low_n, 0.95);
  EXPECT_GE(double(high_safe) / high_n, 0.95);
}

TEST(RealScans, GratedStairsGiveTreadsNotUnderGratingReturns) {
  REQUIRE_SHARED_SCANS();
  const TerrainMap m = map_of("terrain_understanding_mit/grid_stairs.npy", {0.02});
  const auto& grid = m.grid();
  const auto& g = grid.geometry;
  struct Tread {
    double x0, x1, z;
  };
  // Inner parts of the treads (README: -0.75, -0.56, -0.39, -0.19, -0.02); the top tread is only
  // seen on a 2 cm strip.
  const Tread treads[] = {{-0.33, -0.23, -0.75},
                          {-0.17, 0.03, -0.56},
                          {0.09, 0.29, -0.385},
                          {0.37, 0.57, -0.19},
                          {0.60, 0.62, -0.02}};
  for (const Tread& t : treads) {
    std::vector<double> z;
    size_t near = 0;
    for (int i = 0; i < g.nx; ++i) {
      const double x = g.center(i, 0).x();
      if (x < t.x0 || x > t.x1) continue;
      for (int j = 1; j <= g.ny - 2; ++j) {
        const double h = grid.elevation[g.index(i, j)];
        z.push_back(h);
        near += std::abs(h - t.z) < 0.03;
      }
    }
    ASSERT_FALSE(z.empty());
    const double frac = double(near) / z.size();
    if (t.x1 - t.x0 < 0.05) {
      EXPECT_GE(near, 2u) << "top tread " << t.z;
    } else {
      EXPECT_NEAR(median(z), t.z, 0.015) << "tread " << t.z;
      EXPECT_GE(frac, 0.75) << "tread " << t.z;
    }
  }
  EXPECT_GT(grid.see_through_cells, 50u);
}
