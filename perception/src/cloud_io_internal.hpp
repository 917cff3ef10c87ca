// Internal to perception/src: the PCL-backed readers live in pcl_io.cpp so that only that file
// includes PCL's io headers.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace terrastride::perception::detail {

// Points as read, non-finite ones included (the caller drops and counts them).
struct RawCloud {
  std::vector<Eigen::Vector3f> points;
  // A PCD's VIEWPOINT as written (unchecked), unless it is PCL's identity-zero default.
  bool has_viewpoint = false;
  Eigen::Vector3d viewpoint_position = Eigen::Vector3d::Zero();
  Eigen::Vector4d viewpoint_wxyz{1, 0, 0, 0};
  // The header carries kSensorFrameMarker: the points are in the VIEWPOINT's frame.
  bool sensor_frame_marked = false;
};

// The comment terrastride's PCD writer puts in the header. A VIEWPOINT with a position and no
// rotation is ambiguous without it: the writer of earlier versions put world-frame points there.
inline constexpr const char* kSensorFrameMarker =
    "# terrastride: points in the sensor frame, VIEWPOINT = its pose (world = R p + t)";

RawCloud read_pcd_with_pcl(const std::string& path);
RawCloud read_ply_with_pcl(const std::string& path);

// A file's extension in lower case ("scan.PCD" -> ".pcd"): every input reader dispatches on it.
inline std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

}  // namespace terrastride::perception::detail
