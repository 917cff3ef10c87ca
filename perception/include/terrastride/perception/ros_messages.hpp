// The two ROS messages a terrain map needs from a bag, decoded from their wire bytes: ROS 2's CDR
// (little or big endian, XCDR1 alignment) and ROS 1's serialisation. sensor_msgs/PointCloud2 with
// any field layout that has x, y, z as float32 (or float64), organised (height > 1) or not; and
// tf2_msgs/TFMessage. Every length is checked against the bytes: a message that disagrees with
// itself is an InputError saying what (the caller adds the file, topic and time).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "terrastride/perception/bag.hpp"

namespace terrastride::perception {

struct DecodedCloud {
  int64_t stamp_ns = 0;   // header.stamp
  std::string frame_id;   // header.frame_id
  uint32_t width = 0, height = 0;
  std::vector<Eigen::Vector3f> points;  // finite points, in frame_id
  size_t points_in = 0;   // width * height
  size_t non_finite = 0;  // dropped: a coordinate was NaN or infinite (organised clouds' misses)
};

DecodedCloud decode_pointcloud2(std::string_view data, MessageEncoding encoding);

// Reads only the header (stamp, frame_id) of a PointCloud2 (for listing a bag).
DecodedCloud decode_pointcloud2_header(std::string_view data, MessageEncoding encoding);

struct TransformSample {
  int64_t stamp_ns = 0;
  std::string parent;  // header.frame_id
  std::string child;   // child_frame_id
  Eigen::Isometry3d parent_from_child = Eigen::Isometry3d::Identity();
};

std::vector<TransformSample> decode_tf_message(std::string_view data, MessageEncoding encoding);

}  // namespace terrastride::perception
