// Reading and writing point clouds (PCD, PLY, XYZ text, NPY). No PCL types here: PCL stays inside
// perception/src so that only a few translation units pay for its headers.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

// Reads a cloud, choosing the format by extension (case-insensitive):
//   .pcd        PCL's PCD reader (ascii/binary/binary_compressed); a VIEWPOINT that is not the
//               identity-zero default becomes sensor_origin.
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
PointCloud read_cloud(const std::string& path,
                      std::optional<Eigen::Vector3d> origin = std::nullopt);

struct ReadStats {
  size_t points_in_file = 0;  // rows/points present in the file, finite or not
  size_t non_finite = 0;      // dropped because a coordinate was NaN or infinite
};
// As read_cloud, also reporting how many points were dropped.
PointCloud read_cloud(const std::string& path, std::optional<Eigen::Vector3d> origin,
                      ReadStats* stats);

// Writes a binary PCD (x y z float32) whose VIEWPOINT is the sensor origin (identity-zero when the
// cloud has none), atomically (temp file + rename). Throws InputError when the directory is not
// writable.
void write_pcd(const PointCloud& cloud, const std::string& path);

}  // namespace terrastride::perception
