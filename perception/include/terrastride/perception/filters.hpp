// Cloud cleaning with PCL filters (crop box, voxel grid, statistical outlier removal).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

struct CloudFilterOptions {
  std::optional<Eigen::Vector3f> crop_min,
      crop_max;                 // crop box (pcl::CropBox); either bound optional
  float voxel_size = 0.0f;      // 0 = off (pcl::VoxelGrid), else leaf size, m
  int outlier_neighbours = 0;   // 0 = off (pcl::StatisticalOutlierRemoval meanK)
  double outlier_stddev = 2.0;  // StatisticalOutlierRemoval stddev multiplier
  // > 0: the outlier removal judges cells of this size (m) by their centroids and keeps or drops
  // each cell's points together (much faster on dense clouds, and the points themselves stay);
  // when the cells would hold under two points on average it judges the points instead. 0: it
  // always judges every point.
  float outlier_voxel = 0.0f;
};

// The cleaning `terrastride map` and the service's map.update apply unless told otherwise: the
// statistical outlier removal with 8 neighbours and a 2 sigma threshold, judged per 1 cm cell
// (about 3x faster on dense scans than per point), no voxel grid.
CloudFilterOptions default_map_cleaning();

struct FilterStats {
  size_t points_in = 0, non_finite = 0, after_crop = 0, after_voxel = 0, after_outliers = 0;
  size_t outlier_cells = 0;  // cells the outlier removal judged (0: it judged points)
  double seconds = 0;
};

// Applies, in order: drop non-finite points, crop, voxel grid, statistical outlier removal (per
// point, or per outlier_voxel cell). Steps
// that are off pass the cloud through (their "after_" count equals the previous one). The sensor
// origin and source are kept. Throws InputError on invalid options (negative voxel size, crop_min >
// crop_max, a voxel size so small that the grid index would overflow, stddev <= 0).
PointCloud filter_cloud(const PointCloud& cloud, const CloudFilterOptions& options,
                        FilterStats* stats = nullptr);

}  // namespace terrastride::perception
