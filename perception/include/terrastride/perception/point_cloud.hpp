// Point clouds as plain arrays (no PCL types in the public API), with the sensor origin when known.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace terrastride::perception {

// Bad or unreadable input; the message names the input (file, field) and the problem.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct PointCloud {
  std::vector<Eigen::Vector3f> points;            // world frame, metres
  std::optional<Eigen::Vector3d> sensor_origin;   // where the rays came from, when known
  std::string source;                             // file name or description, for messages
};

}  // namespace terrastride::perception
