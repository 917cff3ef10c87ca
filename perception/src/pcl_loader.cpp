// Loading the PCL module on first use (pcl_module.hpp).
#include <dlfcn.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

#include "pcl_module.hpp"

namespace terrastride::perception::detail {
namespace {

constexpr const char* kModuleFile = "terrastride_pcl.so";

std::vector<std::string> candidate_paths() {
  std::vector<std::string> paths;
  if (const char* env = std::getenv("TERRASTRIDE_PCL_MODULE"); env && *env) paths.push_back(env);
  char exe[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n > 0) {
    exe[n] = '\0';
    paths.push_back((std::filesystem::path(exe).parent_path() / kModuleFile).string());
  }
#ifdef TERRASTRIDE_PCL_MODULE_PATH
  paths.push_back(TERRASTRIDE_PCL_MODULE_PATH);
#endif
  return paths;
}

const PclModule* load() {
  std::string tried;
  for (const std::string& path : candidate_paths()) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      tried += (tried.empty() ? "" : "; ") + path + ": not found";
      continue;
    }
    // RTLD_LOCAL: PCL's and VTK's symbols stay out of the global scope; the module is never
    // unloaded (PCL registers static objects).
    void* handle = dlopen(path.c_str(), RTLD_LAZY | RTLD_LOCAL | RTLD_NODELETE);
    if (!handle) {
      const char* err = dlerror();
      tried += (tried.empty() ? "" : "; ") + std::string(err ? err : path + ": dlopen failed");
      continue;
    }
    using Entry = const PclModule* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(handle, "terrastride_pcl_module"));
    const PclModule* module = entry ? entry() : nullptr;
    if (!module || module->version != kPclModuleVersion) {
      tried += (tried.empty() ? "" : "; ") + path + ": not this build's PCL module";
      continue;
    }
    return module;
  }
  throw InputError("cannot load the PCL module " + std::string(kModuleFile) +
                   " (PCD/PLY reading and cloud filters; set TERRASTRIDE_PCL_MODULE to its path): " +
                   tried);
}

}  // namespace

const PclModule& pcl_module() {
  static std::once_flag once;
  static const PclModule* module = nullptr;
  std::call_once(once, [] { module = load(); });
  return *module;
}

}  // namespace terrastride::perception::detail
