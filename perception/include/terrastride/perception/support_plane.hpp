// The dominant plane of a cloud, as the up direction of a cloud nobody gave an orientation for:
// PCL's sample consensus (pcl::SACSegmentation, plane model, RANSAC) on a voxel-downsampled copy.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace terrastride::perception {

struct SupportPlaneOptions {
  double voxel = 0.05;        // downsampling leaf (m); grown on huge extents (PCL's index range)
  size_t max_points = 20000;  // of the downsampled copy, taken at an even stride beyond this
  double distance = 0.03;     // inlier distance (m): a floor seen with a few cm of noise
  int max_iterations = 300;   // RANSAC iterations
  size_t min_points = 30;     // fewer downsampled points: no estimate
  double min_inlier_share = 0.15;  // a smaller best plane is not "dominant": no estimate
  // A sensor closer to the plane than this cannot tell which side is up: the normal is then
  // taken in the +z hemisphere (sensor_in_plane).
  double min_sensor_distance = 0.05;
};

struct SupportPlane {
  bool found = false;
  std::string problem;  // why not, when !found ("only 12 points", "no dominant plane: ...")
  // n.x, n.y, n.z, d with |n| = 1 and n . p + d = 0 on the plane; n points to the sensor's side.
  Eigen::Vector4d coefficients = Eigen::Vector4d::Zero();
  double tilt_deg = 0.0;       // angle between n and +z: > 90 when the sensor is below the plane
  double sensor_height = 0.0;  // n . sensor + d: the sensor's distance from the plane (>= 0)
  bool sensor_in_plane = false;
  double inlier_share = 0.0;  // of the downsampled points
  size_t points_used = 0;     // downsampled points the estimate saw
  double seconds = 0.0;       // the estimate's own time (not loading the PCL module)
  Eigen::Vector3d normal() const { return coefficients.head<3>(); }
};

// Estimates the dominant plane of `points` seen from `sensor`. Deterministic (PCL's sample
// consensus seeds its generator with a constant). A cloud with too few points or no plane holding
// min_inlier_share of them gives found = false and the reason; it never throws for such data.
// Throws InputError when PCL is not available.
SupportPlane estimate_support_plane(const std::vector<Eigen::Vector3f>& points,
                                    const Eigen::Vector3d& sensor,
                                    const SupportPlaneOptions& options = {});

}  // namespace terrastride::perception
