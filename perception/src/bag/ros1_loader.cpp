// Loading the ROS 1 bag module on first use (ros1_module.hpp).
#include <dlfcn.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <vector>

#include "bag/bag_readers.hpp"
#include "bag/ros1_module.hpp"

namespace terrastride::perception::bag {
namespace {

constexpr const char* kModuleFile = "terrastride_rosbag.so";

std::vector<std::string> candidate_paths() {
  std::vector<std::string> paths;
  if (const char* env = std::getenv("TERRASTRIDE_ROSBAG_MODULE"); env && *env) paths.push_back(env);
  char exe[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n > 0) {
    exe[n] = '\0';
    paths.push_back((std::filesystem::path(exe).parent_path() / kModuleFile).string());
  }
#ifdef TERRASTRIDE_ROSBAG_MODULE_PATH
  paths.push_back(TERRASTRIDE_ROSBAG_MODULE_PATH);
#endif
  return paths;
}

const RosbagModule* load() {
  std::string tried;
  for (const std::string& path : candidate_paths()) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      tried += (tried.empty() ? "" : "; ") + path + ": not found";
      continue;
    }
    void* handle = dlopen(path.c_str(), RTLD_LAZY | RTLD_LOCAL | RTLD_NODELETE);
    if (!handle) {
      const char* err = dlerror();
      tried += (tried.empty() ? "" : "; ") + std::string(err ? err : path + ": dlopen failed");
      continue;
    }
    using Entry = const RosbagModule* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(handle, "terrastride_rosbag_module"));
    const RosbagModule* module = entry ? entry() : nullptr;
    if (!module || module->version != kRosbagModuleVersion) {
      tried += (tried.empty() ? "" : "; ") + path + ": not this build's ROS 1 bag module";
      continue;
    }
    return module;
  }
  throw InputError("cannot load the ROS 1 bag module " + std::string(kModuleFile) +
                   " (set TERRASTRIDE_ROSBAG_MODULE to its path): " + tried);
}

}  // namespace

std::unique_ptr<BagReader> open_ros1(const std::string& path) {
  static std::once_flag once;
  static const RosbagModule* module = nullptr;
  std::call_once(once, [] { module = load(); });
  return module->open(path);
}

}  // namespace terrastride::perception::bag
