// The ROS 1 bag reader lives in a module loaded on first use (terrastride_rosbag.so), as PCL does
// (pcl_module.hpp): librosbag_storage pulls in about twenty libraries (boost, console_bridge,
// class_loader, rospack and with it libpython), which every process would otherwise load and
// relocate, for commands that never open a ROS 1 bag.
//
// Where the module is looked for (module_loader.hpp), in order: $TERRASTRIDE_ROSBAG_MODULE;
// terrastride_rosbag.so beside the running executable; the build tree's path, compiled in (the
// test executables).
#pragma once

#include <memory>
#include <string>

#include "terrastride/perception/bag.hpp"

namespace terrastride::perception::bag {

struct RosbagModule {
  int version;  // kRosbagModuleVersion of the module's build
  std::unique_ptr<BagReader> (*open)(const std::string& path);
};
constexpr int kRosbagModuleVersion = 1;

}  // namespace terrastride::perception::bag

extern "C" const terrastride::perception::bag::RosbagModule* terrastride_rosbag_module();
