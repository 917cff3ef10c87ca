// Reading and writing point clouds (PCD, PLY, XYZ text, NPY). No PCL types here: PCL stays inside
// perception/src so that only a few translation units pay for its headers.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/perception/sensor_pose.hpp"

namespace terrastride::perception {

// Reads a cloud, choosing the format by extension (case-insensitive):
//   .pcd        PCL's PCD reader (ascii/binary/binary_compressed). A VIEWPOINT that is not the
//               identity-zero default gives sensor_origin; the points are placed by it (PCL's
//               meaning, world = R p + t) only when the file carries terrastride's marker (its
//               writer's files), and else returned as written. Placing clouds as `map` does
//               (any VIEWPOINT, poses, the up check) is terrain::read_map_clouds.
//   .ply        PCL's PLY reader (extra properties such as normals or intensity are ignored).
//   .xyz, .txt  text, "x y z" per line; extra columns ignored; '#' starts a comment; blank lines
//               ok.
//   .npy        float32/float64 array of shape (N, >=3), little endian, C or Fortran order;
//               columns 0..2 = x y z. (3, N) and other shapes with more columns than rows (and at
//               least 3 rows) are refused as transposed.
// Non-finite points are dropped (the ReadStats overload counts them). `origin`, when given,
// overrides the file's sensor origin. Throws InputError naming the file and the problem:
// missing/unreadable, unknown extension, mislabeled content (e.g. a .pcd that is text garbage),
// empty, all non-finite, and a body that disagrees with its header: a value that is not a number
// (named by line and field), a line with the wrong number of values, fewer or more points than the
// header says, binary data shorter than the header says or with non-zero data after the declared
// points.
// `origin` (the old --origin) takes the points as world-frame and ignores any VIEWPOINT.
PointCloud read_cloud(const std::string& path,
                      std::optional<Eigen::Vector3d> origin = std::nullopt);

struct ReadStats {
  size_t points_in_file = 0;  // rows/points present in the file, finite or not
  size_t non_finite = 0;      // dropped because a coordinate was NaN or infinite
};
// As read_cloud, also reporting how many points were dropped.
PointCloud read_cloud(const std::string& path, std::optional<Eigen::Vector3d> origin,
                      ReadStats* stats);

// Writes a binary PCD (x y z float32) of a world-frame cloud, atomically (temp file + rename), as
// PCL means a VIEWPOINT: the points in the sensor frame, VIEWPOINT its pose (world = R p + t),
// so that pcl_viewer and read_cloud place them where they are. `frame`, when given, is that pose
// (e.g. a camera's optical frame); else a cloud with a sensor origin is written relative to it
// (VIEWPOINT = origin, no rotation) and one without as it is (PCL's identity-zero VIEWPOINT).
// A written VIEWPOINT comes with kSensorFrameMarker's header comment. Throws InputError when the
// directory is not writable or the pose is not finite.
void write_pcd(const PointCloud& cloud, const std::string& path, const SensorPose* frame = nullptr);

// A cloud as its file holds it: the finite points in the file's own frame, and what the file says
// of its sensor.
struct CloudFileRead {
  std::vector<Eigen::Vector3f> points;
  // A PCD's VIEWPOINT unless PCL's identity-zero default; its quaternion checked (unit within
  // 1e-3, normalised) and its values finite, else InputError.
  std::optional<SensorPose> viewpoint;
  // The header says the points are in the VIEWPOINT's frame (terrastride's writer).
  bool viewpoint_marked = false;
  ReadStats stats;
};
// Reads `path` (any format of read_cloud) without placing it. Throws InputError as read_cloud.
CloudFileRead read_cloud_file(const std::string& path);

// How a VIEWPOINT is read:
//   kDefault   PCL's meaning (the points are in the sensor frame, VIEWPOINT is its pose), except
//              that a VIEWPOINT with a position and no rotation in a file without terrastride's
//              marker is refused as ambiguous: terrastride's writer of earlier versions wrote
//              world-frame points with the sensor position there, and read as a pose they would
//              map shifted by that position.
//   kPose      PCL's meaning, whatever the VIEWPOINT.
//   kPosition  the points are in the world frame and VIEWPOINT's position is the sensor's
//              (earlier terrastride files); its rotation, if any, is not applied.
enum class ViewpointUse { kDefault, kPose, kPosition };

// What a file says of its sensor under `use`: nullopt without a VIEWPOINT; else the pose and
// whether its rotation is known (false for kPosition). Throws InputError naming the file when
// the VIEWPOINT cannot be read that way.
struct FileSensor {
  SensorPose pose;
  bool rotation_known = true;
};
std::optional<FileSensor> file_sensor(const CloudFileRead& file, const std::string& path,
                                      ViewpointUse use);

}  // namespace terrastride::perception
