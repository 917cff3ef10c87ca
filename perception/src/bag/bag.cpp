// open_bag: the reader by extension, after a look at the file.
#include "terrastride/perception/bag.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "bag/bag_readers.hpp"
#include "cloud_io_internal.hpp"

namespace terrastride::perception {
namespace {

using detail::lower_extension;

}  // namespace

bool is_bag_file(const std::string& path) {
  const std::string ext = lower_extension(path);
  return ext == ".mcap" || ext == ".db3" || ext == ".bag" || bag::is_rosbag2_folder(path);
}

std::unique_ptr<BagReader> open_bag(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw InputError(path + ": file not found");
  if (std::filesystem::is_directory(path, ec)) {
    if (bag::is_rosbag2_folder(path)) return bag::open_rosbag2_folder(path);
    throw InputError(path +
                     ": is a directory without metadata.yaml (a rosbag2 folder has one; "
                     "or give a bag file itself: .mcap, .db3, .bag)");
  }
  if (std::filesystem::file_size(path, ec) == 0) throw InputError(path + ": file is empty");
  const std::string ext = lower_extension(path);
  if (ext == ".mcap") return bag::open_mcap(path);
  if (ext == ".db3") return bag::open_db3(path);
  if (ext == ".bag") return bag::open_ros1(path);
  throw InputError(path + ": not a bag file name (expected .mcap, .db3 or .bag)");
}

std::string normalise_type(const std::string& type) {
  const size_t p = type.find("/msg/");
  if (p == std::string::npos) return type;
  return type.substr(0, p) + "/" + type.substr(p + 5);
}

}  // namespace terrastride::perception
