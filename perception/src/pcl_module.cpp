// The PCL module's entry point (pcl_module.hpp): its function table.
#include "pcl_module.hpp"

extern "C" __attribute__((visibility("default"))) const terrastride::perception::detail::PclModule*
terrastride_pcl_module() {
  using namespace terrastride::perception::detail;
  static const PclModule module{kPclModuleVersion, &read_pcd_with_pcl, &read_ply_with_pcl,
                                &filter_with_pcl, &support_plane_with_pcl};
  return &module;
}
