// Where a point cloud's sensor was, and which way it looked: the pose that takes a cloud's points
// from the frame they were recorded in to the world (map) frame, world = R p + t, as PCL's
// sensor_origin_/sensor_orientation_ (a PCD's VIEWPOINT) and ROS tf (parent <- child) mean it.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace terrastride::perception {

struct SensorPose {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  // unit
  Eigen::Vector3d apply(const Eigen::Vector3d& p) const { return orientation * p + position; }
};

// The frame the points of a camera are in, relative to the camera's body (REP 103): a body frame
// has x forward, y left, z up; an optical frame z forward (depth), x right, y down. A pose given
// for the body of a camera whose points are in its optical frame is composed with this rotation.
enum class SensorFrame { kBody, kOptical };

// Applies `pose` to every point (world = R p + t, in double) and drops the points that leave
// float's range (a coordinate near 3e38 rotated); returns how many were dropped.
size_t transform_points(std::vector<Eigen::Vector3f>& points, const SensorPose& pose);

// The optical frame's orientation in the body frame (the quaternion x, y, z, w = -0.5, 0.5, -0.5,
// 0.5 of every ROS camera driver's `*_optical_frame`).
Eigen::Quaterniond optical_in_body();

// A unit quaternion from x, y, z, w. Quaternions whose norm is within 1e-3 of 1 are normalised
// (values typed with 4-6 decimals); NaN/inf, zero and farther-off ones are refused with an
// InputError naming `what`.
Eigen::Quaterniond checked_quaternion(double x, double y, double z, double w,
                                      const std::string& what);

// "X,Y,Z,QX,QY,QZ,QW" (the order of ROS's static_transform_publisher and of
// geometry_msgs/Transform; commas, spaces or both between the values). Throws InputError naming
// `what` for a wrong count, a value that is not a finite number, or a bad quaternion.
SensorPose parse_sensor_pose(const std::string& text, const std::string& what);

// A poses file: one cloud per line, "PATH X Y Z QX QY QZ QW" (values separated by spaces or
// commas); '#' starts a comment; blank lines are skipped. A relative PATH is relative to the
// poses file's folder. Throws InputError naming the file and line.
struct PoseLine {
  std::string path;      // as written
  std::string resolved;  // absolute and canonical (fs::weakly_canonical)
  SensorPose pose;
  size_t line = 0;
};
std::vector<PoseLine> read_poses_file(const std::string& path);

}  // namespace terrastride::perception
