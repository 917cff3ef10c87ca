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
  // Undersides of overhangs (x, y, world z of the lowest face of a surface with free space beneath
  // it), from inputs that know free space (an OctoMap's free voxels). They are not support: the
  // height grid keeps them as its overhead layer, and a column with an overhang and no support
  // point has no walkable ground.
  std::vector<Eigen::Vector3f> overhangs;
};

// Free height beneath a surface that makes it an overhang rather than ground (m): twice the 10 cm
// a pallet deck has beneath it (a crevice no foot is put into: the deck is ground), and less than
// any room a leg or a trunk could use beneath a shelf, a table (0.7 m) or a ceiling.
constexpr double kOverhangFreeHeight = 0.2;

}  // namespace terrastride::perception
