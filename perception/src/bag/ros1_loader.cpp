// Loading the ROS 1 bag module on first use (ros1_module.hpp, module_loader.hpp), for bags that
// pass check_ros1_bag.
#include <mutex>

#include "bag/bag_readers.hpp"
#include "bag/ros1_check.hpp"
#include "bag/ros1_module.hpp"
#include "module_loader.hpp"

namespace terrastride::perception::bag {

std::unique_ptr<BagReader> open_ros1(const std::string& path) {
  static std::once_flag once;
  static const RosbagModule* module = nullptr;
  std::call_once(once, [] {
#ifdef TERRASTRIDE_ROSBAG_MODULE_PATH
    const char* build_path = TERRASTRIDE_ROSBAG_MODULE_PATH;
#else
    const char* build_path = nullptr;
#endif
    module = &detail::load_module<RosbagModule, kRosbagModuleVersion>(
        {"terrastride_rosbag.so", "terrastride_rosbag_module", "TERRASTRIDE_ROSBAG_MODULE",
         build_path, "the ROS 1 bag module"});
  });
  check_ros1_bag(path);  // before librosbag trusts its lengths
  return module->open(path);
}

}  // namespace terrastride::perception::bag
