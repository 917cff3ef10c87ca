// Simulated recorded scans of the analytic scenes: a robot-mounted depth camera ray-cast against
// the scene from a few poses along the approach path, with range-dependent noise, dropouts and
// mixed
// ("flying") pixels at depth edges. Deterministic for a given seed.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/perception/sensor_pose.hpp"

namespace terrastride::terrain {

class Scene;

struct DepthSensorOptions {
  double height = 0.8;      // sensor height above the ground (m)
  double pitch_deg = 40.0;  // optical axis pitched down from the horizontal
  // The camera body's roll about its optical axis and yaw about the world's z (degrees): the
  // body's orientation is Rz(yaw) Ry(pitch) Rx(roll), x forward, y left, z up.
  double roll_deg = 0.0;
  double yaw_deg = 0.0;
  double hfov_deg = 87.0;   // a RealSense D435-like field of view
  double vfov_deg = 58.0;
  int columns = 200;  // depth image size (downsampled: keeps shipped scans small)
  int rows = 150;
  double max_range = 3.0;  // m; farther returns are dropped
  // Range noise along the ray: sigma = noise_a + noise_b * range^2 (stereo depth error grows
  // with the square of the range).
  double noise_a = 0.001;
  double noise_b = 0.0015;
  double dropout = 0.02;      // random dropout probability per pixel
  double grazing_deg = 75.0;  // beyond this incidence angle dropouts rise linearly to 100 % at 90
  double mixed_pixel = 0.5;   // probability that a pixel straddling a depth edge is mixed
  double edge_jump = 0.05;    // range difference inside a pixel that counts as a depth edge (m)
  // Sensor x positions along the path (y = 0), looking along +x. The defaults approach the
  // start so that the start area, the obstacle and the goal area are all seen.
  std::vector<double> sensor_x = {-1.0, -0.6, -0.2};
  unsigned seed = 1;
};

struct SimulatedScan {
  perception::PointCloud cloud;  // world frame, sensor_origin set
  // The camera body's pose (x forward, y left, z up): its frame's points are
  // sensor.orientation^-1 (p - sensor.position).
  perception::SensorPose sensor;
  size_t pixels = 0;
  size_t dropped = 0;
  size_t mixed = 0;
};

// One scan per sensor position. Throws perception::InputError for invalid options (naming them).
std::vector<SimulatedScan> simulate_scans(const Scene& scene, const DepthSensorOptions& options);

}  // namespace terrastride::terrain
