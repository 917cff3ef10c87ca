// Loading a module of our own on first use (module_loader.hpp).
#include "module_loader.hpp"

#include <dlfcn.h>
#include <unistd.h>

#include <climits>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception::detail {
namespace {

std::vector<std::string> candidate_paths(const ModuleSpec& spec) {
  std::vector<std::string> paths;
  if (const char* env = std::getenv(spec.env_variable); env && *env) paths.push_back(env);
  char exe[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n > 0) {
    exe[n] = '\0';
    paths.push_back((std::filesystem::path(exe).parent_path() / spec.file).string());
  }
  if (spec.build_path && *spec.build_path) paths.push_back(spec.build_path);
  return paths;
}

}  // namespace

const void* load_module(const ModuleSpec& spec, bool (*accept)(const void* table)) {
  std::string tried;
  const auto note = [&tried](const std::string& why) {
    tried += (tried.empty() ? "" : "; ") + why;
  };
  for (const std::string& path : candidate_paths(spec)) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      note(path + ": not found");
      continue;
    }
    // RTLD_LOCAL: the module's libraries' symbols stay out of the global scope; RTLD_NODELETE:
    // never unloaded (PCL and rosbag register static objects).
    void* handle = dlopen(path.c_str(), RTLD_LAZY | RTLD_LOCAL | RTLD_NODELETE);
    if (!handle) {
      const char* err = dlerror();
      note(err ? std::string(err) : path + ": dlopen failed");
      continue;
    }
    // Every entry function returns a pointer to its table; read as `const void*` (same ABI).
    using Entry = const void* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(handle, spec.entry_symbol));
    const void* table = entry ? entry() : nullptr;
    if (!table || !accept(table)) {
      note(path + ": not this build's " + spec.file);
      continue;
    }
    return table;
  }
  throw InputError("cannot load " + std::string(spec.what) + " " + spec.file + " (set " +
                   spec.env_variable + " to its path): " + tried);
}

}  // namespace terrastride::perception::detail
