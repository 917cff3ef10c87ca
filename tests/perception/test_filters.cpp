// The PCL filters do what they claim on real and synthetic clouds.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <set>
#include <tuple>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::scan;

size_t count_if_z(const PointCloud& c, float lo, float hi) {
  size_t n = 0;
  for (const auto& p : c.points) n += (p.z() >= lo && p.z() <= hi);
  return n;
}

TEST(FilterCloud, OffPassesThroughAndDropsNaN) {
  PointCloud c;
  c.source = "mem";
  c.sensor_origin = Eigen::Vector3d(1, 2, 3);
  c.points = {{0, 0, 0}, {std::numeric_limits<float>::quiet_NaN(), 0, 0}, {1, 1, 1}};
  FilterStats s;
  const PointCloud out = filter_cloud(c, {}, &s);
  EXPECT_EQ(out.points.size(), 2u);
  EXPECT_EQ(s.points_in, 3u);
  EXPECT_EQ(s.non_finite, 1u);
  EXPECT_EQ(s.after_crop, 2u);
  EXPECT_EQ(s.after_voxel, 2u);
  EXPECT_EQ(s.after_outliers, 2u);
  EXPECT_GE(s.seconds, 0.0);
  EXPECT_EQ(out.sensor_origin, c.sensor_origin);
  EXPECT_EQ(out.source, "mem");
}

TEST(FilterCloud, CropBoundsHold) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("octomap/scan.xyz"));
  CloudFilterOptions o;
  o.crop_min = Eigen::Vector3f(0, -5, -1);
  o.crop_max = Eigen::Vector3f(10, 5, 2);
  FilterStats s;
  const PointCloud out = filter_cloud(c, o, &s);
  size_t expected = 0;
  for (const auto& p : c.points) {
    expected +=
        (p.array() >= o.crop_min->array()).all() && (p.array() <= o.crop_max->array()).all();
  }
  EXPECT_EQ(out.points.size(), expected);
  EXPECT_GT(expected, 1000u);
  EXPECT_LT(expected, c.points.size());
  for (const auto& p : out.points) {
    ASSERT_TRUE((p.array() >= o.crop_min->array()).all() &&
                (p.array() <= o.crop_max->array()).all())
        << p.transpose();
  }
  EXPECT_EQ(s.after_crop, expected);
}

TEST(FilterCloud, OneSidedCrop) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("terrain_understanding_mit/grid_water.npy"));
  CloudFilterOptions o;
  o.crop_min = Eigen::Vector3f(-1e3f, -1e3f, -1.0f);  // drop see-through returns below z = -1
  const PointCloud out = filter_cloud(c, o);
  EXPECT_EQ(out.points.size(), c.points.size() - count_if_z(c, -1e9f, -1.0f - 1e-6f));
  EXPECT_EQ(count_if_z(out, -1e9f, -1.0001f), 0u);
}

TEST(FilterCloud, VoxelGridLeavesAtMostOnePointPerVoxel) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"));
  CloudFilterOptions o;
  o.voxel_size = 0.05f;
  FilterStats s;
  const PointCloud out = filter_cloud(c, o, &s);
  EXPECT_LT(out.points.size(), c.points.size() / 4);
  EXPECT_GT(out.points.size(), 100u);
  EXPECT_EQ(s.after_voxel, out.points.size());
  // Centroids of distinct voxels: no two fall into the same voxel of the same grid.
  std::set<std::tuple<int, int, int>> cells;
  for (const auto& p : c.points) {
    cells.emplace(static_cast<int>(std::floor(p.x() / 0.05f)),
                  static_cast<int>(std::floor(p.y() / 0.05f)),
                  static_cast<int>(std::floor(p.z() / 0.05f)));
  }
  EXPECT_EQ(out.points.size(), cells.size());
  // A coarser grid keeps fewer points.
  o.voxel_size = 0.2f;
  EXPECT_LT(filter_cloud(c, o).points.size(), out.points.size());
}

TEST(FilterCloud, OutlierRemovalDropsFarOutliersKeepsTreads) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("terrain_understanding_mit/grid_stairs.npy"));
  // README: 11 far outliers near z = -2.4; treads at -0.75, -0.56, -0.39, -0.19, -0.02.
  ASSERT_EQ(count_if_z(c, -3.0f, -2.0f), 11u);
  CloudFilterOptions o;
  o.outlier_neighbours = 20;
  o.outlier_stddev = 2.0;
  FilterStats s;
  const PointCloud out = filter_cloud(c, o, &s);
  EXPECT_EQ(count_if_z(out, -3.0f, -2.0f), 0u);
  for (float tread : {-0.75f, -0.56f, -0.39f, -0.19f, -0.02f}) {
    SCOPED_TRACE(tread);
    const size_t before = count_if_z(c, tread - 0.03f, tread + 0.03f);
    const size_t after = count_if_z(out, tread - 0.03f, tread + 0.03f);
    EXPECT_GT(before, 100u);
    EXPECT_GE(after, before * 95 / 100);
  }
  EXPECT_EQ(s.after_outliers, out.points.size());
  EXPECT_LT(out.points.size(), c.points.size());
  EXPECT_GT(out.points.size(), c.points.size() * 9 / 10);
}

// The same outliers and treads when the removal judges 1 cm cells by their centroids (the map
// command's default): whole cells are kept or dropped, and the kept points are the input's own.
TEST(FilterCloud, OutlierRemovalByVoxelDropsFarOutliersKeepsTreads) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("terrain_understanding_mit/grid_stairs.npy"));
  ASSERT_EQ(count_if_z(c, -3.0f, -2.0f), 11u);
  CloudFilterOptions o;
  o.outlier_neighbours = 8;
  o.outlier_stddev = 2.0;
  o.outlier_voxel = 0.01f;
  FilterStats s;
  const PointCloud out = filter_cloud(c, o, &s);
  EXPECT_EQ(count_if_z(out, -3.0f, -2.0f), 0u);
  for (float tread : {-0.75f, -0.56f, -0.39f, -0.19f, -0.02f}) {
    SCOPED_TRACE(tread);
    const size_t before = count_if_z(c, tread - 0.03f, tread + 0.03f);
    EXPECT_GE(count_if_z(out, tread - 0.03f, tread + 0.03f), before * 95 / 100);
  }
  EXPECT_EQ(s.after_outliers, out.points.size());
  EXPECT_LT(out.points.size(), c.points.size());
  EXPECT_GT(s.outlier_cells, 100u);
  EXPECT_LT(s.outlier_cells, c.points.size());
  // Kept points are input points, in input order.
  size_t k = 0;
  for (const auto& p : out.points) {
    while (k < c.points.size() && c.points[k] != p) ++k;
    ASSERT_LT(k, c.points.size());
    ++k;
  }
  // Bad cell sizes are refused.
  o.outlier_voxel = -0.01f;
  expect_input_error([&] { filter_cloud(c, o); }, {"outlier voxel"});
  o.outlier_voxel = 1e-12f;
  expect_input_error([&] { filter_cloud(c, o); }, {"outlier voxel size", "from the cloud's median"});
}

TEST(FilterCloud, StagesChainInOrder) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const PointCloud c = read_cloud(scan("terrain_understanding_mit/curb_w_grass.npy"));
  CloudFilterOptions o;
  o.crop_max = Eigen::Vector3f(0.0f, 1.0f, 1.0f);
  o.voxel_size = 0.01f;
  o.outlier_neighbours = 10;
  FilterStats s;
  const PointCloud out = filter_cloud(c, o, &s);
  EXPECT_EQ(s.points_in, c.points.size());
  EXPECT_LT(s.after_crop, s.points_in);
  EXPECT_LT(s.after_voxel, s.after_crop);
  EXPECT_LE(s.after_outliers, s.after_voxel);
  EXPECT_EQ(out.points.size(), s.after_outliers);
}

// One far stray return in a 1 m patch: the default outlier voxel (1 cm) cannot index a cloud
// 2e7 m wide. The refusal names that point (input index, coordinates) and the limit it breaks,
// not only the cloud's extent; so does the voxel grid's.
TEST(FilterCloud, FarOutlierIsNamedByIndexAndCoordinates) {
  PointCloud c;
  c.source = "stray.pcd";
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j) c.points.emplace_back(0.05f * i, 0.05f * j, 0.0f);
  c.points.insert(c.points.begin() + 7, Eigen::Vector3f(0.1f, 2e7f, 0.0f));  // index 7
  CloudFilterOptions o = default_map_cleaning();
  expect_input_error([&] { filter_cloud(c, o); },
                     {"stray.pcd", "point 7 (0.100000, 20000000.000000, 0.000000)",
                      "from the cloud's median y", "2^30 cells", "outlier voxel size 0.010000"});
  // A crop that excludes the stray point leaves a cloud the octree can index.
  o.crop_max = Eigen::Vector3f(10, 10, 10);
  EXPECT_NO_THROW(filter_cloud(c, o));
  // The voxel grid's limit, on a stray point in z (index 0).
  o = {};
  o.voxel_size = 1e-4f;
  c.points[7] = Eigen::Vector3f(0.1f, 0.1f, 0.0f);
  c.points[0] = Eigen::Vector3f(0.0f, 0.0f, -5e6f);
  expect_input_error([&] { filter_cloud(c, o); },
                     {"stray.pcd", "point 0 (0.000000, 0.000000, -5000000.000000)",
                      "median z", "voxels of size 0.000100"});
}

TEST(FilterCloud, InvalidOptionsNameTheCloud) {
  PointCloud c;
  c.source = "scan42.pcd";
  c.points = {{0, 0, 0}, {1000, 1000, 1000}};
  CloudFilterOptions o;
  o.voxel_size = -0.1f;
  expect_input_error([&] { filter_cloud(c, o); }, {"scan42.pcd", "voxel size"});
  o.voxel_size = std::numeric_limits<float>::quiet_NaN();
  expect_input_error([&] { filter_cloud(c, o); }, {"scan42.pcd", "voxel size"});
  o = {};
  o.voxel_size = 1e-5f;  // 1e8 voxels per axis: PCL's int indices would overflow
  expect_input_error([&] { filter_cloud(c, o); }, {"scan42.pcd", "voxels of size"});
  o = {};
  o.crop_min = Eigen::Vector3f(1, 0, 0);
  o.crop_max = Eigen::Vector3f(0, 1, 1);
  expect_input_error([&] { filter_cloud(c, o); }, {"scan42.pcd", "crop minimum exceeds"});
  o = {};
  o.outlier_neighbours = -3;
  expect_input_error([&] { filter_cloud(c, o); }, {"neighbour"});
  o.outlier_neighbours = 5;
  o.outlier_stddev = 0.0;
  expect_input_error([&] { filter_cloud(c, o); }, {"stddev"});
}

}  // namespace
}  // namespace terrastride::perception
