// Internal to perception/src: the PCL-backed readers live in pcl_io.cpp so that only that file
// includes PCL's io headers.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

namespace terrastride::perception::detail {

// Points as read, non-finite ones included (the caller drops and counts them).
struct RawCloud {
  std::vector<Eigen::Vector3f> points;
  std::optional<Eigen::Vector3d> origin;
};

RawCloud read_pcd_with_pcl(const std::string& path);
RawCloud read_ply_with_pcl(const std::string& path);

}  // namespace terrastride::perception::detail
