// estimate_support_plane: its PCL half is in the PCL module (pcl_plane.cpp), loaded on first use.
#include "terrastride/perception/support_plane.hpp"

#include "pcl_module.hpp"
#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

SupportPlane estimate_support_plane(const std::vector<Eigen::Vector3f>& points,
                                    const Eigen::Vector3d& sensor,
                                    const SupportPlaneOptions& options) {
  if (!sensor.allFinite()) throw InputError("support plane: the sensor position is not finite");
#ifdef TERRASTRIDE_HAVE_PCL
  return detail::pcl_module().support_plane(points, sensor, options);
#else
  (void)points;
  (void)options;
  throw InputError("estimating the up direction needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

}  // namespace terrastride::perception
