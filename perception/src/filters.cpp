// Cloud cleaning with PCL's filters (the only translation unit with PCL filter headers).
#include "terrastride/perception/filters.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "pcl_module.hpp"

namespace terrastride::perception {
namespace {

void validate(const CloudFilterOptions& o, const std::string& name) {
  const auto bad = [&](const std::string& what) {
    throw InputError(name + ": invalid filter options: " + what);
  };
  if (o.crop_min && !o.crop_min->allFinite()) bad("crop minimum is not finite");
  if (o.crop_max && !o.crop_max->allFinite()) bad("crop maximum is not finite");
  if (o.crop_min && o.crop_max && (o.crop_min->array() > o.crop_max->array()).any()) {
    bad("crop minimum exceeds crop maximum");
  }
  if (!std::isfinite(o.voxel_size) || o.voxel_size < 0.0f) {
    bad("voxel size must be a finite number >= 0 (0 = off)");
  }
  if (o.outlier_neighbours < 0) bad("outlier neighbour count must be >= 0 (0 = off)");
  if (!std::isfinite(o.outlier_voxel) || o.outlier_voxel < 0.0f) {
    bad("outlier voxel size must be a finite number >= 0 (0 = judge single points)");
  }
  if (o.outlier_neighbours > 0 && !(std::isfinite(o.outlier_stddev) && o.outlier_stddev > 0.0)) {
    bad("outlier stddev multiplier must be a finite number > 0");
  }
}


}  // namespace

CloudFilterOptions default_map_cleaning() {
  CloudFilterOptions o;
  o.outlier_neighbours = 8;
  o.outlier_stddev = 2.0;
  o.outlier_voxel = 0.01f;
  return o;
}

PointCloud filter_cloud(const PointCloud& cloud, const CloudFilterOptions& options,
                        FilterStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  const std::string& name = cloud.source.empty() ? std::string("point cloud") : cloud.source;
  validate(options, name);
  FilterStats s;
  s.points_in = cloud.points.size();

  PointCloud out;
  out.source = cloud.source;
  out.sensor_origin = cloud.sensor_origin;

#ifdef TERRASTRIDE_HAVE_PCL
  // PCL runs in the PCL module, loaded on first use (pcl_module.hpp).
  detail::pcl_module().filter(cloud, options, name, &s, &out);
#else
  if (options.crop_min || options.crop_max || options.voxel_size > 0.0f ||
      options.outlier_neighbours > 0) {
    throw InputError(name + ": cloud filters need PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
  }
  for (const auto& p : cloud.points) {
    if (p.allFinite()) out.points.push_back(p);
  }
  s.non_finite = s.points_in - out.points.size();
  s.after_crop = s.after_voxel = s.after_outliers = out.points.size();
#endif

  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (stats) *stats = s;
  return out;
}

}  // namespace terrastride::perception
