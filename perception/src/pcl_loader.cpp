// Loading the PCL module on first use (pcl_module.hpp, module_loader.hpp).
#include <mutex>

#include "module_loader.hpp"
#include "pcl_module.hpp"

namespace terrastride::perception::detail {

const PclModule& pcl_module() {
  static std::once_flag once;
  static const PclModule* module = nullptr;
  std::call_once(once, [] {
#ifdef TERRASTRIDE_PCL_MODULE_PATH
    const char* build_path = TERRASTRIDE_PCL_MODULE_PATH;
#else
    const char* build_path = nullptr;
#endif
    module = &load_module<PclModule, kPclModuleVersion>(
        {"terrastride_pcl.so", "terrastride_pcl_module", "TERRASTRIDE_PCL_MODULE", build_path,
         "the PCL module (PCD/PLY reading, cloud filters, support plane)"});
  });
  return *module;
}

}  // namespace terrastride::perception::detail
