// The PCL half of estimate_support_plane (support_plane.hpp): a voxel-grid copy of the cloud and
// PCL's RANSAC plane segmentation. Built into the PCL module (pcl_module.hpp).
#include <pcl/ModelCoefficients.h>
#include <pcl/PointIndices.h>
#include <pcl/console/print.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/method_types.h>
#include <pcl/sample_consensus/model_types.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>

#include "pcl_module.hpp"

namespace terrastride::perception::detail {
namespace {

// Every `stride`-th point, so that at most `limit` remain (deterministic, spread over the cloud).
template <class Get>
void take_evenly(size_t n, size_t limit, pcl::PointCloud<pcl::PointXYZ>& out, const Get& get) {
  const size_t stride = n > limit ? (n + limit - 1) / limit : 1;
  out.clear();
  out.reserve(n / stride + 1);
  for (size_t i = 0; i < n; i += stride) out.push_back(get(i));
}

std::string percent(double share) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f %%", 100.0 * share);
  return buf;
}

SupportPlane estimate(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3d& sensor,
                      const SupportPlaneOptions& o);

}  // namespace

SupportPlane support_plane_with_pcl(const std::vector<Eigen::Vector3f>& points,
                                    const Eigen::Vector3d& sensor, const SupportPlaneOptions& o) {
  static std::once_flag quiet;
  std::call_once(quiet, [] { pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS); });
  const auto t0 = std::chrono::steady_clock::now();
  SupportPlane r = estimate(points, sensor, o);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace terrastride::perception::detail

namespace terrastride::perception::detail {
namespace {

SupportPlane estimate(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3d& sensor,
                      const SupportPlaneOptions& o) {
  SupportPlane r;
  // A bounded copy first: the voxel grid's cost grows with the points, the estimate does not
  // need them all (a 1 M-point scan keeps 200 k).
  auto sample = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  take_evenly(points.size(), 200000, *sample,
              [&](size_t i) { return pcl::PointXYZ(points[i].x(), points[i].y(), points[i].z()); });
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = -lo;
  for (const auto& p : *sample) {
    lo = lo.cwiseMin(p.getVector3fMap());
    hi = hi.cwiseMax(p.getVector3fMap());
  }
  // PCL's voxel grid refuses (and passes the cloud through) when the voxel count overflows an
  // int: 1000 voxels a side is well inside.
  const double extent = sample->empty() ? 0.0 : static_cast<double>((hi - lo).maxCoeff());
  const double leaf = std::max(o.voxel, extent / 1000.0);
  auto down = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  pcl::VoxelGrid<pcl::PointXYZ> grid;
  grid.setInputCloud(sample);
  grid.setLeafSize(static_cast<float>(leaf), static_cast<float>(leaf), static_cast<float>(leaf));
  grid.filter(*down);
  if (down->size() > o.max_points) {
    const auto all = down;
    down = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    take_evenly(all->size(), o.max_points, *down, [&](size_t i) { return (*all)[i]; });
  }
  r.points_used = down->size();
  if (down->size() < o.min_points) {
    r.problem = "too few points for a plane: " + std::to_string(down->size()) + " after " +
                std::to_string(leaf).substr(0, 5) + " m voxels (" + std::to_string(o.min_points) +
                " needed)";
    return r;
  }
  pcl::SACSegmentation<pcl::PointXYZ> seg;
  seg.setOptimizeCoefficients(true);
  seg.setModelType(pcl::SACMODEL_PLANE);
  seg.setMethodType(pcl::SAC_RANSAC);
  seg.setDistanceThreshold(o.distance);
  seg.setMaxIterations(o.max_iterations);
  seg.setInputCloud(down);
  pcl::PointIndices inliers;
  pcl::ModelCoefficients coefficients;
  seg.segment(inliers, coefficients);
  if (inliers.indices.empty() || coefficients.values.size() != 4) {
    r.problem = "no plane found by RANSAC";
    return r;
  }
  r.inlier_share = static_cast<double>(inliers.indices.size()) / static_cast<double>(down->size());
  if (r.inlier_share < o.min_inlier_share) {
    r.problem = "no dominant plane: the best plane holds " + percent(r.inlier_share) +
                " of the points (" + percent(o.min_inlier_share) + " needed)";
    return r;
  }
  Eigen::Vector4d c(coefficients.values[0], coefficients.values[1], coefficients.values[2],
                    coefficients.values[3]);
  const double norm = c.head<3>().norm();
  if (!(norm > 0) || !c.allFinite()) {
    r.problem = "degenerate plane from RANSAC";
    return r;
  }
  c /= norm;
  double h = c.head<3>().dot(sensor) + c[3];
  if (std::abs(h) < o.min_sensor_distance) {
    r.sensor_in_plane = true;
    if (c[2] < 0) c = -c;
  } else if (h < 0) {
    c = -c;
  }
  h = c.head<3>().dot(sensor) + c[3];
  r.found = true;
  r.coefficients = c;
  r.sensor_height = h;
  r.tilt_deg = std::acos(std::clamp(c[2], -1.0, 1.0)) * 180.0 / M_PI;
  return r;
}

}  // namespace
}  // namespace terrastride::perception::detail
