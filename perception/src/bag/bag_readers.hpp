// The bag readers behind perception::open_bag.
#pragma once

#include <memory>
#include <string>

#include "terrastride/perception/bag.hpp"

namespace terrastride::perception::bag {

std::unique_ptr<BagReader> open_mcap(const std::string& path);
std::unique_ptr<BagReader> open_db3(const std::string& path);
std::unique_ptr<BagReader> open_ros1(const std::string& path);
// A rosbag2 folder (metadata.yaml and its storage files, read in order as one recording).
bool is_rosbag2_folder(const std::string& path);
std::unique_ptr<BagReader> open_rosbag2_folder(const std::string& path);

}  // namespace terrastride::perception::bag
