// The PCL module: everything that calls PCL (PCD/PLY reading in pcl_io.cpp, the cloud filters in
// pcl_filters.cpp, the support plane in pcl_plane.cpp) is built into a separate shared object,
// terrastride_pcl.so, which the perception library loads with dlopen the first time a process reads
// a PCD/PLY file or filters a cloud. PCL's io library alone pulls in about twenty VTK libraries:
// linked into the executable, PCL and VTK were loaded and relocated by every process (a plan, a
// check, the server), about a third of the process's start-up and half of its resident memory, for
// commands that never read a point cloud. Only `map`, `scan-sim`, `polytopes`... that do read or
// filter clouds load it now.
//
// Where the module is looked for, in order: $TERRASTRIDE_PCL_MODULE; terrastride_pcl.so beside
// the running executable (build/ and an installed tree); the build tree's path, compiled in (the
// test executables in build/tests/...).
#pragma once

#include <string>

#include "cloud_io_internal.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/perception/support_plane.hpp"

namespace terrastride::perception::detail {

// The PCL half of filter_cloud: from the cloud (options already validated) to the filtered points
// and the counts in *stats; `name` names the cloud in error messages.
void filter_with_pcl(const PointCloud& cloud, const CloudFilterOptions& options,
                     const std::string& name, FilterStats* stats, PointCloud* filtered);

// The PCL half of estimate_support_plane (pcl_plane.cpp).
SupportPlane support_plane_with_pcl(const std::vector<Eigen::Vector3f>& points,
                                    const Eigen::Vector3d& sensor,
                                    const SupportPlaneOptions& options);

// The module's entry points. Both sides are built from this header in the same build, so plain
// C++ function pointers (and exceptions: InputError) cross the boundary.
struct PclModule {
  int version;  // kPclModuleVersion of the module's build
  RawCloud (*read_pcd)(const std::string& path);
  RawCloud (*read_ply)(const std::string& path);
  void (*filter)(const PointCloud& cloud, const CloudFilterOptions& options,
                 const std::string& name, FilterStats* stats, PointCloud* filtered);
  SupportPlane (*support_plane)(const std::vector<Eigen::Vector3f>& points,
                                const Eigen::Vector3d& sensor, const SupportPlaneOptions& options);
};
constexpr int kPclModuleVersion = 2;

// The loaded module (dlopen on the first call, thread-safe). Throws InputError when it cannot be
// found or loaded, naming the paths tried and dlopen's message.
const PclModule& pcl_module();

}  // namespace terrastride::perception::detail

// The symbol the loader looks up in the module.
extern "C" const terrastride::perception::detail::PclModule* terrastride_pcl_module();
